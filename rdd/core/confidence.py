"""How much to trust each segment of an RDD decomposition, calibrated on the database itself.

Two things make a segment trustworthy, and a segment's **confidence** (in [0, 1]) is their product:

* **Agreement.** The database's calibration (``rdd.core.calibrate``) scored a grid of settings by
  decomposing its own episodes, each held out in turn; several settings come close to the best.
  The episode is decomposed again at the ``NEAR_BEST`` best of them (one retrieval serves all), and a
  segment's agreement is the mean, over those partitions, of its best IoU with their segments: a cut
  that every near-best setting also makes does not hang on one choice of alpha or min_len. (A
  database without a calibration: the calibration's alphas at the decomposer's own length bounds.)
* **Match.** A segment is explained by its nearest database entry; it is doubtful when that entry
  is far (angular distance of the interval vectors) or of another length (``|log(dur / dur_nn)|``:
  half or twice the match's length is as suspicious either way). The sum of the two, its cost, is
  read against the database's own matches: every entry (up to ``REFERENCE_SAMPLE``, seeded) matched,
  leave-one-episode-out, to its nearest entry of another episode. Its match score is the fraction of
  those reference costs at least its own (ties half), and it scales the agreement from 0.5 (a match
  worse than all of the database's own) to 1.

Measured (docs/review.md): AUROC of confidence against segments with best IoU < 0.5 on RLBench
open_drawer leave-one-out and on Unitree G1 episodes against the hand rule.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rdd import geometry
from rdd.core import scoring
from rdd.core.calibrate import DEFAULT_ALPHAS, partitions
from rdd.database.model import SubtaskDatabase
from rdd.metrics import segment_iou

# Episodes with a segment below this confidence are the ones to look at. Chosen by measurement
# (docs/review.md): it flags most episodes with a doubtful segment, few others.
REVIEW_BELOW = 0.5

REFERENCE_SAMPLE = 2000
NEAR_BEST = 5
# Rows of the (sample, N) cosine matrix computed at once: bounds memory on large databases.
CHUNK = 256
# One reference per loaded database, made on its first decomposition, gone with the database.
_REFERENCES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def match_cost(distance, query_durations, neighbour_durations) -> np.ndarray:
    """A match's cost: angular distance plus ``|log(dur / dur_nn)|`` (durations clamped to >= 1)."""
    q = np.maximum(np.asarray(query_durations, dtype=np.float64), 1.0)
    n = np.maximum(np.asarray(neighbour_durations, dtype=np.float64), 1.0)
    return np.asarray(distance, dtype=np.float64) + np.abs(np.log(q / n))


@dataclass(frozen=True)
class ConfidenceReference:
    """The sorted costs of the database's own leave-one-episode-out matches."""

    costs: np.ndarray

    def confidence(self, costs: Sequence[float] | np.ndarray) -> list[float]:
        """Per cost, the fraction of reference costs >= it (ties half): a number in [0, 1]."""
        c = np.asarray(costs, dtype=np.float64)
        ref = self.costs
        if ref.size == 0:
            return [0.5] * int(c.size)  # nothing to compare with: neither trusted nor doubted
        below = np.searchsorted(ref, c, side="left")
        above = ref.size - np.searchsorted(ref, c, side="right")
        return [float(x) for x in (above + 0.5 * (ref.size - below - above)) / ref.size]


def reference(db: SubtaskDatabase, sample: int = REFERENCE_SAMPLE, seed: int = 0) -> ConfidenceReference:
    """Each sampled entry matched to its nearest entry of another episode (of another entry, when
    the database names no episodes or holds one), the match's :func:`match_cost` each."""
    n = len(db)
    if n < 2:
        return ConfidenceReference(np.zeros(0))
    vectors = db.interval_vectors().astype(np.float32)
    vectors /= np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-12)
    episodes = np.asarray(db.episodes, dtype=object)
    several = len(set(db.episodes)) > 1
    rows = np.arange(n) if n <= sample else np.sort(np.random.default_rng(seed).choice(n, sample, replace=False))
    costs = []
    for lo in range(0, rows.size, CHUNK):
        part = rows[lo:lo + CHUNK]
        cos = vectors[part] @ vectors.T
        same = episodes[part][:, None] == episodes[None, :] if several else np.eye(n, dtype=bool)[part]
        cos[same] = -np.inf
        nearest = np.argmax(cos, axis=1)
        dist = geometry.cosine_to_angular(cos[np.arange(part.size), nearest])
        costs.append(match_cost(dist, db.durations[part], db.durations[nearest]))
    return ConfidenceReference(np.sort(np.concatenate(costs)))


def match_scores(ref: ConfidenceReference, db: SubtaskDatabase, frame_vectors: np.ndarray,
                 segments: Sequence[tuple[int, int]], entries: Sequence[int]) -> list[float]:
    """Each segment's match to database entry ``entries[k]`` read against ``ref``, in [0, 1].

    The distance is always that of the interval vectors (also in the OOD mode, whose retrieval
    compares end frames only), so every segment is on the reference's scale."""
    s = np.array([int(a) for a, _ in segments])
    e = np.array([int(b) for _, b in segments])
    ids = np.asarray(entries, dtype=np.int64)
    query = geometry.interval_vectors(frame_vectors, s, e)
    dist = geometry.angular_distance(query, np.concatenate([db.begin[ids], db.end[ids]], axis=1))
    return ref.confidence(match_cost(dist, scoring.durations(s, e), db.durations[ids]))


def near_best_points(db: SubtaskDatabase, min_len: int, max_len: int | None) -> list[dict]:
    """The ``NEAR_BEST`` settings with the best held-out mIoU in the database's calibration (grid
    order breaks ties); without one, the calibration's alphas at ``min_len``/``max_len``."""
    results = (db.meta.get("calibration") or {}).get("results") or []
    if results:
        ranked = sorted(results, key=lambda r: -float(r["miou"]))[:NEAR_BEST]
        return [{"alpha": float(r["alpha"]), "min_len": int(r["min_len"]), "max_len": r["max_len"]} for r in ranked]
    return [{"alpha": a, "min_len": min_len, "max_len": max_len} for a in DEFAULT_ALPHAS]


def agreement(segments: Sequence[tuple[int, int]], others: Sequence[Sequence[tuple[int, int]] | None]
              ) -> list[float]:
    """Per segment, the mean over ``others`` of its best IoU with their segments (None counts 0)."""
    return [float(np.mean([max((segment_iou(seg, o) for o in other), default=0.0) if other else 0.0
                           for other in others])) if others else 1.0 for seg in segments]


def for_segments(db: SubtaskDatabase, index, frame_vectors: np.ndarray, segments: Sequence[tuple[int, int]],
                 entries: Sequence[int], min_len: int, max_len: int | None) -> list[float]:
    """Each segment's confidence: agreement x (0.5 + 0.5 x match score), ``index`` fitted on ``db``."""
    ref = _REFERENCES.get(db)
    if ref is None:
        ref = _REFERENCES[db] = reference(db)
    fv = np.asarray(frame_vectors, dtype=np.float32)
    others = partitions(index, db.durations, fv, near_best_points(db, min_len, max_len))
    match = match_scores(ref, db, fv, segments, entries)
    return [a * (0.5 + 0.5 * m) for a, m in zip(agreement(segments, others), match, strict=True)]
