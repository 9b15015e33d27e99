"""UVD's milestone search (Zhang et al., ICRA 2024): walking backwards over embedding distances.

Matches the official ``embedding_decomp`` of zcczhang/UVD with its default "embed" settings
(kernel smoothing, strict local maxima, ``min_interval`` spacing); read there, written anew here.
Used by the UVD decomposer (``rdd.decomposers.uvd``) and by RDD's OOD prior (``rdd.core.scoring``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _as_float_matrix(embeddings: np.ndarray) -> np.ndarray:
    """The (T, D) array as floats, keeping its float dtype (the official code computes in it)."""
    emb = np.asarray(embeddings)
    if emb.ndim != 2:
        raise ValueError(f"UVD needs a (T, D) embedding array, got shape {emb.shape}")
    if not np.issubdtype(emb.dtype, np.floating):
        emb = emb.astype(np.float64)
    return emb


def kernel_smooth(x: np.ndarray, y: np.ndarray, gamma: float) -> np.ndarray:
    """Nadaraya-Watson regression of ``y`` on ``x`` with RBF weights exp(-gamma (x_i - x)^2)."""
    xf = np.asarray(x, dtype=np.float64)
    # Squared distances of integer positions are exact, so this equals sklearn's rbf_kernel.
    weights = np.exp((xf[:, None] - xf[None, :]) ** 2 * -gamma)
    return (weights * np.asarray(y)[:, None]).sum(axis=0) / weights.sum(axis=0)


def strict_local_maxima(values: np.ndarray) -> np.ndarray:
    """Indices i (end points excluded) with values[i] > values[i-1] and values[i] > values[i+1]."""
    v = np.asarray(values)
    if v.shape[0] < 3:
        return np.zeros(0, dtype=np.int64)
    inner = (v[1:-1] > v[:-2]) & (v[1:-1] > v[2:])
    return np.nonzero(inner)[0] + 1


def uvd_distance_curve(
    embeddings: np.ndarray,
    goal: int,
    gamma: float = 0.08,
    normalize_curve: bool = False,
    window_length: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Frame positions and the smoothed distance-to-goal curve UVD inspects for one backward step."""
    emb = _as_float_matrix(embeddings)
    goal = int(goal)
    if not 0 <= goal < emb.shape[0]:
        raise ValueError(f"goal frame {goal} is outside [0, {emb.shape[0] - 1}]")
    start = max(0, goal - (window_length or goal))
    window = emb[start : goal + 1]
    distances = np.linalg.norm(window - window[-1], axis=1)
    if normalize_curve:
        with np.errstate(divide="ignore", invalid="ignore"):
            distances = distances / np.linalg.norm(window[0] - window[-1])
    x = np.arange(start, goal + 1)
    with np.errstate(invalid="ignore"):
        return x, kernel_smooth(x, distances, gamma)


def uvd_previous_milestone(
    embeddings: np.ndarray,
    goal: int,
    min_interval: int = 18,
    gamma: float = 0.08,
    normalize_curve: bool = False,
    window_length: int | None = None,
) -> int | None:
    """The milestone one backward UVD step from frame ``goal`` finds, or None when there is none.

    The latest strict local maximum p of the smoothed distance-to-goal curve with
    ``goal - p > min_interval`` and ``p > min_interval``.
    """
    x, curve = uvd_distance_curve(embeddings, goal, gamma, normalize_curve, window_length)
    for p in x[strict_local_maxima(curve)][::-1]:
        if int(goal) - int(p) > min_interval and int(p) > min_interval:
            return int(p)
    return None


