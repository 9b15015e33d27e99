"""The retrieval interface: a batch of interval vectors in, nearest entry ids and angular distances out."""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path

import numpy as np

from rdd.scoring import check_intervals


def _as_pair(begin: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    b = np.ascontiguousarray(begin, dtype=np.float32)
    e = np.ascontiguousarray(end, dtype=np.float32)
    if b.ndim != 2 or b.shape != e.shape:
        raise ValueError(f"begin and end must be (N, D) arrays of one shape, got {b.shape} and {e.shape}")
    if b.shape[0] == 0:
        raise ValueError("cannot build an index over an empty database")
    return b, e


class NearestIndex(ABC):
    """Nearest database entry under angular distance on interval vectors ``concat(begin, end)``."""

    name: str = "index"

    def __init__(self) -> None:
        self.num_entries = 0
        self.frame_dim = 0

    def fit(
        self,
        begin: np.ndarray,
        end: np.ndarray,
        cache_dir: str | Path | None = None,
        key: str | None = None,
    ) -> NearestIndex:
        """Index the entries' begin and end frame vectors (N, D) each; return self.

        ``cache_dir``/``key``: where a backend may save its built index (beside the database) and the
        identity of the data it was built from; backends without a saved form ignore them.
        """
        b, e = _as_pair(begin, end)
        self.num_entries, self.frame_dim = b.shape
        self._fit(b, e, None if cache_dir is None else Path(cache_dir), key)
        return self

    @abstractmethod
    def _fit(self, begin: np.ndarray, end: np.ndarray, cache_dir: Path | None, key: str | None) -> None:
        """Backend-specific build."""

    @abstractmethod
    def _search(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Backend-specific search over validated (Q, 2D) float32 queries."""

    def search(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest entry id (Q,) int64 and its angular distance (Q,) float64 for (Q, 2D) interval vectors."""
        if self.num_entries == 0:
            raise RuntimeError(f"{self.name} index: call fit() before search()")
        q = np.ascontiguousarray(queries, dtype=np.float32)
        if q.ndim != 2 or q.shape[1] != 2 * self.frame_dim:
            raise ValueError(
                f"{self.name} index: queries must be (Q, {2 * self.frame_dim}) interval vectors, got {q.shape}"
            )
        if q.shape[0] == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float64)
        if not np.isfinite(q).all():
            raise ValueError(f"{self.name} index: queries contain NaN or inf")
        if (np.linalg.norm(q, axis=1) == 0).any():
            raise ValueError(f"{self.name} index: a query interval vector is zero (angular distance undefined)")
        return self._search(q)

    def search_intervals(
        self, frame_vectors: np.ndarray, starts, ends, chunk: int = 8192
    ) -> tuple[np.ndarray, np.ndarray]:
        """Nearest entries of intervals ``[start, end)`` of one demonstration's (T, D) frame vectors.

        The default builds interval vectors chunk by chunk and calls ``search``; backends that can use
        the concat(begin, end) structure override it.
        """
        fv = np.asarray(frame_vectors, dtype=np.float32)
        if fv.ndim != 2 or fv.shape[1] != self.frame_dim:
            raise ValueError(
                f"{self.name} index: frame vectors must be (T, {self.frame_dim}), got {fv.shape}"
            )
        s, e = check_intervals(fv.shape[0], starts, ends)
        ids = np.empty(s.shape[0], dtype=np.int64)
        dists = np.empty(s.shape[0], dtype=np.float64)
        for a in range(0, s.shape[0], chunk):
            sl = slice(a, a + chunk)
            q = np.concatenate([fv[s[sl]], fv[e[sl] - 1]], axis=1)
            ids[sl], dists[sl] = self.search(q)
        return ids, dists


def interval_matrix(begin: np.ndarray, end: np.ndarray, normalize: bool = True) -> np.ndarray:
    """(N, 2D) interval vectors ``concat(begin, end)``, unit-normalised when ``normalize``."""
    x = np.concatenate([begin, end], axis=1).astype(np.float32)
    if normalize:
        norm = np.linalg.norm(x, axis=1, keepdims=True)
        if (norm == 0).any():
            raise ValueError("a database interval vector is zero (angular distance undefined)")
        x /= norm
    return x
