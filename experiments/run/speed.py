"""The ``speed`` experiment: RDD decomposition time versus demonstration length, with and without L_max.

Frame vectors are a smooth random walk on the sphere (two views, each L2-normalised as
docs/architecture.md requires) and the database holds random sub-task entries of the same layout; what is measured is the
whole ``decompose_embeddings`` call (batched retrieval of every candidate interval plus the solver).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from omegaconf import DictConfig

from rdd.encoders.embed import concat_views


def _walk(rng: np.random.Generator, t: int, dim: int, views: int) -> np.ndarray:
    per_view = []
    for _ in range(views):
        steps = rng.standard_normal((t, dim)).astype(np.float32) * 0.05
        per_view.append(np.cumsum(steps, axis=0) + rng.standard_normal(dim).astype(np.float32))
    return concat_views(per_view)


def measure_speed(cfg: DictConfig) -> dict[str, Any]:
    """Wall time of RDD on synthetic demonstrations of each length in ``cfg.speed.frames``."""
    from hydra.utils import instantiate

    from rdd.database.model import SubtaskDatabase

    sp = cfg.speed
    rng = np.random.default_rng(int(cfg.seed))
    views = len(cfg.views)
    n, dim = int(sp.database_size), int(sp.dim)
    begin = concat_views([rng.standard_normal((n, dim)).astype(np.float32) for _ in range(views)])
    end = concat_views([rng.standard_normal((n, dim)).astype(np.float32) for _ in range(views)])
    durations = rng.integers(5, 60, size=n)
    database = SubtaskDatabase.from_arrays(begin, end, durations)
    rows = []
    for t in sp.frames:
        frames = _walk(rng, int(t), dim, views)
        timing = {}
        for label, max_len in (("with", int(sp.max_len)), ("without", None)):
            node = cfg.decomposer.copy()
            decomposer = instantiate(node, _partial_=True)(database=database, max_len=max_len)
            best = float("inf")
            for _ in range(int(sp.repeats)):
                t0 = time.perf_counter()
                decomposer.decompose_embeddings(frames)
                best = min(best, time.perf_counter() - t0)
            timing[label] = best
        rows.append({"frames": int(t), "seconds_with_max_len": timing["with"],
                     "seconds_without_max_len": timing["without"]})
    return {"max_len": int(sp.max_len), "database_size": n, "dim_per_view": dim, "views": views,
            "repeats": int(sp.repeats), "rows": rows}
