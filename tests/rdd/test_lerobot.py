"""LeRobot reader: the real v2.1 G1 dataset, and a v3.0 dataset written here with pyarrow + PyAV."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pa = pytest.importorskip("pyarrow")
av = pytest.importorskip("av")
import pyarrow.parquet as pq  # noqa: E402

from rdd.data.lerobot.dataset import LeRobotDataset  # noqa: E402
from rdd.data.lerobot.reader import load_episode, load_episodes  # noqa: E402

KEY = "observation.images.top"
FPS = 10


def level(i):
    """A grey level per frame index, far apart enough to survive lossy coding."""
    return (i * 37) % 200 + 20


def write_video(path, levels, size=(32, 48)):
    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as out:
        stream = out.add_stream("mpeg4", rate=FPS)
        stream.width, stream.height = size[1], size[0]
        stream.pix_fmt = "yuv420p"
        stream.options = {"qscale": "2"}
        for lv in levels:
            img = np.full((size[0], size[1], 3), lv, dtype=np.uint8)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)


def make_v30(root: Path, lengths=(6, 9)):
    info = {
        "codebase_version": "v3.0", "fps": FPS, "robot_type": "toy", "chunks_size": 1000,
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
        "features": {
            "observation.state": {"dtype": "float32", "shape": [3]},
            KEY: {"dtype": "video", "shape": [32, 48, 3]},
        },
    }
    (root / "meta").mkdir(parents=True)
    (root / "meta/info.json").write_text(json.dumps(info))
    rows, ep_rows, levels, start = [], [], [], 0
    for ep, n in enumerate(lengths):
        for i in range(n):
            grip = 1.0 if i < n // 2 else 0.0
            rows.append({"observation.state": [float(i), 0.0, grip], "timestamp": i / FPS,
                         "frame_index": i, "episode_index": ep, "index": start + i, "task_index": ep})
            levels.append(level(start + i))
        ep_rows.append({
            "episode_index": ep, "tasks": [f"task {ep}"], "length": n,
            "data/chunk_index": 0, "data/file_index": 0,
            "dataset_from_index": start, "dataset_to_index": start + n,
            f"videos/{KEY}/chunk_index": 0, f"videos/{KEY}/file_index": 0,
            f"videos/{KEY}/from_timestamp": start / FPS, f"videos/{KEY}/to_timestamp": (start + n) / FPS,
        })
        start += n
    (root / "data/chunk-000").mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(rows), root / "data/chunk-000/file-000.parquet")
    (root / "meta/episodes/chunk-000").mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(ep_rows), root / "meta/episodes/chunk-000/file-000.parquet")
    pq.write_table(pa.Table.from_pylist([{"task": f"task {e}", "task_index": e} for e in range(len(lengths))]),
                   root / "meta/tasks.parquet")
    write_video(root / f"videos/{KEY}/chunk-000/file-000.mp4", levels)


def test_v30_episodes_locate_their_frames(tmp_path):
    make_v30(tmp_path)
    eps = load_episodes(tmp_path, gripper_key="observation.state", gripper_indices=[2])
    assert [e.name for e in eps] == ["episode_000000", "episode_000001"]
    e1 = eps[1]
    assert e1.num_frames == 9 and e1.goal == "task 1" and list(e1.views) == ["top"]
    frames = e1.frames("top")
    got = frames.reshape(9, -1).mean(axis=1)
    expected = np.array([level(6 + i) for i in range(9)])
    assert np.abs(got - expected).max() < 6
    np.testing.assert_array_equal(e1.gripper_open, (np.arange(9) < 4).astype(float))
    np.testing.assert_allclose(e1.joint_velocities[:, 0], FPS)  # position i -> velocity fps
    sub = e1.frames("top", [8, 0])
    assert np.abs(sub.reshape(2, -1).mean(1) - [level(14), level(6)]).max() < 6


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="meta/info.json"):
        LeRobotDataset(tmp_path)
    make_v30(tmp_path / "d")
    with pytest.raises(KeyError, match="not listed"):
        load_episode(tmp_path / "d", 7)
    with pytest.raises(KeyError, match="camera keys"):
        load_episode(tmp_path / "d", 0, camera_keys=["observation.images.nope"])


def test_real_g1_v21(real_data):
    G1 = real_data("lerobot/unitree_g1_pick_bottle")
    ds = LeRobotDataset(G1)
    assert ds.version == "v2.1" and len(ds.episodes) == 100 and ds.present_episodes() == [1, 2]
    with pytest.raises(FileNotFoundError, match="episode 0 is listed.*episode_000000.parquet"):
        load_episodes(G1)
    with pytest.raises(FileNotFoundError, match="episode 5 is listed"):
        load_episode(ds, 5)
    eps = load_episodes(G1, skip_missing=True, gripper_key="observation.state",
                        gripper_indices=[20, 21, 22, 23], gripper_threshold=0.6, max_side=64)
    assert [(e.name, e.num_frames) for e in eps] == [("episode_000001", 393), ("episode_000002", 343)]
    e = eps[0]
    assert e.goal == "Pick up the yellow bottle on the table."
    # Arm joints inferred from info.json's names: the 14 that are not hand dims (README: 0-13).
    assert e.joint_positions.shape == (393, 14) and e.meta["joint_indices"] == list(range(14))
    # The right hand closes on the bottle and opens again: both states occur.
    assert set(np.unique(e.gripper_open)) == {0.0, 1.0}
    f = e.frames("cam_high", [0, 392])
    assert f.shape == (2, 48, 64, 3) and f.dtype == np.uint8 and f.std() > 5


def test_real_g1_inferred_hands(real_data):
    """No options: hands inferred per side from the names (README: left 14-19, right 20-25); the
    right hand closes on the bottle once and opens once, the left rests, so the flag (fraction of
    hands open) changes exactly twice per episode."""
    G1 = real_data("lerobot/unitree_g1_pick_bottle")
    from rdd.data.lerobot.reader import describe_layout

    for e in load_episodes(G1, skip_missing=True):
        g = e.meta["gripper"]
        assert g["sides"] == ["left", "right"]
        assert g["indices"] == [list(range(14, 20)), list(range(20, 26))]
        assert int(np.count_nonzero(np.diff(e.gripper_open))) == 2
        assert "dims [0, 1, 2" in describe_layout(e) and "right [20, 21" in describe_layout(e)


def test_names_inference_and_options(tmp_path, caplog):
    from rdd.data.lerobot.layout import feature_names, hand_flags, infer_layout
    from rdd.data.lerobot.reader import check_reader_options

    names = ["l_shoulder", "left_elbow", "left_gripper", "right_elbow", "RightHandIndex", "right_finger2", "waist"]
    assert infer_layout(names) == ([0, 1, 3, 6], {"left": [2], "right": [4, 5]})
    info = {"features": {"s": {"names": {"motors": ["a", "b"]}}, "t": {"names": [["x", "y"]]}, "u": {"names": None}}}
    assert feature_names(info, "s") == ["a", "b"] and feature_names(info, "t") == ["x", "y"]
    assert feature_names(info, "u") is None and feature_names(info, "nope") is None
    # Hysteresis: a level hovering around the threshold does not flicker; a real close/open does.
    level = np.array([0.49, 0.51, 0.49, 0.52, 0.2, 0.3, 0.52, 0.6, 0.9])
    assert hand_flags(level[:, None], [[0]], 0.5, 0.05, True, "x")[:, 0].tolist() == [0, 0, 0, 0, 0, 0, 0, 1, 1]
    assert hand_flags(level[:, None], [[0]], 0.5, 0.0, True, "x")[:, 0].tolist() == [0, 1, 0, 1, 0, 0, 1, 1, 1]
    for bad, match in [({"gripper_indx": [1]}, "unknown LeRobot reader option"),
                       ({"gripper_indices": [1.5]}, "gripper_indices"),
                       ({"gripper_indices": []}, "gripper_indices"),
                       ({"max_side": 0}, "max_side"), ({"skip_missing": "yes"}, "skip_missing"),
                       ({"gripper_threshold": "high"}, "gripper_threshold"),
                       ({"camera_keys": "observation.images.top"}, "camera_keys")]:
        with pytest.raises(ValueError, match=match):
            check_reader_options(bad)
    make_v30(tmp_path)
    with pytest.raises(ValueError, match="gripper_key='observation.state'.*3 dims.*gripper_indices"):
        load_episodes(tmp_path, gripper_key="observation.state")
    with pytest.raises(ValueError, match="episodes: \\[9\\]"):
        load_episodes(tmp_path, episodes=[9])
    with caplog.at_level("WARNING"):
        eps = load_episodes(tmp_path, gripper_key="observation.state", gripper_indices=[1])
    assert "never changes" in caplog.text and "gripper_threshold" in caplog.text
    assert eps[0].gripper_open.tolist() == [0.0] * 6


def test_real_g1_expert_rule_through_the_cli(tmp_path, caplog, real_data):
    """Issue 14's first attempt: gripper_key=observation.state now uses the inferred hand dims, and
    the expert rule does not shatter the episodes (it gave 24-48 five-frame segments)."""
    G1 = real_data("lerobot/unitree_g1_pick_bottle")
    from rdd.cli import main

    out = tmp_path / "expert.json"
    with caplog.at_level("INFO", logger="rdd"):
        assert main(["-v", "decompose", "--format", "lerobot", "--data", str(G1), "--reader-option",
                     "skip_missing=true", "--reader-option", "gripper_key=observation.state", "--decomposer",
                     "expert", "--out", str(out)]) == 0
    assert "right [20, 21, 22, 23, 24, 25] (inferred)" in caplog.text
    for rec in json.loads(out.read_text())["episodes"]:
        lengths = [e - s for s, e in rec["segments"]]
        assert 3 <= len(lengths) <= 12 and min(lengths) >= 6  # 0.2 s at 30 fps


def test_cli_names_the_dims_it_used_with_verbose_only(lerobot_factory, tmp_path):
    """The reader's dims line is a -v detail: absent from a plain run's stderr, logged once with -v."""
    import subprocess
    import sys

    data = lerobot_factory("v3.0")
    argv = ["decompose", "--format", "lerobot", "--data", str(data), "--decomposer", "uniform", "--no-cache"]
    errs = {}
    for flags in ((), ("-v",)):
        out = tmp_path / f"out{len(flags)}.json"
        proc = subprocess.run([sys.executable, "-m", "rdd", *flags, *argv, "--out", str(out)], capture_output=True,
                              text=True, timeout=120, cwd=Path(__file__).resolve().parents[2])
        assert proc.returncode == 0, proc.stderr
        errs[flags] = proc.stderr
    assert "arm joints" not in errs[()]
    assert errs[("-v",)].count("arm joints") == 1 and "--reader-option joint_indices" in errs[("-v",)]
