"""data.val_first_episode picks disjoint validation demo sets (the paper's M=1 ablation on three sets)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _decompose(tmp: Path, name: str, *overrides: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "WANDB_MODE": "disabled", "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, str(ROOT / "run.py"), "experiment=smoke", "mode=decompose", "decomposer=uniform",
         f"paths.cache_dir={tmp / 'cache'}", f"hydra.run.dir={tmp / name}", *overrides],
        cwd=tmp, env=env, text=True, capture_output=True, timeout=600)


def _episodes(tmp: Path, name: str) -> list[str]:
    data = json.loads((tmp / name / "results.json").read_text())
    return [d["episode"] for d in data["decomposition"]["demos"]]


def test_first_episode_shifts_the_window_of_validation_demos(tmp_path: Path):
    both = _decompose(tmp_path, "both", "data.val_episodes_per_task=2")
    assert both.returncode == 0, both.stderr[-2000:]
    second = _decompose(tmp_path, "second", "data.val_episodes_per_task=1", "data.val_first_episode=1")
    assert second.returncode == 0, second.stderr[-2000:]
    pair = _episodes(tmp_path, "both")
    assert len(set(pair)) == 2
    assert _episodes(tmp_path, "second") == pair[1:]  # the same demo as the pair's second, not a new one


def test_negative_first_episode_is_refused(tmp_path: Path):
    proc = _decompose(tmp_path, "neg", "data.val_first_episode=-1")
    assert proc.returncode != 0
    assert "data.val_first_episode" in proc.stdout + proc.stderr
