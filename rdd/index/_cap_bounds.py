"""Certified bounds for the exact index: spherical caps around clusters of begin and end vectors.

Every entry's begin vector lies in a begin cluster: a unit centre ``c`` with every member's direction
within angle ``theta`` of it and its length in ``[n_min, n_max]``. For a frame ``f`` at angle ``psi`` to
``c``, every member ``b`` satisfies (triangle inequality on the sphere)

    |f| * n * cos(min(pi, psi + theta))  <=  f . b  <=  |f| * n * cos(max(0, psi - theta)),

with ``n`` the member's length (the end vectors likewise). Entries are grouped into *cells* (begin
cluster, end cluster); a cell's scores on a candidate interval ``(s, e)`` lie between the sums of its
two clusters' bounds. The largest cell lower bound is a score some entry reaches, so a cell whose
upper bound is below it cannot hold the nearest entry: only the surviving cells' entries are scored.
Centres and bounds are computed in float64 from the stored float32 vectors; a margin covering
float32 dot-product rounding keeps the result equal to a dense float32 search.
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROWS = 65536  # rows per chunk for the N-sized passes (bounded memory at a million entries)


@dataclass
class Caps:
    """Clusters of one side's vectors (begin or end): centres, cap angles and member lengths."""

    assign: np.ndarray  # (N,) cluster of each entry (stored order)
    centres: np.ndarray  # (K, D) float64 unit
    cos_t: np.ndarray  # (K,) cos of the cap half-angle
    sin_t: np.ndarray
    n_min: np.ndarray  # (K,) member lengths
    n_max: np.ndarray
    centres32: np.ndarray = field(init=False, repr=False)  # for the (T, K) float32 product

    def __post_init__(self) -> None:
        self.centres32 = self.centres.astype(np.float32)

    def cos_bounds(self, f_unit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T, K) lower and upper bounds of the cosine between each unit frame and a cluster's members.

        ``f_unit`` is float32; its float32 cosines with the centres err by at most D * 2^-24, so
        the upper bound is taken at the cosine plus that error and the lower at it minus.
        """
        c = (f_unit @ self.centres32.T).astype(np.float64)
        err = f_unit.shape[1] * 2.0 ** -24 + 1e-6
        hi, lo = np.minimum(c + err, 1.0), np.maximum(c - err, -1.0)
        cu = np.where(hi >= self.cos_t, 1.0, hi * self.cos_t + np.sqrt(1.0 - hi * hi) * self.sin_t)
        cl = np.where(lo <= -self.cos_t, -1.0, lo * self.cos_t - np.sqrt(1.0 - lo * lo) * self.sin_t)
        return cl, cu

    def bounds(self, f_unit: np.ndarray, f_norm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T, K) lower and upper bounds of ``f . x`` over each cluster's members x (``f = f_unit * f_norm``)."""
        cl, cu = self.cos_bounds(f_unit)
        up = np.where(cu >= 0, self.n_max * cu, self.n_min * cu) * f_norm[:, None]
        low = np.where(cl >= 0, self.n_min * cl, self.n_max * cl) * f_norm[:, None]
        return low, up

def spherical_kmeans(x: np.ndarray, k: int, seed: int, iters: int = 4, sketch_dim: int = 64,
                     sample: int = 8192) -> np.ndarray:
    """Cluster of each row of ``x`` (N, D): spherical k-means on a random projection of the rows.

    Only the grouping depends on the projection; every bound is computed in the full space.
    """
    rng = np.random.default_rng(seed)
    n, d = x.shape
    k = max(1, min(k, n))
    if d > sketch_dim:
        proj = (rng.normal(size=(d, sketch_dim)) / np.sqrt(sketch_dim)).astype(np.float32)
        y = np.concatenate([x[a : a + ROWS] @ proj for a in range(0, n, ROWS)])
    else:
        y = np.array(x, dtype=np.float32)
    y /= np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-12)
    train = y[rng.choice(n, size=min(n, sample), replace=False)]
    centres = train[rng.choice(train.shape[0], size=min(k, train.shape[0]), replace=False)]
    for _ in range(iters):
        assign = (train @ centres.T).argmax(1)
        sums = group_sum(train, assign, centres.shape[0]).astype(np.float32)
        norm = np.linalg.norm(sums, axis=1, keepdims=True)
        centres = np.where(norm > 0, sums / np.maximum(norm, 1e-12), centres)
    return np.concatenate([(y[a : a + ROWS] @ centres.T).argmax(1) for a in range(0, n, ROWS)])


