"""The sweep's progress bar counts the jobs Hydra's basic sweeper launches and the finished ones."""

from __future__ import annotations

import json
import time
from pathlib import Path

from omegaconf import OmegaConf

from experiments.run.sweep_progress import SweepProgress, finished_runs, sweep_size


def _hydra(task: list[str], params: dict | None = None, sweep_dir: str = "/tmp/x") -> OmegaConf:
    return OmegaConf.create({"hydra": {"overrides": {"task": task}, "sweeper": {"params": params or {}},
                                       "sweep": {"dir": sweep_dir}}})


def test_sweep_size_is_the_product_of_the_sweeps():
    assert sweep_size(_hydra(["decomposer=rdd,uvd", "seed=0,1,2", "eval.max_steps=4"])) == 6
    # the experiment's sweeper params, with a command-line value replacing one of them
    params = {"decomposer": "rdd,uvd,uniform,expert,none", "seed": "0,1,2"}
    assert sweep_size(_hydra([], params)) == 15
    assert sweep_size(_hydra(["seed=0"], params)) == 5
    assert sweep_size(_hydra([], {"seed": "range(10)"})) == 10
    assert sweep_size(_hydra(["experiment=smoke"])) == 1


def test_bar_follows_the_results_files(tmp_path: Path, capsys):
    cfg = _hydra(["seed=0,1,2"], sweep_dir=str(tmp_path))
    cb = SweepProgress(poll_s=0.05)
    cb.on_multirun_start(cfg)
    for job in range(3):
        (tmp_path / str(job)).mkdir()
        (tmp_path / str(job) / "results.json").write_text(json.dumps({}))
        time.sleep(0.1)
    (tmp_path / "3").mkdir()  # a job still running: no results yet
    assert finished_runs(tmp_path) == 3
    cb.on_multirun_end(cfg)
    err = capsys.readouterr().err
    assert "sweep" in err and "3/3" in err
    # stderr is no terminal here (a log file, as under experiments.reproduce): one line per change
    # in the count, never a redraw per poll
    lines = err.splitlines()
    assert "\r" not in err and len(lines) == len(set(lines)) <= 4, lines
