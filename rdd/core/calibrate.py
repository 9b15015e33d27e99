"""Self-calibration of RDD's options on the database's own, already segmented, episodes.

The right ``alpha`` (and segment length bounds) depends on the encoder and the data, and a user has
no ground truth for new demonstrations, but the database's episodes are segmented. Calibration holds
each of a sample of them out in turn (leave-one-episode-out): the rest of the database decomposes
it, for every point of a small grid over ``alpha``, ``min_len`` and ``max_len``, and the
decomposition is scored by mIoU (``rdd.metrics.miou``) against the held-out episode's stored
segmentation. The grid point with the best mean mIoU is chosen; ties keep the paper's setting
(alpha 1, min_len 2, no max_len) when it is among them, else the first in grid order.

Only retrieval depends on the database; it runs once per held-out episode over the widest length
range, and every grid point reuses it (the scores and the DP are cheap).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rdd.core import scoring
from rdd.core.solver import candidate_intervals, max_sum_partition_dense
from rdd.database.model import DatabaseError, SubtaskDatabase
from rdd.errors import InputError
from rdd.index import load_index
from rdd.metrics import miou

log = logging.getLogger(__name__)

CALIBRATION_VERSION = 1
DEFAULT_SAMPLE = 10
DEFAULT_ALPHAS = (0.0, 0.1, 0.25, 0.5, 1.0, 2.0)
DEFAULT_MIN_LENS = (2, 4)
# min_len candidates as fractions of the shortest stored segment
DEFAULT_MIN_LEN_FACTORS = (0.5, 1.0)
# ... and of the median one: an annotation's flicker can store a sub-task far shorter than any real
# one, and a min_len near it lets RDD cut such slivers too (G1, 20 episodes, held out in turn: the
# best min_len was 24-32 frames, 0.45-0.6 of the median segment, where the shortest gave 6-8).
DEFAULT_MIN_LEN_MEDIAN_FACTORS = (0.25, 0.5)
# max_len candidates as multiples of the longest stored segment (None: unbounded).
DEFAULT_MAX_LEN_FACTORS = (None, 1.25, 2.0)
PAPER_POINT = {"alpha": 1.0, "min_len": 2, "max_len": None}


class CalibrationError(InputError):
    """Calibration cannot run on this input (the message names the option or file at fault)."""


def sample_episodes(names: Sequence[str], k: int = DEFAULT_SAMPLE, seed: int = 0) -> list[str]:
    """Up to ``k`` distinct episode names drawn without replacement (seeded), in their given order."""
    unique = list(dict.fromkeys(names))
    if k < 1:
        raise CalibrationError(f"calibration sample size must be >= 1, got {k}")
    if len(unique) <= k:
        return unique
    pick = set(np.random.default_rng(seed).choice(len(unique), size=k, replace=False).tolist())
    return [n for i, n in enumerate(unique) if i in pick]


def default_grid(db: SubtaskDatabase) -> dict[str, list]:
    """The default grid; max_len values are multiples of the database's longest segment, and
    min_len values beyond the fixed ones fractions of its shortest and of its median segment."""
    longest = int(db.durations.max()) + 1
    shortest = int(db.durations.min()) + 1
    median = float(np.median(db.durations)) + 1
    max_lens = sorted({None if f is None else max(2, math.ceil(f * longest))
                       for f in DEFAULT_MAX_LEN_FACTORS}, key=lambda v: (v is not None, v or 0))
    min_lens = sorted(set(DEFAULT_MIN_LENS) | {max(2, int(f * shortest)) for f in DEFAULT_MIN_LEN_FACTORS}
                      | {max(2, int(f * median)) for f in DEFAULT_MIN_LEN_MEDIAN_FACTORS})
    return {"alpha": list(DEFAULT_ALPHAS), "min_len": min_lens, "max_len": max_lens}


def check_grid(grid: Mapping[str, Sequence]) -> dict[str, list]:
    """Validate a grid {alpha, min_len, max_len: values}; raise CalibrationError naming the bad key."""
    out: dict[str, list] = {}
    for key in ("alpha", "min_len", "max_len"):
        if key not in grid:
            raise CalibrationError(f"calibration grid has no {key!r} values")
        values = list(grid[key])
        if not values:
            raise CalibrationError(f"calibration grid {key!r} is empty (give at least one value)")
        for v in values:
            if key == "alpha" and (not isinstance(v, (int, float)) or not math.isfinite(v) or not
                                   0 <= v <= scoring.ALPHA_MAX):
                raise CalibrationError(f"calibration grid 'alpha': {v!r} is not a number >= 0 and "
                                       f"<= {scoring.ALPHA_MAX}", option=key)
            if key == "min_len" and (not isinstance(v, (int, np.integer)) or v < 1):
                raise CalibrationError(f"calibration grid 'min_len': {v!r} is not an integer >= 1", option=key)
            if key == "max_len" and v is not None and (not isinstance(v, (int, np.integer)) or v < 1):
                raise CalibrationError(f"calibration grid 'max_len': {v!r} is not None or an integer >= 1",
                                       option=key)
        out[key] = [None if v is None else (float(v) if key == "alpha" else int(v)) for v in values]
    if not any(m is None or m >= n for n in out["min_len"] for m in out["max_len"]):
        raise CalibrationError("calibration grid: every max_len is below every min_len")
    return out


def _points(grid: dict[str, list]) -> list[dict[str, Any]]:
    pts = [{"alpha": a, "min_len": n, "max_len": m}
           for n in grid["min_len"] for m in grid["max_len"] for a in grid["alpha"]
           if m is None or m >= n]
    if PAPER_POINT not in pts:
        pts.append(dict(PAPER_POINT))  # always scored, as the reference the choice is compared to
    return pts


def partitions(nearest, durations: np.ndarray, fv: np.ndarray, points: Sequence[Mapping[str, Any]]
               ) -> list[list[tuple[int, int]] | None]:
    """RDD's default-mode partition of frame vectors ``fv`` for every point {alpha, min_len, max_len}
    (None where no partition fits its bounds); one retrieval with ``nearest`` (a fitted index over
    entries of ``durations``) serves them all."""
    t = fv.shape[0]
    lo = min(p["min_len"] for p in points)
    if t < lo:
        return [None] * len(points)
    hi = max(lo, max(t if p["max_len"] is None else min(p["max_len"], t) for p in points))
    starts, ends, valid = candidate_intervals(t, lo, hi)
    s, e = starts[valid], ends[valid]
    ids, dist = nearest.search_intervals(fv, s, e)
    length = scoring.length_term(scoring.durations(s, e), durations[ids])
    weight = scoring.weights(s, e)
    out: list[list[tuple[int, int]] | None] = []
    for p in points:
        mn, mx = p["min_len"], t if p["max_len"] is None else min(p["max_len"], t)
        if t < mn or mx < mn:
            out.append(None)
            continue
        dense = np.full(starts.shape, -np.inf)
        dense[valid] = -weight * (dist + p["alpha"] * length)
        try:
            out.append(max_sum_partition_dense(dense[:, mn - lo : mx - lo + 1], mn, mx)[1])
        except ValueError:  # no partition with these bounds
            out.append(None)
    return out


def _held_out_scores(db: SubtaskDatabase, held: str, points: list[dict[str, Any]], index: str,
                     index_options: Mapping[str, Any]) -> list[float]:
    """mIoU of decomposing ``held`` with the rest of the database, for every grid point (0: none fits)."""
    gt = db.episode_segments(held)
    keep = np.array([n != held for n in db.episodes])
    nearest = load_index(index, **dict(index_options)).fit(db.begin[keep], db.end[keep])
    found = partitions(nearest, db.durations[keep], db.frames[held], points)
    return [0.0 if segs is None else miou(segs, gt) for segs in found]


def calibrate(
    db: SubtaskDatabase,
    grid: Mapping[str, Sequence] | None = None,
    sample: int = DEFAULT_SAMPLE,
    seed: int = 0,
    index: str = "exact",
    index_options: Mapping[str, Any] | None = None,
    progress=None,
) -> dict[str, Any] | None:
    """Leave-one-episode-out calibration of alpha/min_len/max_len; the record for the manifest.

    Returns None (with a warning) when the database has only one episode: nothing to leave out.
    Raises CalibrationError for an empty or invalid grid, and when the database keeps no frame
    vectors (built with ``--no-calibrate``): those are needed to decompose held-out episodes.
    """
    grid = check_grid(default_grid(db) if grid is None else grid)
    episodes = list(dict.fromkeys(db.episodes))
    if len(episodes) < 2:
        log.warning("calibration skipped: the database holds one episode (%s), nothing to leave out",
                    episodes[0] if episodes else "none")
        return None
    if not db.frames:
        where = db.directory or "the database"
        raise CalibrationError(
            f"{where} keeps no frame vectors to calibrate on (it was built with --no-calibrate); "
            "rebuild it without --no-calibrate"
        )
    unknown = sorted(set(db.frames) - set(episodes))
    if unknown:
        raise DatabaseError(f"frame vectors kept for episodes without entries: {unknown}")
    held = sample_episodes([n for n in episodes if n in db.frames], sample, seed)
    points = _points(grid)
    per_episode = []
    for name in (progress(held) if progress is not None else held):
        per_episode.append(_held_out_scores(db, name, points, index, index_options or {}))
    scores = np.asarray(per_episode)  # (episodes, points)
    means = scores.mean(axis=0)
    best = float(means.max())
    tied = [i for i, m in enumerate(means) if m == best]
    paper = points.index(PAPER_POINT)
    chosen = paper if paper in tied else tied[0]
    return {
        "version": CALIBRATION_VERSION,
        "metric": "miou",
        "method": "leave-one-episode-out",
        "chosen": dict(points[chosen]),
        "score": float(means[chosen]),
        "paper_setting": {**PAPER_POINT, "score": float(means[paper])},
        "episodes": held,
        "sample": int(sample),
        "seed": int(seed),
        "backend": index,  # the manifest key saved databases have (the index by its older name)
        "grid": grid,
        "results": [{**p, "miou": float(means[i]), "per_episode": [float(x) for x in scores[:, i]]}
                    for i, p in enumerate(points)],
    }


def summary(calibration: Mapping[str, Any]) -> str:
    """One line: the chosen options, their score and the paper setting's score."""
    c, p = calibration["chosen"], calibration["paper_setting"]
    return (f"calibrated on {len(calibration['episodes'])} held-out episodes: alpha={c['alpha']:g} "
            f"min_len={c['min_len']} max_len={c['max_len']} (mIoU {calibration['score']:.3f}; "
            f"paper setting alpha=1 min_len=2 max_len=None: {p['score']:.3f})")
