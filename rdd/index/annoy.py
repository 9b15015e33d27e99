"""Annoy index (the paper's setting): angular metric, ``n_trees`` random-projection trees.

Annoy's angular distance is ``sqrt(2 (1 - cos))``, the project's distance. With ``search_k=-1`` a
query inspects ``n_trees * N`` nodes (all trees). Queries run one at a time (Annoy has no batch call).
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

import numpy as np

from rdd.atomic import atomic_path, read_verified, write_sha256
from rdd.checks import whole
from rdd.errors import InputError
from rdd.index.base import NearestIndex, interval_matrix
from rdd.registry import register

log = logging.getLogger(__name__)


def _require_annoy():
    try:
        from annoy import AnnoyIndex
    except ImportError as exc:  # optional extra
        raise ImportError(
            "the annoy index needs the 'annoy' package: pip install 'rdd[index]'"
        ) from exc
    return AnnoyIndex


@register("index", "annoy")
class AnnoyIndex(NearestIndex):
    """Approximate nearest neighbours with Annoy; the built forest is saved beside the database."""

    name = "annoy"
    OPTION_RULES = {"n_trees": whole(1), "search_k": whole(-1), "seed": whole(0)}

    @classmethod
    def check_options(cls, **options):
        """The rules' ranges, and ``search_k`` -1 (every tree) or >= 1."""
        opts = super().check_options(**options)
        if opts.get("search_k") == 0:
            raise InputError(f"{cls.option_owner()}: option search_k must be -1 (all trees) or >= 1, got 0",
                             option="search_k")
        return opts

    def __init__(self, n_trees: int = 10, search_k: int = -1, seed: int = 0) -> None:
        super().__init__()
        opts = self.check_options(n_trees=n_trees, search_k=search_k, seed=seed)
        self.n_trees, self.search_k, self.seed = opts["n_trees"], opts["search_k"], opts["seed"]
        self._index = None
        self.path: Path | None = None

    def _fit(self, begin: np.ndarray, end: np.ndarray, cache_dir: Path | None, key: str | None) -> None:
        annoy_index = _require_annoy()
        x = interval_matrix(begin, end, normalize=False)
        dim = x.shape[1]
        if key is None:
            key = hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()
        # The file name holds everything that made the forest, so a stale file is never reused
        # (v2: a .sha256 file beside it, checked before the forest is mapped).
        fname = f"annoy-v2-d{dim}-n{x.shape[0]}-t{self.n_trees}-s{self.seed}-{key[:16]}.ann"
        path = cache_dir / fname if cache_dir is not None else None
        if path is not None and path.is_file():
            index = annoy_index(dim, "angular")
            try:
                read_verified(path)
                if not index.load(str(path)) or index.get_n_items() != x.shape[0]:
                    raise ValueError("it is unreadable or has the wrong size")
                self._index, self.path = index, path
                return
            except (ValueError, OSError) as exc:  # a cache: damage costs a build, never a wrong search
                log.warning("annoy index file %s: %s; building the forest again", path, exc)
        index = self._build(annoy_index, x)
        if path is not None:
            try:
                with atomic_path(path) as tmp:
                    if index.save(str(tmp)) is False:
                        raise OSError(f"annoy could not write {tmp}")
                write_sha256(path)
                # save() leaves the index memory-mapped from tmp; reload from the final name.
                index = annoy_index(dim, "angular")
                index.load(str(path))
                self.path = path
            except OSError as exc:  # a folder without room only costs the next fit its forest
                log.warning("annoy index: could not save its forest to %s (%s)", path, exc.strerror or exc)
                index = self._build(annoy_index, x)
        self._index = index

    def _build(self, annoy_index, x: np.ndarray):
        """The forest of the rows of ``x``, in memory."""
        index = annoy_index(x.shape[1], "angular")
        index.set_seed(self.seed)
        for i, row in enumerate(x):
            index.add_item(i, row.tolist())
        index.build(self.n_trees, n_jobs=1)
        return index

    def _search(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ids = np.empty(queries.shape[0], dtype=np.int64)
        dists = np.empty(queries.shape[0], dtype=np.float64)
        for i, q in enumerate(queries):
            found, dist = self._index.get_nns_by_vector(q.tolist(), 1, search_k=self.search_k,
                                                        include_distances=True)
            ids[i], dists[i] = found[0], dist[0]
        return ids, dists
