"""Round trip and error reporting of the native episode format."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.data.native import load_episode, load_episodes, save_episode


def make_episode(name="ep", t=7, seed=0):
    rng = np.random.default_rng(seed)
    return Episode(
        name=name,
        views={
            "front": rng.integers(0, 256, size=(t, 8, 6, 3), dtype=np.uint8),
            "wrist": rng.integers(0, 256, size=(t, 4, 4, 3), dtype=np.uint8),
        },
        gripper_open=(np.arange(t) < 3).astype(float),
        joint_velocities=rng.normal(size=(t, 7)),
        ee_poses=rng.normal(size=(t, 7)),
        goal="open the drawer",
        task="open_drawer",
        segments=[(0, 3), (3, t)],
        instructions=["reach the handle", "pull"],
        meta={"seed": np.int64(3), "variation": np.array([1, 2]), "scale": np.float32(0.5)},
    )


def test_round_trip(tmp_path):
    ep = make_episode()
    priv = {"object_poses": np.arange(7 * 2 * 7, dtype=np.float32).reshape(7, 2, 7)}
    out = save_episode(ep, tmp_path / "ep", privileged=priv)
    back = load_episode(out)
    assert back.name == "ep" and back.goal == ep.goal and back.task == ep.task
    assert back.num_frames == 7 and set(back.views) == {"front", "wrist"}
    for v in ("front", "wrist"):
        np.testing.assert_array_equal(back.frames(v), ep.frames(v))
        np.testing.assert_array_equal(back.frames(v, [6, 0]), ep.frames(v)[[6, 0]])
    np.testing.assert_array_equal(back.gripper_open, ep.gripper_open)
    np.testing.assert_array_equal(back.joint_velocities, ep.joint_velocities)
    np.testing.assert_array_equal(back.ee_poses, ep.ee_poses)
    assert back.joint_positions is None
    assert back.segments == [(0, 3), (3, 7)] and back.instructions == ep.instructions
    assert back.meta["seed"] == 3 and back.meta["variation"] == [1, 2] and back.meta["scale"] == 0.5
    np.testing.assert_array_equal(back.meta["privileged"]["object_poses"], priv["object_poses"])
    # The fingerprint follows the file bytes: equal content, equal files, equal fingerprint.
    again = load_episode(save_episode(back, tmp_path / "copy"))
    assert (tmp_path / "copy" / "frames_front.npz").read_bytes() == (out / "frames_front.npz").read_bytes()
    assert again.fingerprint() == back.fingerprint()
    assert load_episode(save_episode(make_episode(seed=1), tmp_path / "o")).fingerprint() != back.fingerprint()


def test_overwrite_and_folder_listing(tmp_path):
    for i in (10, 2, 1):
        save_episode(make_episode(name=f"e{i}", t=5 + i), tmp_path / f"episode{i}")
    save_episode(make_episode(name="new", t=4), tmp_path / "episode2")  # replaces in place
    eps = load_episodes(tmp_path)
    assert [e.name for e in eps] == ["e1", "new", "e10"]
    assert eps[1].num_frames == 4
    assert [e.name for e in load_episodes(tmp_path / "episode10")] == ["e10"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp dirs left
    # Nested layout <split>/<task>/<episode>/, and half-written hidden temp dirs are ignored.
    save_episode(make_episode(name="b1"), tmp_path / "nest/train/task_b/b_seed1")
    save_episode(make_episode(name="a2"), tmp_path / "nest/train/task_a/a_seed10")
    save_episode(make_episode(name="a1"), tmp_path / "nest/train/task_a/a_seed9")
    save_episode(make_episode(name="tmp"), tmp_path / "nest/train/task_a/.a_seed11.tmp-x")
    assert [e.name for e in load_episodes(tmp_path / "nest")] == ["a1", "a2", "b1"]


def test_errors_name_the_fault(tmp_path):
    with pytest.raises(FileNotFoundError, match="no native episodes"):
        load_episodes(tmp_path)
    d = save_episode(make_episode(), tmp_path / "ep")
    (d / "frames_wrist.npz").unlink()
    with pytest.raises(FileNotFoundError, match="frames_wrist.npz"):
        load_episode(d)
    d = save_episode(make_episode(), tmp_path / "ep")
    header = json.loads((d / "episode.json").read_text())
    header["version"] = 99
    (d / "episode.json").write_text(json.dumps(header))
    with pytest.raises(ValueError, match="'version'"):
        load_episode(d)
    with pytest.raises(ValueError, match="privileged array 'x'"):
        save_episode(make_episode(), tmp_path / "p", privileged={"x": np.zeros(3)})
    bad = make_episode()
    bad.meta["obj"] = object()
    with pytest.raises(ValueError, match="meta"):
        save_episode(bad, tmp_path / "m")
    assert not (tmp_path / "m").exists()


def test_colour_episode_drifts_red_green_blue_with_the_gripper_closed_in_the_second():
    from rdd.testing.native_synth import colour_episode

    ep = colour_episode("c", [4, 5, 6], seed=0, size=8)
    front = ep.frames("front").astype(float).mean(axis=(1, 2))
    assert ep.num_frames == 15 and front.shape == (15, 3)
    assert front[0].argmax() == 0 and front[4].argmax() == 1 and front[9].argmax() == 2  # red, green, blue starts
    assert front[14].argmax() == 0  # the last sub-task ends back at red
    assert list(ep.gripper_open) == [1.0] * 4 + [0.0] * 5 + [1.0] * 6
    assert np.array_equal(ep.frames("wrist"), ep.frames("front")[:, ::-1])