def _latest_valid_maximum(curves: np.ndarray, ends: np.ndarray, min_interval: int,
                          tol: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row r: the latest strict local maximum p of ``curves[r, :ends[r] + 1]`` with
    ``ends[r] - p > min_interval`` and ``p > min_interval`` (-1 when none), and whether a
    comparison that decides it is within ``tol[r]`` of a tie (then rounding could change it).
    """
    rows, t = curves.shape
    cols = np.arange(t)[None, :]
    diff = np.full((rows, t), np.nan)
    diff[:, 1:] = curves[:, 1:] - curves[:, :-1]  # diff[j] = S[j] - S[j-1]
    up = diff > 0
    down = np.zeros_like(up)
    down[:, :-1] = diff[:, 1:] < 0
    lo, hi = min_interval + 1, ends[:, None] - min_interval - 1  # p in [lo, hi]
    ok = up & down & (cols >= lo) & (cols <= hi)
    found = np.where(ok.any(axis=1), t - 1 - np.argmax(ok[:, ::-1], axis=1), -1)
    # Comparisons S[j] vs S[j-1] for j in [max(found, lo), hi + 1] decide the answer.
    first = np.maximum(found, lo)[:, None]
    examined = (cols >= first) & (cols <= hi + 1)
    close = examined & ~(np.abs(diff) > tol[:, None])  # NaN counts as close
    return found, close.any(axis=1)


def uvd_previous_milestones_all(
    embeddings: np.ndarray,
    end_frames: Sequence[int] | np.ndarray,
    min_interval: int = 18,
    gamma: float = 0.08,
    normalize_curve: bool = False,
    window_length: int | None = None,
    block: int = 256,
) -> dict[int, int | None]:
    """:func:`uvd_previous_milestone` for every goal in ``end_frames`` at once: {goal: milestone}.

    One Gram matrix gives every frame-to-goal distance and the kernel smoother of every goal's
    curve is one matrix product with a cumulative normaliser, O(T^2 D + T^3) in BLAS instead of
    a Python loop of O(T^2) kernels. The only difference from the per-goal computation is float
    rounding, so a goal whose decision rests on a comparison within rounding of a tie is
    recomputed with :func:`uvd_previous_milestone` (the reference), keeping results identical.
    """
    emb = _as_float_matrix(embeddings)
    goals = np.unique(np.asarray(end_frames, dtype=np.int64))
    if goals.size == 0:
        return {}
    t = emb.shape[0]
    if goals[0] < 0 or goals[-1] >= t:
        raise ValueError(f"goal frames must be in [0, {t - 1}], got {goals[0]}..{goals[-1]}")
    out: dict[int, int | None] = {}
    if window_length is not None:  # windowed curves: no shared structure worth exploiting
        for g in goals:
            out[int(g)] = uvd_previous_milestone(emb, int(g), min_interval, gamma, normalize_curve,
                                                 window_length)
        return out
    x = emb.astype(np.float64)
    sq = np.einsum("ij,ij->i", x, x)
    pos = np.arange(t, dtype=np.float64)
    kernel = np.exp((pos[:, None] - pos[None, :]) ** 2 * -gamma)  # (i, j), as kernel_smooth
    norm = np.cumsum(kernel, axis=0)  # norm[g, j] = sum_{i <= g} kernel[i, j]
    recheck = []
    for a in range(0, goals.size, block):
        g = goals[a : a + block]
        d2 = sq[g][:, None] + sq[None, :] - 2.0 * (x[g] @ x.T)
        dist = np.sqrt(np.maximum(d2, 0.0))
        dist[np.arange(g.size), g] = 0.0
        dist[np.arange(t)[None, :] > g[:, None]] = 0.0  # frames after the goal are not in its curve
        with np.errstate(divide="ignore", invalid="ignore"):
            curves = (dist @ kernel) / norm[g]
        curves[np.arange(t)[None, :] > g[:, None]] = np.nan
        if normalize_curve:
            # A positive scale keeps every maximum; a zero first distance makes the curve NaN
            # (no maximum) in the per-goal form, left to the reference below.
            scale_zero = np.linalg.norm(emb[0][None, :] - emb[g], axis=1) == 0  # as the per-goal form
        else:
            scale_zero = np.zeros(g.size, dtype=bool)
        peak = np.nanmax(np.abs(curves), axis=1, initial=0.0)
        # Measured gap to the per-goal curves: ~4e-8 of the peak for float32 embeddings (their
        # distances are float32 there), ~1e-14 for float64; the margin is about 70x.
        tol = max(20.0 * float(np.finfo(emb.dtype).eps), 1e-12) * peak + 1e-300
        found, close = _latest_valid_maximum(curves, g, int(min_interval), tol)
        for gi, f, c, z in zip(g, found, close, scale_zero, strict=True):
            if c or z:
                recheck.append(int(gi))
            else:
                out[int(gi)] = None if f < 0 else int(f)
    for gi in recheck:
        out[gi] = uvd_previous_milestone(emb, gi, min_interval, gamma, normalize_curve, None)
    return out


def uvd_milestones(
    embeddings: np.ndarray,
    min_interval: int = 18,
    gamma: float = 0.08,
    normalize_curve: bool = False,
    window_length: int | None = None,
) -> list[int]:
    """UVD milestones of a (T, D) embedding sequence, ascending, always ending at T-1."""
    emb = _as_float_matrix(embeddings)
    if emb.shape[0] == 0:
        raise ValueError("UVD needs at least one frame")
    goal = emb.shape[0] - 1
    milestones = [goal]
    while goal > (window_length or min_interval):
        previous = uvd_previous_milestone(
            emb, goal, min_interval, gamma, normalize_curve, window_length
        )
        if previous is None:
            break
        goal = previous
        milestones.append(goal)
        if goal < min_interval:
            break
    return milestones[::-1]