def fit_caps(x: np.ndarray, assign: np.ndarray) -> Caps:
    """Centres (mean member direction), cap angles and length ranges of the clusters ``assign``."""
    n, d = x.shape
    k = int(assign.max()) + 1
    sums = np.zeros((k, d))
    norms = np.empty(n)
    for a in range(0, n, ROWS):
        xb = x[a : a + ROWS].astype(np.float64)
        nb = np.linalg.norm(xb, axis=1)
        norms[a : a + ROWS] = nb
        sums += group_sum(xb / np.maximum(nb, 1e-300)[:, None], assign[a : a + ROWS], k)
    length = np.linalg.norm(sums, axis=1, keepdims=True)
    # A cluster whose directions cancel (or of zero vectors only) gets any unit centre: its cap
    # angle below is then measured from it, so the bounds stay valid.
    centres = np.where(length > 1e-12, sums / np.maximum(length, 1e-300), 0.0)
    centres[length[:, 0] <= 1e-12, 0] = 1.0
    min_cos = np.ones(k)
    for a in range(0, n, ROWS):
        xb = x[a : a + ROWS].astype(np.float64)
        nb = norms[a : a + ROWS]
        cos = np.einsum("ij,ij->i", xb, centres[assign[a : a + ROWS]]) / np.maximum(nb, 1e-300)
        cos[nb == 0] = 1.0  # a zero vector scores 0 whatever its direction; n_min covers it
        np.minimum.at(min_cos, assign[a : a + ROWS], np.clip(cos, -1.0, 1.0))
    n_min = np.full(k, np.inf)
    n_max = np.zeros(k)
    np.minimum.at(n_min, assign, norms)
    np.maximum.at(n_max, assign, norms)
    n_min[~np.isfinite(n_min)] = 0.0
    # Widen each cap a little against the rounding of the float64 passes above.
    cos_t = np.clip(min_cos - 1e-12, -1.0, 1.0)
    return Caps(assign, centres, cos_t, np.sqrt(1.0 - cos_t * cos_t), n_min, n_max)


@dataclass
class Cells:
    """Entries grouped by (begin cluster, end cluster), stored order sorted by begin then end cluster."""

    begin: Caps
    end: Caps
    perm: np.ndarray  # stored position -> caller's entry id
    start: np.ndarray  # (C + 1,) first stored position of each cell
    jb: np.ndarray  # (C,) begin cluster of each cell
    je: np.ndarray  # (C,) end cluster of each cell
    by_begin: np.ndarray  # (Kb + 1,) first cell of each begin cluster
    by_end: np.ndarray  # (C,) cells sorted by end cluster
    by_end_start: np.ndarray  # (Ke + 1,) first position in by_end of each end cluster


