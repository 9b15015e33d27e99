"""Calibration is a stage of its own: rdd never pays for it, rdd_calibrated adds it to rdd's database."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import open_dict

import experiments.config.schemas  # noqa: F401  (registers base_config)

pytest.importorskip("pybullet")

CONF = Path(__file__).resolve().parents[2] / "conf"
# Smoke scale with three training demos, so that leave-one-episode-out calibration has episodes to
# leave out; decompose mode trains no policy and no planner.
SMALL = ["experiment=smoke", "threads=1", "mode=decompose", "data.train_episodes_per_task=3"]


def _decompose(decomposer: str, cache: Path, out: Path) -> dict:
    from experiments.cache.store import read_json
    from experiments.run.pipeline import run

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config",
                      overrides=[*SMALL, f"decomposer={decomposer}", f"paths.cache_dir={cache}"])
    with open_dict(cfg):
        cfg.output_dir = str(out)
    assert run(cfg)["status"] == "ok"
    return read_json(out / "results.json")


def _only_database(stage_dir: Path) -> Path:
    dirs = [d / "database" for d in stage_dir.iterdir() if (d / "database" / "manifest.json").is_file()]
    assert len(dirs) == 1, dirs
    return dirs[0]


def test_only_the_calibrated_decomposer_builds_the_calibration(tmp_path: Path):
    from rdd.database.model import SubtaskDatabase

    cache = tmp_path / "cache"
    plain = _decompose("rdd", cache, tmp_path / "rdd")
    assert not plain["timings"]["database"]["cached"]
    assert not (cache / "calibration").exists()
    db_dir = _only_database(cache / "database")
    manifest = json.loads((db_dir / "manifest.json").read_text())
    assert manifest["calibration"] is None and manifest["frames_episodes"] == []
    assert not (db_dir / "frames.npz").exists()  # no whole episode was embedded

    calibrated = _decompose("rdd_calibrated", cache, tmp_path / "cal")
    assert calibrated["timings"]["database"]["cached"]  # rdd's database, reused
    assert not calibrated["timings"]["calibration"]["cached"]
    cal_dir = _only_database(cache / "calibration")
    cal = SubtaskDatabase.load(cal_dir)
    base = SubtaskDatabase.load(db_dir)
    # the same entries as rdd's database, plus the calibration and the frames it decomposed
    assert cal.labels == base.labels and cal.starts == base.starts and cal.episodes == base.episodes
    np.testing.assert_array_equal(cal.begin, base.begin)
    np.testing.assert_array_equal(cal.end, base.end)
    record = cal.meta["calibration"]
    assert sorted(record["episodes"]) == sorted(cal.frames) == sorted(set(base.episodes))
    for name, vectors in cal.frames.items():
        # an entry's begin vector is the whole-episode vector at its start frame
        i = base.episodes.index(name)
        np.testing.assert_allclose(vectors[base.starts[i]], base.begin[i], atol=1e-5)
    assert calibrated["config"]["decomposer"]["_target_"] == "rdd.decomposers.rdd.RDDDecomposer.calibrated"

    again = _decompose("rdd_calibrated", cache, tmp_path / "again")
    assert again["timings"]["calibration"]["cached"]
