"""RDD (Yan et al., NeurIPS 2025): the partition whose intervals best match database sub-tasks.

Every candidate interval ``[start, end)`` with ``min_len <= end - start <= max_len`` is retrieved in
one batch, scored ``J(I) = weight(I) * sim(I, I_nn)`` (Eq. 3.4, or Eq. 3.5 in the OOD mode), and the
exact maximum-sum partition is found by dynamic programming over the dense score array.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rdd import scoring
from rdd.data.episode import Episode
from rdd.database import SubtaskDatabase
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.encoders.base import Encoder
from rdd.encoders.embed import DEFAULT_VIEWS, episode_frame_vectors
from rdd.index import NearestIndex, load_index
from rdd.solver import candidate_intervals, max_sum_partition_dense

MODES = ("default", "ood")


class RDDDecomposer(Decomposer):
    """Retrieval-based demonstration decomposer over a :class:`SubtaskDatabase`."""

    name = "rdd"

    def __init__(
        self,
        database: SubtaskDatabase,
        encoder: Encoder | None = None,
        alpha: float = 1.0,
        beta: float = 0.1,
        mode: str = "default",
        min_len: int = 2,
        max_len: int | None = None,
        backend: str | NearestIndex = "exact",
        views: Sequence[str] = DEFAULT_VIEWS,
        backend_options: Mapping[str, Any] | None = None,
        uvd_options: Mapping[str, Any] | None = None,
        cache=None,
    ) -> None:
        if not isinstance(database, SubtaskDatabase):
            raise TypeError(f"database must be a SubtaskDatabase, got {type(database).__name__}")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if alpha < 0 or beta < 0:
            raise ValueError(f"alpha and beta must be >= 0, got alpha={alpha}, beta={beta}")
        if int(min_len) != min_len or min_len < 1:
            raise ValueError(f"min_len must be an integer >= 1, got {min_len!r}")
        if max_len is not None and (int(max_len) != max_len or max_len < min_len):
            raise ValueError(f"max_len must be None or an integer >= min_len={min_len}, got {max_len!r}")
        self.database = database
        self.encoder = encoder
        self.alpha, self.beta, self.mode = float(alpha), float(beta), mode
        self.min_len, self.max_len = int(min_len), None if max_len is None else int(max_len)
        self.views = tuple(views)
        self.uvd_options = dict(uvd_options or {})
        self.cache = cache
        if encoder is not None:
            database.check_compatible(encoder, self.views)
        if isinstance(backend, NearestIndex):
            if backend_options:
                raise ValueError("backend_options apply only when backend is given by name")
            self.index = backend
        elif isinstance(backend, str):
            self.index = load_index(backend, **dict(backend_options or {}))
        else:
            raise TypeError(f"backend must be a backend name or a NearestIndex, got {type(backend).__name__}")
        self.index.fit(
            database.begin, database.end, cache_dir=database.directory,
            key=database.fingerprint() if database.directory is not None else None,
        )

    def decompose(self, episode: Episode) -> Decomposition:
        """Embed ``episode`` with the encoder and decompose it."""
        if self.encoder is None:
            raise ValueError("RDDDecomposer.decompose(episode) needs an encoder; "
                             "pass encoder= or call decompose_embeddings(frame_vectors)")
        fv = episode_frame_vectors(episode, self.encoder, views=self.views, cache=self.cache)
        result = self.decompose_embeddings(fv)
        result.meta["episode"] = episode.name
        return result

    def decompose_embeddings(self, frame_vectors: np.ndarray) -> Decomposition:
        """Decompose a demonstration given its (T, D) frame vectors (the database's layout)."""
        fv = np.asarray(frame_vectors, dtype=np.float32)
        if fv.ndim != 2:
            raise ValueError(f"frame_vectors must be a (T, D) array, got shape {fv.shape}")
        if fv.shape[1] != self.database.frame_dim:
            raise ValueError(
                f"frame vectors are {fv.shape[1]}-d but the database holds {self.database.frame_dim}-d "
                "frame vectors (same encoder and views are required)"
            )
        t = fv.shape[0]
        max_len = self.max_len if self.max_len is None else min(self.max_len, t)
        starts, ends, valid = candidate_intervals(t, self.min_len, max_len)
        s, e = starts[valid], ends[valid]
        ids, dist = self.index.search_intervals(fv, s, e)  # all candidates in one batch
        if self.mode == "default":
            sim = scoring.default_similarity(
                dist, scoring.durations(s, e), self.database.durations[ids], self.alpha
            )
        else:
            end_dist = scoring.angular_distance(fv[e - 1], self.database.end[ids])
            milestones = scoring.uvd_milestones_per_end(fv, np.unique(e - 1), **self.uvd_options)
            sim = scoring.ood_similarity(end_dist, s, e, milestones, self.beta)
        j = scoring.interval_scores(sim, s, e)
        dense = np.full(starts.shape, -np.inf)
        dense[valid] = j
        total, segments = max_sum_partition_dense(dense, self.min_len, max_len)
        # Map each chosen segment back to its candidate: row end-1, column length-min_len.
        rows = np.array([b - 1 for _, b in segments])
        cols = np.array([b - a - self.min_len for a, b in segments])
        flat = np.flatnonzero(valid.ravel())
        pos = np.searchsorted(flat, rows * starts.shape[1] + cols)
        seg_scores = [float(x) for x in j[pos]]
        neighbours = []
        for p in pos:
            entry = self.database.entry(int(ids[p]))
            entry["distance"] = float(dist[p])
            entry["similarity"] = float(sim[p])
            neighbours.append(entry)
        return Decomposition(
            segments=segments,
            scores=seg_scores,
            neighbours=neighbours,
            novelty=scoring.novelty(seg_scores),
            meta={"objective": total, "mode": self.mode, "backend": self.index.name,
                  "num_candidates": int(s.size)},
        )
