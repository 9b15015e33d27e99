"""Exact nearest neighbours by cosine, factorised over the interval's begin and end frames.

For an interval vector ``q = concat(qb, qe)`` and an entry ``x = concat(xb, xe)``,
``q . x = qb . xb + qe . xe``. Over one demonstration every begin (end) frame is shared by many
candidate intervals, so two (T, D) x (D, N) matrix products give every candidate's dot product
with every entry as a sum of two looked-up rows; a max over the database finishes the search.
The database is processed in chunks so memory stays bounded for a million entries.

Pruning (still exact, ``rdd.index._cap_bounds``): begin and end vectors are clustered at fit time;
spherical-cap bounds per cluster, from (T, K) products with the cluster centres, rule out every
cell of entries whose best possible score is below a score some entry is certain to reach. Only
the surviving entries' products are computed and searched. Where the bounds rule out too little
(unclustered data) the dense path is taken.
"""

from __future__ import annotations

import contextlib
import logging
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from rdd.checks import FLAG, whole
from rdd.geometry import check_intervals, cosine_to_angular
from rdd.index._cap_bounds import CELLS_FORMAT, Cells, fit_cells, load_cells, ranges, save_cells
from rdd.index.base import NearestIndex, row_sq_norms64
from rdd.registry import register

log = logging.getLogger(__name__)
DENSE_ABOVE = 0.6  # share of surviving entries above which pruning does not pay: search them all


