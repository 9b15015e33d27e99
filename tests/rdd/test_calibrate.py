"""Leave-one-episode-out calibration against decompositions run independently per held-out episode."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from rdd.core.calibrate import (
    CalibrationError,
    calibrate,
    check_grid,
    default_grid,
    sample_episodes,
)
from rdd.database import DatabaseError
from rdd.database.model import SubtaskDatabase
from rdd.decomposers.rdd import RDDDecomposer
from rdd.demo import SyntheticWorld, build_synthetic_database
from rdd.metrics import miou


@pytest.fixture(scope="module")
def db_with_frames():
    world = SyntheticWorld.make(seed=3)
    db, demos = build_synthetic_database(world, demos_per_task=2, rng=np.random.default_rng(1))
    db.frames = {f"{task}/train_{i}": fv for task, runs in demos.items() for i, (fv, _) in enumerate(runs)}
    return db


def sub_database(db, held):
    keep = [i for i, n in enumerate(db.episodes) if n != held]
    return SubtaskDatabase.from_arrays(db.begin[keep], db.end[keep], db.durations[keep])


def test_scores_equal_independent_leave_one_out_decompositions(db_with_frames):
    db = db_with_frames
    grid = {"alpha": [0.0, 0.5, 1.0, 3.0], "min_len": [2, 5], "max_len": [None, 12]}
    cal = calibrate(db, grid=grid, sample=4, seed=2)
    assert len(cal["episodes"]) == 4 and set(cal["episodes"]) <= set(db.frames)
    assert len(cal["results"]) == 4 * 2 * 2
    for row in cal["results"]:
        expected = []
        for held in cal["episodes"]:
            dec = RDDDecomposer(sub_database(db, held), alpha=row["alpha"], min_len=row["min_len"],
                                max_len=row["max_len"])
            segs = dec.decompose_embeddings(db.frames[held]).segments
            expected.append(miou(segs, db.episode_segments(held)))
        assert row["per_episode"] == pytest.approx(expected)
        assert row["miou"] == pytest.approx(np.mean(expected))
    best = max(r["miou"] for r in cal["results"])
    assert cal["score"] == pytest.approx(best)
    chosen = next(r for r in cal["results"] if {k: r[k] for k in ("alpha", "min_len", "max_len")}
                  == cal["chosen"])
    assert chosen["miou"] == pytest.approx(best)
    paper = next(r for r in cal["results"] if (r["alpha"], r["min_len"], r["max_len"]) == (1.0, 2, None))
    assert cal["paper_setting"]["score"] == pytest.approx(paper["miou"])


def test_decomposer_uses_calibration_unless_overridden(db_with_frames):
    db = SubtaskDatabase.from_arrays(db_with_frames.begin, db_with_frames.end, db_with_frames.durations,
                                     meta={"calibration": {"chosen": {"alpha": 0.25, "min_len": 3,
                                                                      "max_len": 20}}})
    dec = RDDDecomposer.calibrated(db)
    assert (dec.alpha, dec.min_len, dec.max_len) == (0.25, 3, 20)
    assert dec.option_source == {"alpha": "calibration", "min_len": "calibration", "max_len": "calibration"}
    dec = RDDDecomposer.calibrated(db, alpha=1.0, max_len=None)
    assert (dec.alpha, dec.min_len, dec.max_len) == (1.0, 3, None)
    assert dec.option_source == {"alpha": "given", "min_len": "calibration", "max_len": "given"}
    dec = RDDDecomposer(db)
    assert (dec.alpha, dec.min_len, dec.max_len) == (1.0, 2, None)
    assert dec.option_source == {"alpha": "paper", "min_len": "paper", "max_len": "paper"}
    with pytest.raises(DatabaseError, match="has no calibration"):
        RDDDecomposer.calibrated(SubtaskDatabase.from_arrays(db.begin, db.end, db.durations))


def test_bad_input(db_with_frames, caplog):
    db = db_with_frames
    with pytest.raises(CalibrationError, match="'alpha' is empty"):
        calibrate(db, grid={"alpha": [], "min_len": [2], "max_len": [None]})
    with pytest.raises(CalibrationError, match="'min_len': 0"):
        check_grid({"alpha": [1.0], "min_len": [0], "max_len": [None]})
    with pytest.raises(CalibrationError, match="every max_len is below every min_len"):
        check_grid({"alpha": [1.0], "min_len": [5], "max_len": [3]})
    no_frames = SubtaskDatabase.from_arrays(db.begin, db.end, db.durations,
                                            meta={"episodes": db.episodes})
    with pytest.raises(CalibrationError, match="keeps no frame vectors.*--no-calibrate"):
        calibrate(no_frames)
    one = SubtaskDatabase.from_arrays(db.begin[:3], db.end[:3], db.durations[:3],
                                      meta={"episodes": ["a"] * 3})
    with caplog.at_level(logging.WARNING):
        assert calibrate(one) is None
    assert "one episode" in caplog.text
    with pytest.raises(CalibrationError, match=">= 1"):
        sample_episodes(["a"], 0)
    assert sample_episodes(list("abcdef"), 3, seed=0) == sample_episodes(list("abcdef"), 3, seed=0)
    assert len(sample_episodes(list("abcdef"), 3)) == 3 and sample_episodes(list("ab"), 10) == ["a", "b"]


def test_default_grid_offers_min_lens_from_the_shortest_and_the_median_stored_segment():
    v = np.eye(3, dtype=np.float32)
    # durations are end - 1 - start: segments of 18, 41 and 30 frames (median 30)
    db = SubtaskDatabase.from_arrays(v, v, [17, 40, 29])
    grid = default_grid(db)
    # the fixed ones; half the shortest (9), the shortest (18); a quarter (7) and half (15) the median
    assert grid["min_len"] == [2, 4, 7, 9, 15, 18]
    assert grid["max_len"] == [None, 52, 82]  # 1.25 and 2 times the longest (41 frames), rounded up
