"""The synthetic LeRobot v3.0 writer reads back as written (episodes across several files), and the
scale benchmark (issue 47.2) runs end to end at a tiny size: same bytes with 1 and 2 workers, and a
killed run's rerun redoes only the episodes not staged and writes the uninterrupted run's bytes."""

from __future__ import annotations

import json

import numpy as np
import pytest


def test_synthetic_v30_reads_back_frame_by_frame(tmp_path):
    pytest.importorskip("av")
    from rdd.data.lerobot.reader import load_episodes
    from rdd.testing.lerobot_synth import write_synthetic_v30

    lengths = [[12, 9], [7], [5, 6, 4]]  # three data/video files of 2, 1 and 3 episodes
    root = write_synthetic_v30(tmp_path / "ds", lengths, size=(24, 32))
    episodes = load_episodes(root)
    flat = [n for f in lengths for n in f]
    assert [e.name for e in episodes] == [f"episode_{i:06d}" for i in range(len(flat))]
    for ep, n in zip(episodes, flat, strict=True):
        frames = ep.views["top"].load()
        assert frames.shape == (n, 24, 32, 3)
        # frame i is flat red 20 + 200 i / (n - 1), green 255 minus that (MPEG-4 at qscale 2: a few levels off)
        red = 20 + 200 * np.arange(n) / (n - 1)
        np.testing.assert_allclose(frames[:, 12, 16, 0], red, atol=6)
        np.testing.assert_allclose(frames[:, 12, 16, 1], 255 - red, atol=6)
        np.testing.assert_array_equal(ep.gripper_open, (np.arange(n) < n // 2).astype(float))


def test_benchmark_tiny_run(tmp_path, capsys, benchmark_module):
    pytest.importorskip("av")
    bench = benchmark_module("bench_scale")
    out = tmp_path / "bench"
    res = bench.main(["--episodes", "6", "--frames", "100", "--per-file", "4", "--size", "96x128",
                      "--compare-episodes", "5", "--kill-at", "0.4", "--effnet-episodes", "0", "--out", str(out)])
    assert [r["episodes"] for r in res["runs"]][:3] == [6, 5, 5]
    assert res["workers_same_bytes"] is True
    resume = res["resume"]
    assert resume["killed"] and 2 <= resume["staged_at_kill"] < 5
    assert resume["redone"] == 5 - resume["staged_at_kill"] and resume["same_bytes"] is True
    assert json.loads((out / "results.json").read_text())["resume"] == resume
    assert "1 vs 2 workers" in capsys.readouterr().out
