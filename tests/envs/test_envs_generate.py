"""Demo generation: split seed ranges, save/load round trip, resume, determinism, rendering."""

from __future__ import annotations

import numpy as np
import pytest

from envs.generate import SPLIT_SEEDS, episode_dir, generate, split_of_seed
from envs.record import validate_privileged


def test_split_seed_ranges_are_disjoint():
    names = list(SPLIT_SEEDS)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not set(SPLIT_SEEDS[a]) & set(SPLIT_SEEDS[b]), (a, b)
    assert split_of_seed(0) == "train" and split_of_seed(10_000) == "val" and split_of_seed(29_999) == "test"
    with pytest.raises(ValueError):
        split_of_seed(10**9)


def test_expert_is_deterministic_per_seed(demo):
    from envs.expert import run_expert

    a = demo("turn_tap", 1)
    b = run_expert("turn_tap", 1, render=False)
    np.testing.assert_array_equal(a.episode.joint_positions, b.episode.joint_positions)
    np.testing.assert_array_equal(a.privileged["object_positions"], b.privileged["object_positions"])
    assert a.episode.segments == b.episode.segments and a.episode.goal == b.episode.goal


def test_generate_round_trip_and_resume(tmp_path, demo):
    from rdd.data.native import load_episode

    used = generate(["turn_tap"], "train", 1, tmp_path, image_size=64, progress=False)
    seed = used["turn_tap"][0]
    assert seed == SPLIT_SEEDS["train"][0] + (0 if demo("turn_tap", seed).success else 1)
    path = episode_dir(tmp_path, "train", "turn_tap", seed)
    ep = load_episode(path)
    # Rendering never touches the physics: the rendered demo equals the no-render one.
    ref = demo("turn_tap", seed)
    np.testing.assert_array_equal(ep.joint_velocities, ref.episode.joint_velocities)
    np.testing.assert_array_equal(ep.gripper_open, ref.episode.gripper_open)
    assert ep.segments == ref.episode.segments and ep.instructions == ref.episode.instructions
    frames = ep.frames("front")
    assert frames.shape == (ep.num_frames, 64, 64, 3) and frames.dtype == np.uint8
    assert ep.frames("wrist").std() > 0 and frames.std() > 0
    priv = ep.meta["privileged"]
    validate_privileged(priv, ep.meta, ep.num_frames)
    np.testing.assert_array_equal(priv["held_object"], ref.privileged["held_object"])
    assert ep.meta["split"] == "train" and ep.meta["seed"] == seed
    stamp = (path / "episode.json").stat().st_mtime_ns
    again = generate(["turn_tap"], "train", 1, tmp_path, image_size=64, progress=False)
    assert again == used
    assert (path / "episode.json").stat().st_mtime_ns == stamp  # resumed, not rewritten


def test_generate_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="split"):
        generate(["turn_tap"], "dev", 1, tmp_path, progress=False)
    with pytest.raises(ValueError, match="unknown tasks"):
        generate(["no_such_task"], "train", 1, tmp_path, progress=False)


def test_failed_seeds_are_recorded_and_replaced(tmp_path, monkeypatch):
    import json

    import envs.generate as gen

    calls = []

    def fake(task, seed, split, out, image_size, render, ticks_per_frame, motion_timeout):
        calls.append(seed)
        if seed == 1:  # the expert "fails" on seed 1: recorded, then seed 2 replaces it
            return seed, False, "timeout at waypoint 0"
        (gen.episode_dir(out, split, task, seed)).mkdir(parents=True)
        (gen.episode_dir(out, split, task, seed) / "episode.json").write_text("{}")
        return seed, True, None

    monkeypatch.setattr(gen, "generate_one", fake)
    used = gen.generate(["turn_tap"], "train", 3, tmp_path, progress=False)
    assert used == {"turn_tap": [0, 2, 3]}
    failed = json.loads((tmp_path / "train" / "turn_tap" / "failed_seeds.json").read_text())
    assert failed == {"1": "timeout at waypoint 0"}
    calls.clear()
    assert gen.generate(["turn_tap"], "train", 3, tmp_path, progress=False) == used
    assert calls == []  # resumed: neither finished nor failed seeds are run again


def test_generate_gives_up_on_a_task_whose_expert_keeps_failing(tmp_path, monkeypatch):
    import json

    import envs.generate as gen

    calls = []

    def always_fails(task, seed, split, out, image_size, render, ticks_per_frame, motion_timeout):
        calls.append(seed)
        return seed, False, "lid slipped" if seed % 2 else "success detector false"

    monkeypatch.setattr(gen, "generate_one", always_fails)
    with pytest.raises(RuntimeError, match=r"turn_tap: the expert failed on 4 new train seeds.*0 of 2"
                                           r".*failed_seeds\.json.*--max-failures"):
        generate(["turn_tap"], "train", 2, tmp_path, progress=False, max_failures=3)
    assert len(calls) == 4  # never more than the budget plus the last batch's overshoot
    failed = json.loads((tmp_path / "train" / "turn_tap" / "failed_seeds.json").read_text())
    assert sorted(int(s) for s in failed) == calls

    # a rerun skips the known failures without counting them, and goes on from the next seed
    def fails_twice_more(task, seed, split, out, image_size, render, ticks_per_frame, motion_timeout):
        calls.append(seed)
        return seed, seed >= 6, None if seed >= 6 else "slipped"

    monkeypatch.setattr(gen, "generate_one", fails_twice_more)
    calls.clear()
    used = generate(["turn_tap"], "train", 2, tmp_path, progress=False, max_failures=2)
    assert used == {"turn_tap": [6, 7]} and calls == [4, 5, 6, 7]
    with pytest.raises(ValueError, match="max-failures"):
        generate(["turn_tap"], "train", 2, tmp_path, progress=False, max_failures=-1)
