"""Exact maximum-sum partition of ``[0, n)`` into half-open segments with length bounds.

Two forms share one recurrence ``best[e] = max_l best[e - l] + score(e - l, e)`` over lengths
``min_len <= l <= max_len``:

* :func:`max_sum_partition` takes a score callable (reference form, any scores);
* :func:`max_sum_partition_dense` takes every candidate score in one array laid out by
  :func:`candidate_intervals` (the fast path: one vectorised max per end frame).

Ties are broken towards the shorter last segment in both forms, so they return the same partition.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rdd.segments import Segment


def _check_bounds(n: int, min_len: int, max_len: int | None) -> int:
    """Validate the arguments and return the effective upper bound on segment length."""
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer number of frames, got {n!r}")
    if int(min_len) != min_len or min_len < 1:
        raise ValueError(f"min_len must be an integer >= 1, got {min_len!r}")
    hi = int(n) if max_len is None else int(max_len)
    if max_len is not None and (int(max_len) != max_len or max_len < min_len):
        raise ValueError(f"max_len must be None or an integer >= min_len={min_len}, got {max_len!r}")
    if n < min_len:
        raise ValueError(
            f"no valid partition: n={n} frames is shorter than min_len={min_len}"
        )
    return min(hi, int(n))


def _no_partition_error(n: int, min_len: int, max_len: int | None) -> ValueError:
    return ValueError(
        f"no valid partition of {n} frames into segments of length in "
        f"[{min_len}, {max_len if max_len is not None else n}]"
    )


def max_sum_partition(
    n: int,
    score: Callable[[int, int], float],
    min_len: int = 2,
    max_len: int | None = None,
) -> tuple[float, list[Segment]]:
    """Maximise ``sum score(start, end)`` over partitions of ``[0, n)`` with bounded segment lengths."""
    hi = _check_bounds(n, min_len, max_len)
    best = np.full(n + 1, -np.inf)
    best[0] = 0.0
    back = np.zeros(n + 1, dtype=np.int64)
    for end in range(min_len, n + 1):
        for length in range(min_len, min(hi, end) + 1):
            prev = best[end - length]
            if prev == -np.inf:
                continue
            value = prev + float(score(end - length, end))
            # strict '>' keeps the shortest length among ties (same rule as the dense form)
            if value > best[end]:
                best[end] = value
                back[end] = length
    if best[n] == -np.inf:
        raise _no_partition_error(n, min_len, max_len)
    return float(best[n]), _backtrack(back, n)


def _backtrack(back: np.ndarray, n: int) -> list[Segment]:
    segments: list[Segment] = []
    end = n
    while end > 0:
        start = end - int(back[end])
        segments.append((start, end))
        end = start
    segments.reverse()
    return segments


def candidate_intervals(
    n: int, min_len: int = 2, max_len: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense layout of all candidate segments: ``(starts, ends, valid)``, each of shape (n, K).

    Row ``r`` holds segments ending at ``end = r + 1``; column ``j`` has length ``min_len + j``, with
    ``K = max_len - min_len + 1``. ``valid`` is False where the segment would start before frame 0.
    """
    hi = _check_bounds(n, min_len, max_len)
    ends = np.arange(1, n + 1, dtype=np.int64)[:, None]
    lengths = np.arange(min_len, hi + 1, dtype=np.int64)[None, :]
    starts = ends - lengths
    valid = starts >= 0
    ends = np.broadcast_to(ends, starts.shape).copy()
    return starts, ends, valid


def max_sum_partition_dense(
    scores: np.ndarray, min_len: int = 2, max_len: int | None = None
) -> tuple[float, list[Segment]]:
    """Same optimum as :func:`max_sum_partition`, scores given as an (n, K) array (see ``candidate_intervals``).

    Entries for invalid candidates (start < 0) are ignored; ``-inf`` marks a forbidden segment.
    """
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2:
        raise ValueError(f"scores must be a 2-D (n, K) array, got shape {scores.shape}")
    n = scores.shape[0]
    hi = _check_bounds(n, min_len, max_len)
    k = hi - min_len + 1
    if scores.shape[1] != k:
        raise ValueError(
            f"scores has {scores.shape[1]} columns but lengths {min_len}..{hi} need K={k}"
        )
    if np.isnan(scores).any():
        raise ValueError("scores contain NaN")
    best = np.full(n + 1, -np.inf)
    best[0] = 0.0
    back = np.zeros(n + 1, dtype=np.int64)
    for end in range(min_len, n + 1):
        kk = min(k, end - min_len + 1)  # lengths min_len .. min(hi, end)
        # best[end - l] for l = min_len .. min_len + kk - 1, i.e. a reversed slice of best
        prev = best[end - min_len - kk + 1 : end - min_len + 1][::-1]
        cand = prev + scores[end - 1, :kk]
        j = int(np.argmax(cand))  # first maximum -> shortest length among ties
        best[end] = cand[j]
        back[end] = min_len + j
    if best[n] == -np.inf:
        raise _no_partition_error(n, min_len, max_len)
    return float(best[n]), _backtrack(back, n)
