"""Exact nearest neighbours by cosine, factorised over the interval's begin and end frames.

For an interval vector ``q = concat(qb, qe)`` and an entry ``x = concat(xb, xe)``,
``q . x = qb . xb + qe . xe``. Over one demonstration every begin (end) frame is shared by many
candidate intervals, so two (T, D) x (D, N) matrix products give every candidate's dot product
with every entry as a sum of two looked-up rows; a max over the database finishes the search.
The database is processed in chunks so memory stays bounded for a million entries.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from rdd.index.base import NearestIndex
from rdd.scoring import check_intervals, cosine_to_angular


class ExactIndex(NearestIndex):
    """Brute-force exact search (no approximation), vectorised over candidate intervals."""

    name = "exact"

    def __init__(self, memory_mb: int = 256, threads: int | None = None) -> None:
        super().__init__()
        if memory_mb <= 0:
            raise ValueError(f"exact index: memory_mb must be positive, got {memory_mb}")
        if threads is not None and threads < 1:
            raise ValueError(f"exact index: threads must be None or >= 1, got {threads}")
        self.memory_mb = int(memory_mb)
        # numpy releases the GIL in add/argmax, so plain threads share the max-over-database work.
        self.threads = int(threads) if threads is not None else min(2, os.cpu_count() or 1)

    def _fit(self, begin: np.ndarray, end: np.ndarray, cache_dir: Path | None, key: str | None) -> None:
        norm = np.sqrt((begin.astype(np.float64) ** 2).sum(1) + (end.astype(np.float64) ** 2).sum(1))
        if (norm == 0).any():
            raise ValueError("exact index: a database interval vector is zero (angular distance undefined)")
        # Entries pre-scaled to unit interval norm: a query's dot product with them is its cosine
        # times its own norm, so the argmax over entries needs no per-pair division.
        inv = (1.0 / norm).astype(np.float32)[:, None]
        self._begin = np.ascontiguousarray(begin * inv)
        self._end = np.ascontiguousarray(end * inv)

    def _chunk_entries(self, rows: int) -> int:
        """Entries per database chunk so that ``rows`` float32 rows per entry fit the memory budget."""
        return max(1, (self.memory_mb << 20) // (4 * max(rows, 1)))

    def _search(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = self.frame_dim
        qn = np.linalg.norm(queries.astype(np.float64), axis=1)
        q = (queries / qn[:, None]).astype(np.float32)
        best = np.full(q.shape[0], -np.inf, dtype=np.float32)
        best_id = np.zeros(q.shape[0], dtype=np.int64)
        qc = max(1, min(q.shape[0], 4096))
        nc = self._chunk_entries(qc)
        for a in range(0, q.shape[0], qc):
            qb, qe = q[a : a + qc, :d], q[a : a + qc, d:]
            for c in range(0, self.num_entries, nc):
                dots = qb @ self._begin[c : c + nc].T
                dots += qe @ self._end[c : c + nc].T
                self._update(dots, c, best, best_id, slice(a, a + qc))
        return best_id, cosine_to_angular(best)

    @staticmethod
    def _update(dots: np.ndarray, offset: int, best: np.ndarray, best_id: np.ndarray, rows) -> None:
        """Fold one database chunk's (Q, Nc) dot products into the running best per query."""
        idx = dots.argmax(axis=1)
        val = dots[np.arange(dots.shape[0]), idx]
        cur = best[rows]
        better = val > cur  # strict: the lowest entry id wins ties, as in one argmax over all
        cur[better] = val[better]
        best[rows] = cur
        ids = best_id[rows]
        ids[better] = idx[better] + offset
        best_id[rows] = ids

    def search_intervals(
        self, frame_vectors: np.ndarray, starts, ends, chunk: int = 8192
    ) -> tuple[np.ndarray, np.ndarray]:
        """Exact nearest entries of intervals ``[start, end)`` of (T, D) frame vectors, in one pass."""
        fv = np.asarray(frame_vectors, dtype=np.float32)
        if self.num_entries == 0:
            raise RuntimeError("exact index: call fit() before search_intervals()")
        if fv.ndim != 2 or fv.shape[1] != self.frame_dim:
            raise ValueError(f"exact index: frame vectors must be (T, {self.frame_dim}), got {fv.shape}")
        s, e = check_intervals(fv.shape[0], starts, ends)
        if s.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float64)
        if not np.isfinite(fv).all():
            raise ValueError("exact index: frame vectors contain NaN or inf")
        sq = (fv.astype(np.float64) ** 2).sum(1)
        qnorm = np.sqrt(sq[s] + sq[e - 1])
        if (qnorm == 0).any():
            raise ValueError("exact index: a query interval vector is zero (angular distance undefined)")

        # Group candidates by start frame; within a group, sorted ends usually form a run, so the
        # end-frame rows are a contiguous slice (a view, no gather).
        order = np.lexsort((e, s))
        s_sorted, e_sorted = s[order], e[order]
        cuts = np.flatnonzero(np.diff(s_sorted)) + 1
        groups = np.split(np.arange(order.size), cuts)
        t = fv.shape[0]
        longest = max(g.size for g in groups)
        # Two (T, Nc) product matrices plus one (longest, Nc) work buffer per database chunk.
        nc = self._chunk_entries(2 * t + longest)
        best = np.full(order.size, -np.inf, dtype=np.float32)
        best_id = np.zeros(order.size, dtype=np.int64)
        workers = min(self.threads, len(groups))
        # Contiguous halves of the groups per thread: each writes its own slice of best/best_id.
        parts = [p for p in np.array_split(np.arange(len(groups)), workers) if p.size]
        bufs = [np.empty((longest, min(nc, self.num_entries)), dtype=np.float32) for _ in parts]

        def run(part: np.ndarray, buf: np.ndarray, c: int, sb: np.ndarray, se: np.ndarray) -> None:
            width = sb.shape[1]
            for gi in part:
                g = groups[gi]
                start = int(s_sorted[g[0]])
                eg = e_sorted[g] - 1
                out = buf[: g.size, :width]
                if eg[-1] - eg[0] + 1 == g.size:
                    np.add(se[eg[0] : eg[-1] + 1], sb[start], out=out)
                else:
                    np.add(se[eg], sb[start], out=out)
                self._update(out, c, best, best_id, slice(int(g[0]), int(g[-1]) + 1))

        with ThreadPoolExecutor(max_workers=len(parts)) as pool:
            for c in range(0, self.num_entries, nc):
                sb = fv @ self._begin[c : c + nc].T  # (T, Nc): every frame as a begin
                se = fv @ self._end[c : c + nc].T  # (T, Nc): every frame as an end
                futures = [pool.submit(run, p, b, c, sb, se) for p, b in zip(parts, bufs, strict=True)]
                for f in futures:
                    f.result()
        ids = np.empty_like(best_id)
        cos = np.empty(order.size, dtype=np.float64)
        ids[order] = best_id
        cos[order] = best / qnorm[order]
        return ids, cosine_to_angular(cos)


def build(**options) -> ExactIndex:
    """The exact backend with ``options`` (memory_mb)."""
    return ExactIndex(**options)