@register("index", "exact")
class ExactIndex(NearestIndex):
    """Exact nearest-neighbour search (no approximation), vectorised over candidate intervals."""

    name = "exact"
    OPTION_RULES = {"memory_mb": whole(1), "threads": whole(1, allow_none=True), "prune": FLAG,
                    "cluster_size": whole(1), "seed": whole(0)}

    def __init__(self, memory_mb: int = 256, threads: int | None = None, prune: bool = True,
                 cluster_size: int = 16, seed: int = 0) -> None:
        super().__init__()
        opts = self.check_options(memory_mb=memory_mb, threads=threads, prune=prune, cluster_size=cluster_size,
                                  seed=seed)
        self.prune, self.cluster_size, self.seed = opts["prune"], opts["cluster_size"], opts["seed"]
        self.memory_mb = opts["memory_mb"]
        # numpy releases the GIL in add/argmax, so plain threads share the max-over-database work.
        self.threads = opts["threads"] if threads is not None else min(2, os.cpu_count() or 1)
        self.last_searched_fraction = float("nan")
        self._cells: Cells | None = None

    def _fit(self, begin: np.ndarray, end: np.ndarray, cache_dir: Path | None, key: str | None) -> None:
        norm = np.sqrt(row_sq_norms64(begin, einsum=False) + row_sq_norms64(end, einsum=False))
        if (norm == 0).any():
            raise ValueError("exact index: a database interval vector is zero (angular distance undefined)")
        # Entries pre-scaled to unit interval norm: a query's dot product with them is its cosine
        # times its own norm, so the argmax over entries needs no per-pair division.
        inv = (1.0 / norm).astype(np.float32)[:, None]
        b, e = begin * inv, end * inv
        n = b.shape[0]
        if self.prune and n >= 4 * self.cluster_size:
            self._cells = self._saved_cells(b, e, cache_dir, key)
            self._perm = self._cells.perm
        else:
            self._cells, self._perm = None, np.arange(n)
        # Stored in cell order; self._perm maps a stored position back to the caller's entry id.
        self._begin = np.ascontiguousarray(b[self._perm])
        self._end = np.ascontiguousarray(e[self._perm])

    def _saved_cells(self, b: np.ndarray, e: np.ndarray, cache_dir: Path | None, key: str | None) -> Cells:
        """The clusters of the entries: read from beside the database when saved there, else built
        (and saved there; a folder that cannot be written only costs the next fit its clustering)."""
        if cache_dir is None or key is None:
            return fit_cells(b, e, self.cluster_size, self.seed)
        n, d = b.shape
        path = cache_dir / (f"exact-cells-v{CELLS_FORMAT}-n{n}-d{d}-c{self.cluster_size}-s{self.seed}-"
                            f"{key[:16]}.npz")
        if path.is_file():
            try:
                return load_cells(path, n)
            except ValueError as exc:  # a cache: damage costs a clustering, never a wrong search
                log.warning("%s; clustering again and rewriting it", exc)
        cells = fit_cells(b, e, self.cluster_size, self.seed)
        try:
            save_cells(path, cells)
        except OSError as exc:
            log.warning("exact index: could not save its clusters to %s (%s)", path, exc)
        return cells

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
        better = val > cur  # strict: the lowest stored position wins ties, as in one argmax over all
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
        groups = _Groups(s[order], e[order])
        best = np.full(order.size, -np.inf, dtype=np.float32)
        best_id = np.zeros(order.size, dtype=np.int64)
        keep = None if self._cells is None else self._survivors(fv, sq, groups)
        if keep is None:
            self._search_dense(fv, groups, best, best_id, self._begin, self._end)
        else:
            self._search_dense(fv, groups, best, best_id, self._begin[keep], self._end[keep])
            best_id = keep[best_id]
        searched = groups.size * (self.num_entries if keep is None else keep.size)
        # Share of the (candidate, entry) pairs a dense search would score that were scored.
        self.last_searched_fraction = float(searched) / (order.size * self.num_entries)
        ids = np.empty_like(best_id)
        cos = np.empty(order.size, dtype=np.float64)
        ids[order] = self._perm[best_id]
        cos[order] = best / qnorm[order]
        return ids, cosine_to_angular(cos)

    def _search_dense(self, fv: np.ndarray, groups: _Groups, best: np.ndarray, best_id: np.ndarray,
                      begin: np.ndarray, end: np.ndarray) -> None:
        """Every candidate against every entry of ``begin``/``end``: chunked products, then a max."""
        t, n = fv.shape[0], begin.shape[0]
        longest = groups.longest
        workers = min(self.threads, len(groups))
        # Two (T, Nc) product matrices plus one (longest, Nc) work buffer per thread and chunk.
        nc = self._chunk_entries(2 * t + workers * longest)
        # Contiguous shares of the groups per thread: each writes its own slice of best/best_id.
        parts = [p for p in np.array_split(np.arange(len(groups)), workers) if p.size]
        bufs = [np.empty((longest, min(nc, n)), dtype=np.float32) for _ in parts]

        def run(part: np.ndarray, buf: np.ndarray, c: int, sb: np.ndarray, se: np.ndarray) -> None:
            for gi in part:
                rows, start, se_rows = groups.rows(gi, se)
                out = buf[: rows.stop - rows.start, : sb.shape[1]]
                np.add(se_rows, sb[start], out=out)
                self._update(out, c, best, best_id, rows)

        with ThreadPoolExecutor(max_workers=len(parts)) as pool, _one_blas_thread():
            for c in range(0, n, nc):
                sb, se = self._products(fv, begin[c : c + nc], end[c : c + nc], pool, len(parts))
                for f in [pool.submit(run, p, b, c, sb, se) for p, b in zip(parts, bufs, strict=True)]:
                    f.result()

    @staticmethod
    def _products(fv: np.ndarray, begin: np.ndarray, end: np.ndarray, pool: ThreadPoolExecutor,
                  workers: int) -> tuple[np.ndarray, np.ndarray]:
        """Every frame's dot products with ``begin`` and ``end`` rows, frames split over the threads."""
        sb = np.empty((fv.shape[0], begin.shape[0]), dtype=np.float32)  # every frame as a begin
        se = np.empty_like(sb)  # every frame as an end
        rows = [r for r in np.array_split(np.arange(fv.shape[0]), workers) if r.size]
        futures = [pool.submit(np.matmul, fv[r[0] : r[-1] + 1], m.T, out=o[r[0] : r[-1] + 1])
                   for r in rows for m, o in ((begin, sb), (end, se))]
        for f in futures:
            f.result()
        return sb, se

    def _survivors(self, fv: np.ndarray, sq: np.ndarray, groups: _Groups) -> np.ndarray | None:
        """Stored positions of every entry that may be nearest to some candidate (ascending).

        None when the bounds rule out too little for pruning to pay (the dense pass is taken).
        """
        cells = self._cells
        f_norm = np.sqrt(sq)
        f_unit = (fv / np.maximum(f_norm, 1e-300)[:, None]).astype(np.float32)  # a zero frame stays 0
        lo_b, up_b = cells.begin.bounds(f_unit, f_norm)
        lo_e, up_e = cells.end.bounds(f_unit, f_norm)
        s, e = groups.s, groups.e - 1  # candidates' start and end frames
        # A score some entry reaches, per candidate: the best lower bound over the cells of the
        # start's two likeliest begin clusters and of the end's two likeliest end clusters (any
        # set of non-empty cells gives a valid bound).
        low = np.maximum(_probe(lo_b, lo_e, cells.by_begin, cells.je, s, e),
                         _probe(lo_e, lo_b, cells.by_end_start, cells.jb[cells.by_end], e, s))
        # float32 dot products err by at most D * 2^-24 * |f| here (entries have norm <= 1): a cell
        # is kept unless it loses by more than twice that, so the float32 winner survives. The
        # float32 copies of the bounds below are widened by 1e-6 (their own rounding).
        slack = 2.5 * self.frame_dim * 2.0 ** -24 * f_norm
        low = (low - slack[s] - slack[e] - 1e-6).astype(np.float32)
        up_e32 = up_e.astype(np.float32)
        # A cell (jb, je) can win candidate (s, e) only if up_b[s, jb] + up_e[e, je] >= low[s, e]:
        # reach[g, je] = max over the ends e of group g of up_e[e, je] - low[s, e].
        reach = np.empty((len(groups), up_e.shape[1]), dtype=np.float32)
        for gi in range(len(groups)):
            rows, _, up_rows = groups.rows(gi, up_e32)
            np.max(up_rows - low[rows, None], axis=0, out=reach[gi])
        up_start = (up_b[groups.s[groups.starts]] + 1e-6).astype(np.float32)  # (groups, Kb)
        # Cheap necessary conditions first (each side against the other side's best), then the
        # exact test on the cells that pass both.
        jb_ok = (up_start + reach.max(axis=1, keepdims=True)).max(axis=0) >= 0
        je_ok = (reach + up_start.max(axis=1, keepdims=True)).max(axis=0) >= 0
        alive = jb_ok[cells.jb] & je_ok[cells.je]
        test = np.flatnonzero(alive)
        step = max(1, (64 << 20) // (4 * len(groups)))
        for c in range(0, test.size, step):
            t = test[c : c + step]
            alive[t] = (np.take(up_start, cells.jb[t], axis=1) + np.take(reach, cells.je[t], axis=1)).max(axis=0) >= 0
        keep = ranges(cells.start[:-1][alive], cells.start[1:][alive])
        # An empty set would mean a bound is wrong (the probed cell always survives): search all.
        return keep if 0 < keep.size <= DENSE_ABOVE * self.num_entries else None

    def _end_shortlist(self, unit_frames: np.ndarray) -> np.ndarray | None:
        """Entries of every end cluster whose cosine bound reaches some frame's certain best."""
        cells = self._cells
        if cells is None:
            return None
        low, up = cells.end.cos_bounds(unit_frames)
        # Each cluster's lower bound is a cosine one of its members reaches with that frame.
        need = np.flatnonzero((up >= (low.max(axis=1) - 1e-6)[:, None]).any(axis=0))
        member_cells = cells.by_end[ranges(cells.by_end_start[need], cells.by_end_start[need + 1])]
        stored = ranges(cells.start[member_cells], cells.start[member_cells + 1])
        return np.sort(self._perm[stored]) if stored.size <= DENSE_ABOVE * self.num_entries else None


class _Groups:
    """Candidates sorted by (start, end), grouped by start frame."""

    def __init__(self, s_sorted: np.ndarray, e_sorted: np.ndarray) -> None:
        self.s, self.e = s_sorted, e_sorted
        cuts = np.flatnonzero(np.diff(s_sorted)) + 1
        self.starts = np.concatenate([[0], cuts])
        self.stops = np.append(cuts, s_sorted.size)
        self.size = int(s_sorted.size)
        self.longest = int((self.stops - self.starts).max())

    def __len__(self) -> int:
        return self.starts.size

    def rows(self, gi: int, se: np.ndarray) -> tuple[slice, int, np.ndarray]:
        """The group's candidate rows, start frame, and its ends' rows of ``se`` (a view when contiguous)."""
        a, b = int(self.starts[gi]), int(self.stops[gi])
        eg = self.e[a:b] - 1
        se_rows = se[eg[0] : eg[-1] + 1] if eg[-1] - eg[0] + 1 == b - a else se[eg]
        return slice(a, b), int(self.s[a]), se_rows


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


def _probe(lo_x: np.ndarray, lo_y: np.ndarray, first_cell: np.ndarray, other_of_cell: np.ndarray,
           x: np.ndarray, y: np.ndarray, r: int = 2) -> np.ndarray:
    """Per candidate (x, y): max over the cells of x's top-``r`` clusters of lo_x[x, cx] + lo_y[y, cy].

    ``first_cell[k]:first_cell[k + 1]`` are cluster k's cells (in some order) and ``other_of_cell``
    their cluster on the other side, in the same order.
    """
    r = min(r, lo_x.shape[1])
    top = np.argpartition(-lo_x, r - 1, axis=1)[:, :r]  # (T, r)
    used = np.unique(top)
    # best[i, t]: the largest lo_y[t, cy] over the cells of cluster used[i]
    best = np.stack([lo_y[:, other_of_cell[first_cell[k] : first_cell[k + 1]]].max(axis=1) for k in used])
    pos = np.searchsorted(used, top)  # (T, r) rows of best
    out = np.full(x.size, -np.inf)
    for i in range(r):
        k = top[x, i]
        out = np.maximum(out, lo_x[x, k] + best[pos[x, i], y])
    return out

