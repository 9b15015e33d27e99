"""Exact nearest neighbours by cosine, factorised over the interval's begin and end frames.

For an interval vector ``q = concat(qb, qe)`` and an entry ``x = concat(xb, xe)``,
``q . x = qb . xb + qe . xe``. Over one demonstration every begin (end) frame is shared by many
candidate intervals, so two (T, D) x (D, N) matrix products give every candidate's dot product
with every entry as a sum of two looked-up rows; a max over the database finishes the search.
The database is processed in chunks so memory stays bounded for a million entries.

Pruning (still exact): entries are stored grouped into blocks of similar interval vectors (a small
k-means at fit time). A block's largest begin cosine plus its largest end cosine bounds every entry's
score in it from above; a block whose bound is below a score already reached cannot hold the
nearest entry and is skipped. Float rounding is monotone, so the bound holds in float32 as well.
Where the bounds prune little (e.g. unstructured data) the dense path is taken.
"""

from __future__ import annotations

import contextlib
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from rdd.index.base import NearestIndex
from rdd.scoring import check_intervals, cosine_to_angular


class ExactIndex(NearestIndex):
    """Exact nearest-neighbour search (no approximation), vectorised over candidate intervals."""

    name = "exact"

    def __init__(self, memory_mb: int = 256, threads: int | None = None, prune: bool = True,
                 block_size: int = 32, seed: int = 0) -> None:
        super().__init__()
        if block_size < 1:
            raise ValueError(f"exact index: block_size must be >= 1, got {block_size}")
        self.prune, self.block_size, self.seed = bool(prune), int(block_size), int(seed)
        self.last_searched_fraction = float("nan")
        self.probe_blocks = 8  # blocks searched first per start frame to get tight lower bounds
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
        b, e = begin * inv, end * inv
        n = b.shape[0]
        if self.prune and n >= 4 * self.block_size:
            self._perm, self._offsets = _cluster_blocks(b, e, self.block_size, self.seed)
        else:
            self._perm, self._offsets = np.arange(n), None
        # Stored in block order; self._perm maps a stored position back to the caller's entry id.
        self._begin = np.ascontiguousarray(b[self._perm])
        self._end = np.ascontiguousarray(e[self._perm])

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
        return self._perm[best_id], cosine_to_angular(best)

    @staticmethod
    def _update(dots: np.ndarray, offset: int, best: np.ndarray, best_id: np.ndarray, rows,
                cols: np.ndarray | None = None) -> None:
        """Fold (Q, Nc) dot products (over chunk columns ``cols``, all when None) into the running best."""
        idx = dots.argmax(axis=1)
        val = dots[np.arange(dots.shape[0]), idx]
        if cols is not None:
            idx = cols[idx]
        cur = best[rows]
        better = val > cur  # strict: the lowest entry id wins ties, as in one argmax over all
        cur[better] = val[better]
        best[rows] = cur
        ids = best_id[rows]
        ids[better] = idx[better] + offset
        best_id[rows] = ids

    def _chunk_products(self, fv: np.ndarray, c: int, nc: int, pool: ThreadPoolExecutor,
                        workers: int) -> dict:
        """Begin/end dot products of every frame with database chunk ``[c, c + nc)`` and block bounds."""
        begin, end = self._begin[c : c + nc], self._end[c : c + nc]
        sb = np.empty((fv.shape[0], begin.shape[0]), dtype=np.float32)  # every frame as a begin
        se = np.empty_like(sb)  # every frame as an end
        # Rows split over our own threads (BLAS held to one thread each, see search_intervals).
        rows = [r for r in np.array_split(np.arange(fv.shape[0]), workers) if r.size]
        futures = [pool.submit(np.matmul, fv[r[0] : r[-1] + 1], m.T, out=o[r[0] : r[-1] + 1])
                   for r in rows for m, o in ((begin, sb), (end, se))]
        for f in futures:
            f.result()
        chunk: dict = {"sb": sb, "se": se, "blocks": None}
        if self._offsets is None:
            return chunk
        width = sb.shape[1]
        inside = self._offsets[(self._offsets > c) & (self._offsets < c + width)] - c
        offs = np.concatenate([[0], inside]).astype(np.int64)
        chunk["blocks"] = offs
        chunk["sizes"] = np.diff(np.append(offs, width))
        chunk["bmb"] = np.maximum.reduceat(sb, offs, axis=1)  # (T, K) block maxima
        chunk["bme"] = np.maximum.reduceat(se, offs, axis=1)
        rows = np.arange(sb.shape[0])
        chunk["arg_b"], chunk["arg_e"] = sb.argmax(1), se.argmax(1)
        chunk["max_e"] = se[rows, chunk["arg_e"]]
        return chunk

    @staticmethod
    def _needed_columns(chunk: dict, start: int, eg: np.ndarray, best_so_far: np.ndarray,
                        ub: np.ndarray, done: np.ndarray) -> np.ndarray | None:
        """Chunk columns outside ``done`` blocks that may hold a better entry; None = search all."""
        sb, se = chunk["sb"], chunk["se"]
        # Lower bounds: scores actually reached by the best end match, the best begin match and the
        # blocks searched so far. A block whose upper bound is below them all is skipped.
        b = chunk["arg_b"][start]
        lb = np.maximum(sb[start, chunk["arg_e"][eg]] + chunk["max_e"][eg], sb[start, b] + se[eg, b])
        lb = np.maximum(lb, best_so_far)
        need = (ub >= lb[:, None]).any(axis=0) & ~done
        if chunk["sizes"][need].sum() * 2 > sb.shape[1]:
            return None  # the bounds prune too little: the dense pass is cheaper
        return _block_columns(chunk, need)

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
        # Two (T, Nc) product matrices plus one (longest, Nc) work buffer per thread and chunk.
        nc = self._chunk_entries(2 * t + min(self.threads, len(groups)) * longest)
        best = np.full(order.size, -np.inf, dtype=np.float32)
        best_id = np.zeros(order.size, dtype=np.int64)
        workers = min(self.threads, len(groups))
        # Contiguous halves of the groups per thread: each writes its own slice of best/best_id.
        parts = [p for p in np.array_split(np.arange(len(groups)), workers) if p.size]
        bufs = [np.empty((longest, min(nc, self.num_entries)), dtype=np.float32) for _ in parts]

        searched = np.zeros(len(parts), dtype=np.int64)  # (candidate, entry) pairs scored, per thread

        def run(worker: int, part: np.ndarray, buf: np.ndarray, c: int, chunk: dict) -> None:
            sb, se = chunk["sb"], chunk["se"]
            width = sb.shape[1]
            for gi in part:
                g = groups[gi]
                rows = slice(int(g[0]), int(g[-1]) + 1)
                start = int(s_sorted[g[0]])
                eg = e_sorted[g] - 1
                run_of_rows = eg[-1] - eg[0] + 1 == g.size
                se_rows = se[eg[0] : eg[-1] + 1] if run_of_rows else se[eg]
                if chunk["blocks"] is not None:
                    ub = chunk["bme"][eg] + chunk["bmb"][start]  # (|E|, K) upper bounds per block
                    # Stage 1: the blocks with the highest bounds, searched exactly, give lower bounds.
                    top = np.zeros(ub.shape[1], dtype=bool)
                    m = min(self.probe_blocks, ub.shape[1])
                    top[np.argpartition(-ub.max(axis=0), m - 1)[:m]] = True
                    cols = _block_columns(chunk, top)
                    sub = np.take(se_rows, cols, axis=1)
                    sub += sb[start, cols]
                    self._update(sub, c, best, best_id, rows, cols)
                    searched[worker] += sub.size
                    # Stage 2: every other block whose bound reaches the best score found so far.
                    cols = self._needed_columns(chunk, start, eg, best[rows], ub, top)
                    if cols is not None:
                        if cols.size:
                            sub = np.take(se_rows, cols, axis=1)
                            sub += sb[start, cols]
                            self._update(sub, c, best, best_id, rows, cols)
                            searched[worker] += sub.size
                        continue
                out = buf[: g.size, :width]
                np.add(se_rows, sb[start], out=out)
                self._update(out, c, best, best_id, rows)
                searched[worker] += out.size

        with ThreadPoolExecutor(max_workers=len(parts)) as pool, _one_blas_thread():
            for c in range(0, self.num_entries, nc):
                chunk = self._chunk_products(fv, c, nc, pool, len(parts))
                futures = [pool.submit(run, w, p, b, c, chunk)
                           for w, (p, b) in enumerate(zip(parts, bufs, strict=True))]
                for f in futures:
                    f.result()
        # Share of the (candidate, entry) pairs a dense search would score that were scored.
        self.last_searched_fraction = float(searched.sum()) / (order.size * self.num_entries)
        ids = np.empty_like(best_id)
        cos = np.empty(order.size, dtype=np.float64)
        ids[order] = self._perm[best_id]
        cos[order] = best / qnorm[order]
        return ids, cosine_to_angular(cos)