def choose_caps(x: np.ndarray, cluster_size: int, seed: int) -> tuple[np.ndarray, Caps]:
    """Clusters of ``x`` whose caps are tight: the fewest (of N/c, N/4c, N/16c, at most 1024) whose
    median cap is within 2x (in 1 - cos) of the most numerous's, then every cap much wider than the
    median split in two. More clusters than the data's own groups only fragment the cells; a cap
    spanning two groups bounds nothing.
    """
    n = x.shape[0]
    ks = sorted({max(1, min(n // (cluster_size * 4 ** i), 1024)) for i in range(3)}, reverse=True)
    fits = []
    for k in ks:
        assign = np.unique(spherical_kmeans(x, k, seed), return_inverse=True)[1]  # dense ids
        fits.append((assign, fit_caps(x, assign)))
    width = [np.median(1.0 - caps.cos_t) for _, caps in fits]
    assign, caps = next(f for f, w in zip(reversed(fits), reversed(width), strict=True)
                        if w <= 2.0 * width[0] + 1e-12)
    norms = None
    for _ in range(4):
        # Wide in angle (much wider than the median cap) or in length (longest > 2x shortest).
        angle = 1.0 - caps.cos_t > 4.0 * np.median(1.0 - caps.cos_t) + 1e-9
        length = caps.n_min < 0.5 * caps.n_max
        wide = np.flatnonzero((angle | length) & (np.bincount(assign, minlength=angle.size) > 1))
        wide = wide[: max(0, 1024 - angle.size)]
        if wide.size == 0:
            break
        if norms is None and not angle[wide].all():
            norms = np.linalg.norm(x, axis=1)
        order = np.argsort(assign, kind="stable")  # each cluster's rows, without a pass per cluster
        first = np.searchsorted(assign[order], wide)
        last = np.searchsorted(assign[order], wide, side="right")
        assign = assign.copy()
        for j, a, b in zip(wide, first, last, strict=True):  # split each in two; new ids at the end
            rows = order[a:b]
            if angle[j]:
                half = spherical_kmeans(x[rows], 2, seed + int(j)) == 1
            else:
                half = norms[rows] > np.median(norms[rows])
            if half.any() and not half.all():
                assign[rows[half]] = assign.max() + 1
        assign = np.unique(assign, return_inverse=True)[1]
        caps = fit_caps(x, assign)
    return assign, caps


def fit_cells(begin: np.ndarray, end: np.ndarray, cluster_size: int, seed: int) -> Cells:
    """Cluster begin and end vectors (at least ``cluster_size`` entries a cluster on average)."""
    n = begin.shape[0]
    ab, caps_b = choose_caps(begin, cluster_size, seed)
    ae, caps_e = choose_caps(end, cluster_size, seed + 1)
    ke = int(ae.max()) + 1
    key = ab.astype(np.int64) * ke + ae
    perm = np.argsort(key, kind="stable")
    keys, first = np.unique(key[perm], return_index=True)
    jb, je = keys // ke, keys % ke
    kb = int(ab.max()) + 1
    by_begin = np.searchsorted(jb, np.arange(kb + 1))
    by_end = np.argsort(je, kind="stable")
    by_end_start = np.searchsorted(je[by_end], np.arange(ke + 1))
    # Stored order: assignments follow the entries.
    caps_b.assign, caps_e.assign = ab[perm], ae[perm]
    return Cells(caps_b, caps_e, perm, np.append(first, n), jb, je, by_begin, by_end, by_end_start)


def group_sum(x: np.ndarray, assign: np.ndarray, k: int) -> np.ndarray:
    """(k, D) float64 sums of the rows of ``x`` by group ``assign`` (a sparse one-hot product)."""
    from scipy.sparse import csr_matrix

    n = assign.size
    onehot = csr_matrix((np.ones(n), (assign, np.arange(n))), shape=(k, n))
    return np.asarray(onehot @ np.asarray(x, dtype=np.float64))


def ranges(starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(a, b)`` for each pair (no Python loop)."""
    lens = stops - starts
    total = int(lens.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    shift = np.repeat(starts - (np.cumsum(lens) - lens), lens)
    return np.arange(total, dtype=np.int64) + shift


# Bump when fit_cells changes what it computes or the file's form: saved cells of older code are not read.
# 2: the file holds the sha256 of its arrays, checked on every read.
CELLS_FORMAT = 2


def _cells_checksum(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        h.update(f"{name}{arr.dtype.str}{arr.shape}".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def save_cells(path: Path, cells: Cells) -> None:
    """Write ``cells`` to ``path`` (.npz) atomically, with the sha256 of its arrays."""
    from rdd.atomic import atomic_file

    arrays = {f"{side}_{f}": getattr(getattr(cells, side), f) for side in ("begin", "end") for f in CAPS_FIELDS}
    arrays.update({f: getattr(cells, f) for f in CELLS_FIELDS})
    with atomic_file(path, "wb") as fh:
        np.savez(fh, checksum=np.array(_cells_checksum(arrays)), **arrays)


def load_cells(path: Path, num_entries: int) -> Cells:
    """Cells saved by :func:`save_cells`, their checksum and size verified on the bytes read (ValueError)."""
    try:
        with np.load(io.BytesIO(path.read_bytes()), allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files if name != "checksum"}
            stored = str(z["checksum"])
    except Exception as exc:  # noqa: BLE001 - truncated, not a zip, a member missing: all unreadable
        raise ValueError(f"exact index cells file {path} is unreadable ({type(exc).__name__}: {exc})") from exc
    if _cells_checksum(arrays) != stored:
        raise ValueError(f"exact index cells file {path} fails its checksum")
    try:
        caps = {side: Caps(**{f: arrays[f"{side}_{f}"] for f in CAPS_FIELDS}) for side in ("begin", "end")}
        cells = Cells(caps["begin"], caps["end"], **{f: arrays[f] for f in CELLS_FIELDS})
    except (KeyError, TypeError) as exc:
        raise ValueError(f"exact index cells file {path} lacks {exc}") from exc
    if cells.perm.shape != (num_entries,) or cells.start[-1] != num_entries:
        raise ValueError(f"exact index cells file {path} holds {cells.perm.size} entries, the database "
                         f"{num_entries}")
    return cells


CAPS_FIELDS = ("assign", "centres", "cos_t", "sin_t", "n_min", "n_max")
CELLS_FIELDS = ("perm", "start", "jb", "je", "by_begin", "by_end", "by_end_start")
