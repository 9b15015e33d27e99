"""``python -m rdd`` end to end on native episodes with known sub-task boundaries."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rdd.cli import main, parse_options
from rdd.data.episode import Episode
from rdd.data.native import save_episode

ROOT = Path(__file__).resolve().parents[2]
COLOURS = np.array([[230, 30, 30], [30, 230, 30], [30, 30, 230]], dtype=float)


def synthetic_episode(name: str, lengths: tuple[int, int, int], seed: int) -> Episode:
    """Three sub-tasks: the scene colour drifts between three targets and the gripper is closed
    during the second, so the expert rule cuts where the gripper state changes."""
    rng = np.random.default_rng(seed)
    t = sum(lengths)
    frames = np.zeros((t, 16, 16, 3), dtype=np.uint8)
    vel = np.ones((t, 7))
    grip = np.ones(t)
    start = 0
    for j, n in enumerate(lengths):
        a, b = COLOURS[j], COLOURS[(j + 1) % 3]
        for i in range(n):
            c = a + (b - a) * i / max(n - 1, 1)
            frames[start + i] = np.clip(c + rng.normal(0, 3, size=(16, 16, 3)), 0, 255)
        if j == 1:
            grip[start:start + n] = 0.0
        start += n
    return Episode(name=name, views={"front": frames, "wrist": frames[:, ::-1].copy()},
                   gripper_open=grip, joint_velocities=vel, goal="move the colours", task="toy")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("native")
    for k, lengths in enumerate([(12, 15, 13), (14, 12, 15), (13, 14, 12), (15, 13, 14)]):
        save_episode(synthetic_episode(f"ep{k}", lengths, k), root / f"ep{k}")
    return root


def run(*argv: str) -> int:
    return main([str(a) for a in argv])


def test_parse_options():
    assert parse_options(["a=1", "b=[1,2]", "c=observation.state", "d-e=true"], "--x") == {
        "a": 1, "b": [1, 2], "c": "observation.state", "d_e": True}


def test_full_pipeline(data, tmp_path, capsys):
    cache = ["--cache-dir", tmp_path / "cache"]
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "expert",
               "--out", tmp_path / "expert.json") == 0
    expert = json.loads((tmp_path / "expert.json").read_text())
    # The gripper state first differs at frames 12 and 27 (the arm never rests), then the last frame.
    assert expert["episodes"][0]["keyframes"] == [12, 27, 39]
    assert run("build-db", "--format", "native", "--data", data, "--exclude", "ep0", "--encoder",
               "pixels", "--encoder-option", "size=4", *cache, "--out", tmp_path / "db") == 0
    assert run("decompose", "--format", "native", "--data", data, "--include", "ep0",
               "--decomposer", "rdd", "--db", tmp_path / "db", "--encoder-option", "size=4",
               "--max-len", "30", *cache, "--out", tmp_path / "rdd.json") == 0
    out = json.loads((tmp_path / "rdd.json").read_text())
    rec = out["episodes"][0]
    assert out["config"]["decomposer"] == "rdd" and out["config"]["encoder"] == "pixels"
    assert rec["episode"] == "ep0" and rec["num_frames"] == 40
    assert rec["segments"][0][0] == 0 and rec["segments"][-1][1] == 40
    assert len(rec["scores"]) == len(rec["segments"]) == len(rec["instructions"])
    assert rec["keyframes"] == [e - 1 for _, e in rec["segments"]]
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "uvd",
               "--encoder", "pixels", "--encoder-option", "size=4", "--option", "min_interval=5",
               *cache, "--out", tmp_path / "uvd.json") == 0
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "uniform",
               "--option", "n_segments=3", "--out", tmp_path / "uniform.json") == 0
    capsys.readouterr()
    assert run("evaluate", "--pred", tmp_path / "uniform.json", "--gt", tmp_path / "expert.json",
               "--tolerance", "3", "--out", tmp_path / "eval.json") == 0
    assert "MEAN" in capsys.readouterr().out
    ev = json.loads((tmp_path / "eval.json").read_text())
    # Uniform thirds [0,14),[14,27),[27,40) vs expert [0,13),[13,28),[28,40).
    assert ev["methods"]["uniform"]["episodes"]["ep0"]["miou"] == pytest.approx((13 / 14 + 13 / 15 + 12 / 13) / 3)
    assert run("plot", "--pred", tmp_path / "rdd.json", tmp_path / "uvd.json", "--gt",
               tmp_path / "expert.json", "--format", "native", "--data", data, "--episode", "ep0",
               "--out", tmp_path / "fig.png") == 0
    assert (tmp_path / "fig.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_errors_name_the_option(data, tmp_path, capsys):
    assert run("decompose", "--format", "native", "--data", tmp_path / "nope", "--decomposer",
               "uniform", "--out", tmp_path / "x.json") == 2
    assert "--data" in capsys.readouterr().err
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "rdd",
               "--out", tmp_path / "x.json") == 2
    assert "--db" in capsys.readouterr().err
    assert run("decompose", "--format", "native", "--data", data, "--include", "zzz",
               "--decomposer", "uniform", "--out", tmp_path / "x.json") == 2
    assert "--include" in capsys.readouterr().err
    assert run("decompose", "--format", "native", "--data", data, "--decomposer", "uniform",
               "--option", "bogus=1", "--out", tmp_path / "x.json") == 2
    assert "--option" in capsys.readouterr().err
    assert run("evaluate", "--pred", tmp_path / "missing.json", "--gt", tmp_path / "m.json") == 2
    assert "missing.json" in capsys.readouterr().err


def test_module_entry_point():
    res = subprocess.run([sys.executable, "-m", "rdd", "--help"], cwd=ROOT, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0
    for cmd in ("build-db", "decompose", "evaluate", "plot", "demo"):
        assert cmd in res.stdout


def test_demo_subcommand(tmp_path, capsys):
    assert run("demo", "--json", tmp_path / "demo.json") == 0
    assert (tmp_path / "demo.json").is_file()
    assert "novelty" in capsys.readouterr().out