def build(**options) -> ExactIndex:
    """The exact backend with ``options`` (memory_mb, threads, prune, block_size, seed)."""
    return ExactIndex(**options)


def _one_blas_thread():
    """Hold BLAS to one thread while our own threads split the work.

    A multi-threaded BLAS inside each of our threads oversubscribes the cores, and OpenBLAS's
    spinning workers cost far more on a busy machine. Without threadpoolctl nothing is changed.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def _block_columns(chunk: dict, mask: np.ndarray) -> np.ndarray:
    """Chunk columns of the blocks selected by ``mask`` (concatenated ranges, no pass over all columns)."""
    idx = np.flatnonzero(mask)
    starts, lens = chunk["blocks"][idx], chunk["sizes"][idx]
    total = int(lens.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    # position i of the output lies in range r: column = starts[r] + (i - first output index of r)
    shift = np.repeat(starts - (np.cumsum(lens) - lens), lens)
    return np.arange(total, dtype=np.int64) + shift

def _cluster_blocks(begin: np.ndarray, end: np.ndarray, block_size: int, seed: int, iters: int = 4,
                    sketch_dim: int = 128, sample: int = 8192) -> tuple[np.ndarray, np.ndarray]:
    """Order entries so that similar interval vectors sit together: (permutation, block starts).

    Spherical k-means with about N / block_size centres (at most 1024), run on a random projection
    of the vectors to ``sketch_dim`` dimensions; only the grouping depends on it, never a result.
    """
    rng = np.random.default_rng(seed)
    n, d = begin.shape
    # Sketch of concat(begin, end) without materialising the (N, 2D) concatenation.
    proj = rng.normal(size=(2 * d, sketch_dim)).astype(np.float32) / np.sqrt(sketch_dim)
    x = np.concatenate([begin[a : a + 65536] @ proj[:d] + end[a : a + 65536] @ proj[d:]
                        for a in range(0, n, 65536)])
    x = x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)
    k = max(1, min(n // block_size, 1024))
    train = x[rng.choice(n, size=min(n, sample), replace=False)]
    centres = train[rng.choice(train.shape[0], size=k, replace=False)]
    for _ in range(iters):
        assign = (train @ centres.T).argmax(1)
        sums = np.zeros_like(centres)
        np.add.at(sums, assign, train)
        norm = np.linalg.norm(sums, axis=1, keepdims=True)
        centres = np.where(norm > 0, sums / np.maximum(norm, 1e-12), centres)
    assign = np.concatenate([(x[a : a + 65536] @ centres.T).argmax(1) for a in range(0, n, 65536)])
    perm = np.argsort(assign, kind="stable")
    counts = np.bincount(assign, minlength=k)
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])[counts > 0]
    return perm, offsets.astype(np.int64)
