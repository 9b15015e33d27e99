"""Faiss index: inner product on unit-normalised interval vectors (Flat, IVF or HNSW).

Uses a GPU when faiss-gpu is installed and sees one, the CPU otherwise.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from rdd.checks import one_of, whole
from rdd.geometry import cosine_to_angular
from rdd.index.base import NearestIndex, interval_matrix
from rdd.registry import register

log = logging.getLogger(__name__)
KINDS = ("flat", "ivf", "hnsw")


def _require_faiss():
    try:
        import faiss
    except ImportError as exc:  # optional extra
        raise ImportError(
            "the faiss index needs faiss: pip install 'rdd[index]' (or faiss-gpu)"
        ) from exc
    return faiss


@register("index", "faiss")
class FaissIndex(NearestIndex):
    """Nearest neighbours by maximum inner product on normalised vectors (= minimum angle)."""

    name = "faiss"
    OPTION_RULES = {"kind": one_of(*KINDS), "nlist": whole(1, allow_none=True), "nprobe": whole(1),
                    "hnsw_m": whole(2), "ef_search": whole(1), "use_gpu": one_of(None, True, False)}

    def __init__(self, kind: str = "flat", nlist: int | None = None, nprobe: int = 16,
                 hnsw_m: int = 32, ef_search: int = 128, use_gpu: bool | None = None) -> None:
        super().__init__()
        opts = self.check_options(kind=kind, nlist=nlist, nprobe=nprobe, hnsw_m=hnsw_m, ef_search=ef_search,
                                  use_gpu=use_gpu)
        self.kind, self.nlist, self.nprobe = kind, opts["nlist"], opts["nprobe"]
        self.hnsw_m, self.ef_search = opts["hnsw_m"], opts["ef_search"]
        self.use_gpu = use_gpu
        self._index = None

    def _fit(self, begin: np.ndarray, end: np.ndarray, cache_dir: Path | None, key: str | None) -> None:
        faiss = _require_faiss()
        x = interval_matrix(begin, end, normalize=True)
        n, dim = x.shape
        if self.kind == "flat":
            index = faiss.IndexFlatIP(dim)
        elif self.kind == "ivf":
            # sqrt(N) lists is faiss's usual rule of thumb; training needs at least nlist points.
            nlist = self.nlist or max(1, min(int(np.sqrt(n)), n // 39 or 1))
            index = faiss.IndexIVFFlat(faiss.IndexFlatIP(dim), dim, nlist, faiss.METRIC_INNER_PRODUCT)
            index.train(x)
            index.nprobe = min(self.nprobe, nlist)
        else:
            index = faiss.IndexHNSWFlat(dim, self.hnsw_m, faiss.METRIC_INNER_PRODUCT)
            index.hnsw.efSearch = self.ef_search
        gpus = faiss.get_num_gpus() if hasattr(faiss, "get_num_gpus") else 0
        if self.use_gpu and gpus == 0:
            raise RuntimeError("faiss index: use_gpu=True but no GPU faiss build or device is available")
        if (self.use_gpu or self.use_gpu is None) and gpus > 0 and self.kind != "hnsw":
            index = faiss.index_cpu_to_gpu(faiss.StandardGpuResources(), 0, index)
        else:
            # Measured (benchmarks/bench_decompose.py --scale 12700, T=500, 2 cores): flat 86 s,
            # hnsw 161 s, ivf 115 s (recall@1 0.88) vs 1.1 s for the exact index, which
            # factorises concat(begin, end) products over the demo's frames; faiss cannot.
            log.warning("faiss index on the CPU: every candidate interval is searched as a %d-d "
                        "vector; the exact index is far faster on a CPU (use faiss with a GPU)", dim)
        index.add(x)
        self._index = index

    def _search(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = queries / np.linalg.norm(queries, axis=1, keepdims=True)
        sims, ids = self._index.search(np.ascontiguousarray(q, dtype=np.float32), 1)
        ids = ids[:, 0].astype(np.int64)
        if (ids < 0).any():
            raise RuntimeError(
                "faiss index returned no neighbour for some queries (raise nprobe or ef_search)"
            )
        return ids, cosine_to_angular(sims[:, 0])
