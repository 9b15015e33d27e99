"""RDD interval scoring: weights, durations, similarities (paper Eq. 3.4, 3.5), the UVD prior, novelty.

Conventions (docs/architecture.md): an interval ``[start, end)`` has weight ``end - start`` and
duration ``end - 1 - start``; its vector and the angular distance are :mod:`rdd.geometry`'s.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.core.milestones import uvd_previous_milestones_all


def weights(starts, ends) -> np.ndarray:
    """Segment weights ``end - start`` (the number of frames)."""
    return np.asarray(ends, dtype=np.float64) - np.asarray(starts, dtype=np.float64)


def durations(starts, ends) -> np.ndarray:
    """Segment durations ``end - 1 - start`` used by the length term."""
    return weights(starts, ends) - 1.0


def length_term(query_durations, neighbour_durations) -> np.ndarray:
    """``|1 - dur(I) / dur(I_nn)|``; a one-frame neighbour (duration 0) counts as duration 1.

    A database entry of a single frame has duration 0 under the convention of
    docs/architecture.md; clamping it to 1 keeps the ratio finite instead of making every query that matches it infinitely bad.
    """
    q = np.asarray(query_durations, dtype=np.float64)
    nn = np.maximum(np.asarray(neighbour_durations, dtype=np.float64), 1.0)
    return np.abs(1.0 - q / nn)


# The largest accepted alpha: beyond it the length term outweighs any distance (at most 2) a
# million times over, so the ranking is by length alone, and alpha * length * weight heads for
# float overflow (alpha=1e308 made every score -inf: "no valid partition").
ALPHA_MAX = 1e6


def default_similarity(distance, query_durations, neighbour_durations, alpha: float) -> np.ndarray:
    """Paper Eq. 3.4: ``-[dist(V(I), V(I_nn)) + alpha * |1 - dur(I) / dur(I_nn)|]``."""
    return -(np.asarray(distance, dtype=np.float64) + float(alpha) * length_term(query_durations, neighbour_durations))


def uvd_prior(starts, ends, milestone_of_end) -> np.ndarray:
    """``G(I) = -|start - m(e)| / weight(I)``; ``milestone_of_end[end - 1]`` holds m(e) per end frame."""
    s = np.asarray(starts, dtype=np.int64)
    e = np.asarray(ends, dtype=np.int64)
    m = np.asarray(milestone_of_end, dtype=np.float64)[e - 1]
    return -np.abs(s - m) / weights(s, e)


def ood_similarity(end_distance, starts, ends, milestone_of_end, beta: float) -> np.ndarray:
    """Paper Eq. 3.5: ``-dist(E(o_end), E(o_end_nn)) + beta * G(I)``."""
    return -np.asarray(end_distance, dtype=np.float64) + float(beta) * uvd_prior(starts, ends, milestone_of_end)


def uvd_milestones_per_end(
    frame_vectors: np.ndarray,
    end_frames: Sequence[int] | np.ndarray,
    min_interval: int = 18,
    gamma: float = 0.08,
    normalize_curve: bool = False,
    window_length: int | None = None,
) -> np.ndarray:
    """m(e) for every frame e in ``end_frames``: one backward UVD step from e (0 when UVD finds none).

    Returns a (T,) array (NaN for frames not asked for). All end frames share one Gram matrix and
    one kernel product (``uvd_previous_milestones_all``), equal to one UVD step per end frame.
    """
    fv = np.asarray(frame_vectors)
    out = np.full(fv.shape[0], np.nan)
    found = uvd_previous_milestones_all(
        fv, end_frames, min_interval=min_interval, gamma=gamma,
        normalize_curve=normalize_curve, window_length=window_length,
    )
    for e, m in found.items():
        out[e] = 0.0 if m is None else float(m)
    return out


def interval_scores(similarity, starts, ends) -> np.ndarray:
    """``J(I) = weight(I) * sim(I, I_nn)``."""
    return weights(starts, ends) * np.asarray(similarity, dtype=np.float64)


def novelty(segment_scores: Sequence[float] | np.ndarray) -> float:
    """Delta: the mean interval score of a partition's segments (paper Sec. 3.3)."""
    arr = np.asarray(segment_scores, dtype=np.float64)
    if arr.size == 0:
        raise ValueError("novelty needs at least one segment score")
    return float(arr.mean())
