"""Interval vectors and the angular distance: the conventions retrieval (``rdd.index``) and scoring
(``rdd.core.scoring``) share (docs/architecture.md).

An interval ``[start, end)`` of a demonstration's (T, D) frame vectors has the vector
``concat(frame[start], frame[end - 1])``; distance is angular, ``sqrt(2 (1 - cos))``.
"""

from __future__ import annotations

import numpy as np


def _as_index_array(x, name: str) -> np.ndarray:
    arr = np.asarray(x)
    if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{name} must be a 1-D integer array, got dtype {arr.dtype} shape {arr.shape}")
    return arr.astype(np.int64)


def check_intervals(num_frames: int, starts, ends) -> tuple[np.ndarray, np.ndarray]:
    """Validate half-open intervals ``[start, end)`` inside ``[0, num_frames)``; return int arrays."""
    s = _as_index_array(starts, "starts")
    e = _as_index_array(ends, "ends")
    if s.shape != e.shape:
        raise ValueError(f"starts and ends differ in length: {s.shape} vs {e.shape}")
    if s.size and (s.min() < 0 or e.max() > num_frames or (e <= s).any()):
        bad = np.nonzero((s < 0) | (e > num_frames) | (e <= s))[0][0]
        raise ValueError(
            f"interval [{s[bad]}, {e[bad]}) is empty or outside [0, {num_frames})"
        )
    return s, e


def interval_vectors(frame_vectors: np.ndarray, starts, ends) -> np.ndarray:
    """(N, 2D) interval vectors ``concat(frame[start], frame[end - 1])`` of intervals ``[start, end)``."""
    fv = np.asarray(frame_vectors, dtype=np.float32)
    if fv.ndim != 2:
        raise ValueError(f"frame_vectors must be (T, D), got shape {fv.shape}")
    s, e = check_intervals(fv.shape[0], starts, ends)
    return np.concatenate([fv[s], fv[e - 1]], axis=1)


def cosine_to_angular(cos: np.ndarray) -> np.ndarray:
    """Angular distance ``sqrt(2 (1 - cos))`` (cosine clipped to [-1, 1] against rounding)."""
    cos = np.clip(np.asarray(cos, dtype=np.float64), -1.0, 1.0)
    return np.sqrt(2.0 * (1.0 - cos))


def angular_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise angular distance between ``a`` and ``b`` (broadcast over leading axes)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    na = np.linalg.norm(a, axis=-1)
    nb = np.linalg.norm(b, axis=-1)
    if (na == 0).any() or (nb == 0).any():
        raise ValueError("angular distance is undefined for a zero vector")
    return cosine_to_angular(np.sum(a * b, axis=-1) / (na * nb))
