"""The retrieval interface: a batch of interval vectors in, nearest entry ids and angular distances out."""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path

import numpy as np

from rdd.checks import CheckedOptions
from rdd.geometry import check_intervals, cosine_to_angular

ROWS_AT_ONCE = 4096  # rows widened to float64 at a time: the sums are the same, no (N, D) float64 copy


def row_sq_norms64(x: np.ndarray, einsum: bool = True) -> np.ndarray:
    """(N,) float64 squared norms of the rows of ``x``, summed in float64 a block of rows at a time
    (``einsum=False``: as ``(x ** 2).sum(1)``, whose last bits differ; each caller keeps its own)."""
    out = np.empty(x.shape[0], dtype=np.float64)
    for i in range(0, x.shape[0], ROWS_AT_ONCE):
        block = x[i:i + ROWS_AT_ONCE].astype(np.float64)
        out[i:i + ROWS_AT_ONCE] = np.einsum("ij,ij->i", block, block) if einsum else (block ** 2).sum(1)
    return out


def _as_pair(begin: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    b = np.ascontiguousarray(begin, dtype=np.float32)
    e = np.ascontiguousarray(end, dtype=np.float32)
    if b.ndim != 2 or b.shape != e.shape:
        raise ValueError(f"begin and end must be (N, D) arrays of one shape, got {b.shape} and {e.shape}")
    if b.shape[0] == 0:
        raise ValueError("cannot build an index over an empty database")
    return b, e


class NearestIndex(CheckedOptions, ABC):
    """Nearest database entry under angular distance on interval vectors ``concat(begin, end)``.

    Its options' ranges are its ``OPTION_RULES`` (checked by the constructor and ``check_options``).
    """

    name: str = "index"
    OPTION_KIND = "index"

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

        ``cache_dir``/``key``: where an index may save its built form (beside the database) and the
        identity of the data it was built from; indexes without a saved form ignore them.
        """
        b, e = _as_pair(begin, end)
        self.num_entries, self.frame_dim = b.shape
        end_norm = np.sqrt(row_sq_norms64(e))
        if (end_norm == 0).any():
            raise ValueError(f"{self.name} index: a database end-frame vector is zero "
                             "(angular distance undefined)")
        # For search_ends: a reference to the end vectors (no copy) and their inverse norms.
        self._raw_end, self._end_inv_norm = e, (1.0 / end_norm).astype(np.float32)
        self._fit(b, e, None if cache_dir is None else Path(cache_dir), key)
        return self

    @abstractmethod
    def _fit(self, begin: np.ndarray, end: np.ndarray, cache_dir: Path | None, key: str | None) -> None:
        """Index-specific build."""

    @abstractmethod
    def _search(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Index-specific search over validated (Q, 2D) float32 queries."""

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

        The default builds interval vectors chunk by chunk and calls ``search``; indexes that can use
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

    def search_ends(self, frame_vectors: np.ndarray, memory_mb: int = 256) -> tuple[np.ndarray, np.ndarray]:
        """Entry whose end-frame vector is nearest to each frame (paper Eq. 3.5's OOD retrieval).

        Returns ids (T,) and angular distances (T,) over the end-frame vectors alone. Exact for
        every index: T queries only, one chunked (T, D) x (D, N) product.
        """
        if self.num_entries == 0:
            raise RuntimeError(f"{self.name} index: call fit() before search_ends()")
        fv = np.asarray(frame_vectors, dtype=np.float32)
        if fv.ndim != 2 or fv.shape[1] != self.frame_dim:
            raise ValueError(f"{self.name} index: frame vectors must be (T, {self.frame_dim}), got {fv.shape}")
        norm = np.linalg.norm(fv.astype(np.float64), axis=1)
        if (norm == 0).any() or not np.isfinite(norm).all():
            raise ValueError(f"{self.name} index: a frame vector is zero, NaN or inf")
        q = (fv / norm[:, None]).astype(np.float32)
        best = np.full(q.shape[0], -np.inf, dtype=np.float32)
        nc = max(1, (memory_mb << 20) // (4 * max(q.shape[0], 1)))
        rows = np.arange(q.shape[0])
        shortlist = self._end_shortlist(q)  # entry ids that may be nearest (None: all)
        total = self.num_entries if shortlist is None else shortlist.size
        # float32 products err by up to ~1e-5 in cosine; near an exact match that is a visible
        # angular distance (sqrt), so every entry within `tol` of a row's float32 best is rescored
        # in float64 and the best of those wins (lowest id among exact ties).
        tol = 1e-4
        cand_rows, cand_cols = [], []
        for c in range(0, total, nc):
            cols = np.arange(c, min(c + nc, total)) if shortlist is None else shortlist[c : c + nc]
            dots = q @ (self._raw_end[c : c + nc] if shortlist is None else self._raw_end[cols]).T
            dots *= self._end_inv_norm[cols]
            best = np.maximum(best, dots.max(axis=1))
            r, k = np.nonzero(dots >= (best - tol)[:, None])
            cand_rows.append(r)
            cand_cols.append(cols[k])
        r, k = np.concatenate(cand_rows), np.concatenate(cand_cols)
        qd = fv[r].astype(np.float64) / norm[r, None]
        ed = self._raw_end[k].astype(np.float64)
        cos = np.einsum("ij,ij->i", qd, ed) / np.linalg.norm(ed, axis=1)
        order = np.lexsort((k, -cos, r))  # per row: highest cosine first, then lowest id
        first = np.ones(order.size, dtype=bool)
        first[1:] = r[order][1:] != r[order][:-1]
        pick = order[first]
        best_id = np.zeros(q.shape[0], dtype=np.int64)
        best_cos = np.full(q.shape[0], -1.0)
        best_id[r[pick]], best_cos[r[pick]] = k[pick], cos[pick]
        assert (np.bincount(r[pick], minlength=rows.size) == 1).all()
        return best_id, cosine_to_angular(best_cos)

    def _end_shortlist(self, unit_frames: np.ndarray) -> np.ndarray | None:
        """Ascending ids of the entries that may hold some frame's nearest end (None: every entry).

        Indexes with bounds on end-frame cosines override it; the result must contain every
        frame's nearest entry, and every entry within float32 rounding of it.
        """
        return None


def interval_matrix(begin: np.ndarray, end: np.ndarray, normalize: bool = True) -> np.ndarray:
    """(N, 2D) interval vectors ``concat(begin, end)``, unit-normalised when ``normalize``."""
    x = np.concatenate([begin, end], axis=1).astype(np.float32)
    if normalize:
        norm = np.linalg.norm(x, axis=1, keepdims=True)
        if (norm == 0).any():
            raise ValueError("a database interval vector is zero (angular distance undefined)")
        x /= norm
    return x
