"""The ``state`` view: the joint state as one more view of RDD, UVD and the database."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rdd.cli import main
from rdd.data.episode import Episode
from rdd.data.native import save_episode
from rdd.encoders.embed import STATE_LEVEL_CENTRE, STATE_LEVEL_SPAN, STATE_STD_FLOOR, state_vectors

LENGTHS = [(12, 15, 13), (14, 12, 15), (13, 14, 12), (15, 13, 14), (14, 13, 13)]


def state_episode(name: str, lengths: tuple[int, int, int], seed: int) -> Episode:
    """Sub-task j moves joint j from 0 to 1 (the gripper closed during the second); the camera
    shows the same noise throughout, so only the joint state tells the sub-tasks apart."""
    rng = np.random.default_rng(seed)
    t = sum(lengths)
    q = np.zeros((t, 4))
    grip = np.ones(t)
    start = 0
    for j, n in enumerate(lengths):
        q[start:start + n, :j] = 1.0
        q[start:start + n, j] = np.linspace(0, 1, n)
        if j == 1:
            grip[start:start + n] = 0.0
        start += n
    q += rng.normal(0, 0.01, q.shape)
    frames = rng.integers(100, 110, (t, 8, 8, 3)).astype(np.uint8)
    return Episode(name=name, views={"front": frames}, gripper_open=grip, joint_positions=q,
                   joint_velocities=np.ones((t, 4)), goal="move the joints", task="toy")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("state")
    for k, lengths in enumerate(LENGTHS):
        save_episode(state_episode(f"ep{k}", lengths, k), root / f"ep{k}")
    return root


def test_state_vectors_standardise_each_joint_with_a_floor():
    t = np.arange(50.0)
    # joint 0 swings widely, joint 1 half as much, joint 2 is sensor noise, joint 3 never moves
    q = np.stack([3 * np.sin(t / 8), 1.5 * np.cos(t / 5), 1e-3 * np.sin(t), np.full(50, 0.7)], axis=1)
    ep = Episode(name="e", views={}, joint_positions=q)
    v = state_vectors(ep)
    assert v.shape == q.shape and v.dtype == np.float32
    np.testing.assert_allclose(v.mean(axis=0), 0, atol=1e-5)
    np.testing.assert_allclose(v[:, :2].std(axis=0), 1, rtol=1e-5)  # each moving joint to unit spread
    floor = STATE_STD_FLOOR * q[:, 0].std()
    np.testing.assert_allclose(v[:, 2], (q[:, 2] - q[:, 2].mean()) / floor, rtol=1e-4, atol=1e-7)
    assert np.abs(v[:, 2]).max() < 0.01 and np.abs(v[:, 3]).max() < 1e-6


def test_state_view_adds_the_hands_or_the_gripper():
    t = np.arange(40.0)
    q = np.stack([np.sin(t / 6), np.cos(t / 4)], axis=1)
    hands = np.stack([np.full(40, 0.5), (t > 20).astype(float)], axis=1)  # left at rest, right closes
    grip = (t < 10).astype(float)
    with_levels = state_vectors(Episode(name="h", views={}, joint_positions=q, gripper_open=grip,
                                        meta={"hand_levels": hands}))
    assert with_levels.shape == (40, 6)  # the per-hand levels win over the gripper flag
    right = hands[:, 1]
    np.testing.assert_allclose(with_levels[:, 3], (right - right.mean()) / right.std(), rtol=1e-5)
    assert np.abs(with_levels[:, 2]).max() < 1e-6  # the resting hand stays at zero (standardised)...
    # ...but its level in its own units is the same in every episode: half open is 0, open is +SPAN/2
    np.testing.assert_allclose(with_levels[:, 4], 0.0, atol=1e-6)
    np.testing.assert_allclose(with_levels[:, 5], np.where(t > 20, STATE_LEVEL_SPAN / 2, -STATE_LEVEL_SPAN / 2))
    with_flag = state_vectors(Episode(name="g", views={}, joint_positions=q, gripper_open=grip))
    assert with_flag.shape == (40, 4)
    np.testing.assert_allclose(with_flag[:, 2], (grip - grip.mean()) / grip.std(), rtol=1e-5)
    np.testing.assert_allclose(with_flag[:, 3], (grip - STATE_LEVEL_CENTRE) * STATE_LEVEL_SPAN)


def test_hand_opening_is_the_median_of_the_finger_dims_and_wins_over_the_level():
    from rdd.data.lerobot.layout import finger_levels, hand_levels

    t = np.arange(30.0)
    # one hand: four fingers close at frames 10-13 (one of them late, at 25), the thumb bends early
    fingers = np.stack([(t < c).astype(float) for c in (10, 11, 12, 25)], axis=1)
    thumb = np.stack([(t < 3).astype(float), np.full(30, 0.3)], axis=1)
    values = np.concatenate([np.zeros((30, 2)), fingers, thumb], axis=1)  # two arm dims first
    names = ["arm_a", "arm_b", "R_pinky", "R_ring", "R_middle", "R_index", "R_thumb_bend", "R_thumb_rot"]
    levels = hand_levels(values, [[2, 3, 4, 5, 6, 7]], "x")
    opening = finger_levels(values, [[2, 3, 4, 5, 6, 7]], names, levels)
    np.testing.assert_allclose(opening[:, 0], np.median(fingers, axis=1))  # closed from frame 12 (median)
    mean = finger_levels(values, [[2, 3, 4, 5, 6, 7]], None, levels)  # no names: the mean of the hand's dims
    np.testing.assert_allclose(mean[:, 0], values[:, 2:].mean(axis=1))
    q = np.stack([np.sin(t / 6), np.cos(t / 4)], axis=1)
    ep = Episode(name="h", views={}, joint_positions=q, meta={"hand_levels": mean, "hand_openings": opening})
    np.testing.assert_allclose(state_vectors(ep)[:, 3], (opening[:, 0] - STATE_LEVEL_CENTRE) * STATE_LEVEL_SPAN)


def test_a_state_database_of_another_view_version_is_refused(data, tmp_path, capsys):
    """A database whose state view was computed another way (version 1: a hand's mean level) would be
    matched against vectors it never held: loading it names the version and says to rebuild."""
    from rdd.database.store import seal

    common = ["--format", "native", "--data", str(data), "--encoder", "pixels", "--encoder-option", "size=4",
              "--no-cache"]
    assert main(["build-db", *common, "--views", "state", "--exclude", "ep4", "--no-calibrate",
                 "--out", str(tmp_path / "db")]) == 0
    manifest = json.loads((tmp_path / "db" / "manifest.json").read_text())
    assert manifest["extra"]["state_view"] == 2
    capsys.readouterr()
    del manifest["extra"]["state_view"]  # as written before the version existed
    (tmp_path / "db" / "manifest.json").write_text(json.dumps(seal(manifest)))
    code = main(["decompose", *common, "--include", "ep4", "--decomposer", "rdd", "--db", str(tmp_path / "db"),
                 "--out", str(tmp_path / "rdd.json")])
    err = capsys.readouterr().err.strip()
    assert code != 0 and len(err.splitlines()) == 1
    assert "view 'state' of version 1" in err and "rebuild it with build-db" in err
    assert not (tmp_path / "rdd.json").exists()


def test_rdd_on_the_state_view_finds_the_joint_sub_tasks(data, tmp_path):
    common = ["--format", "native", "--data", str(data), "--encoder", "pixels", "--encoder-option", "size=4",
              "--no-cache"]
    assert main(["build-db", *common, "--views", "state", "--exclude", "ep4", "--no-calibrate",
                 "--out", str(tmp_path / "db")]) == 0
    assert json.loads((tmp_path / "db" / "manifest.json").read_text())["views"] == ["state"]
    assert main(["decompose", *common, "--include", "ep4", "--decomposer", "rdd", "--db", str(tmp_path / "db"),
                 "--out", str(tmp_path / "rdd.json")]) == 0
    segs = json.loads((tmp_path / "rdd.json").read_text())["episodes"][0]["segments"]
    # ep4's sub-tasks change at frames 14 and 27; the expert rule, whose cuts on the other four
    # episodes made the database, cuts one frame later (15, 28), where the gripper state has changed
    assert len(segs) == 3
    assert abs(segs[0][1] - 15) <= 1 and abs(segs[1][1] - 28) <= 1


def test_state_view_without_joint_state_is_a_one_line_error(tmp_path, capsys):
    ep = state_episode("bare", (5, 6, 7), 0)
    bare = Episode(name="bare", views=ep.views, gripper_open=ep.gripper_open, goal="g", task="toy")
    save_episode(bare, tmp_path / "d" / "bare")
    code = main(["build-db", "--format", "native", "--data", str(tmp_path / "d"), "--encoder", "pixels",
                 "--views", "state", "--no-cache", "--no-calibrate", "--out", str(tmp_path / "db")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "'state'" in err and "joint state" in err
    assert not (tmp_path / "db").exists()
