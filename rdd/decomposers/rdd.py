"""RDD (Yan et al., NeurIPS 2025): the partition whose intervals best match database sub-tasks.

Every candidate interval ``[start, end)`` with ``min_len <= end - start <= max_len`` is scored
``J(I) = weight(I) * sim(I, I_nn)`` and the exact maximum-sum partition is found by dynamic
programming over the dense score array.

* Default mode (Eq. 3.4): ``I_nn`` is the entry nearest to ``concat(f[start], f[end-1])``; all
  candidates are retrieved in one batch. ``beta != 0`` adds ``beta * G(I)`` as the official code does.
* OOD mode (Eq. 3.5): ``I_nn`` is the entry whose *end* frame is nearest to ``f[end-1]`` (the
  official ``embed_mode='ood'``), so retrieval is one query per end frame; the score is
  ``-delta(f[end-1], E_nn) + beta * G(I)``. The novelty Delta is defined on the default-mode
  partition, so it is computed there (``meta["novelty_partition"] == "default"``).

``G(I) = -|start - UVD(end-1)| / weight(I)`` with one backward UVD step per end frame, computed for
all end frames at once (``rdd.core.milestones.uvd_previous_milestones_all``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rdd.checks import check_options, number, one_of, whole
from rdd.core import confidence, scoring
from rdd.core.solver import candidate_intervals, max_sum_partition_dense
from rdd.data.episode import Episode
from rdd.database.model import SubtaskDatabase
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.decomposers.uvd import UVD_RULES
from rdd.encoders.base import Encoder
from rdd.encoders.embed import DEFAULT_VIEWS, episode_frame_vectors
from rdd.errors import InputError
from rdd.index import NearestIndex, load_index
from rdd.registry import register

MODES = ("default", "ood")
PAPER_DEFAULTS: dict[str, Any] = {"alpha": 1.0, "min_len": 2, "max_len": None}
DEFAULT_BETA = {"default": 0.0, "ood": 0.1}


@register("decomposer", "rdd")
class RDDDecomposer(Decomposer):
    """Retrieval-based demonstration decomposer over a :class:`SubtaskDatabase`.

    The defaults are the paper's (``alpha`` 1, ``min_len`` 2, ``max_len`` unbounded);
    :meth:`calibrated` takes the values the database's calibration chose (``rdd.core.calibrate``)
    instead. ``beta`` left out is 0 in the default mode and 0.1 in the OOD mode. Frame vectors follow
    the database's ``normalize_views`` setting.
    """

    name = "rdd"
    OPTION_RULES = {
        "mode": one_of(*MODES), "alpha": number(0.0, scoring.ALPHA_MAX),
        "beta": number(0.0, scoring.ALPHA_MAX, allow_none=True), "min_len": whole(1),
        "max_len": whole(1, allow_none=True),
    }

    @classmethod
    def check_options(cls, **options: Any) -> dict[str, Any]:
        """The options' ranges (those left out: the calibration's or the paper's, checked when built),
        ``max_len >= min_len`` when both are given, ``uvd_options`` and ``index_options`` (the index's own)."""
        owner = cls.option_owner()
        opts = super().check_options(**options)
        low, high = opts.get("min_len"), opts.get("max_len")
        if low is not None and high is not None and high < low:
            raise InputError(f"{owner}: option max_len must be null (unbounded) or >= min_len={low}, "
                             f"got {options['max_len']!r}", option="max_len")
        if opts.get("uvd_options"):
            opts["uvd_options"] = check_options(owner, UVD_RULES, dict(opts["uvd_options"]), prefix="uvd_options.")
        index = opts.get("index", "exact")
        if opts.get("index_options") and isinstance(index, str):
            from rdd.registry import component

            try:
                component("index", index).check_options(**opts["index_options"])
            except InputError as exc:
                raise InputError(f"{owner}: index_options: {exc}", option=f"index_options.{exc.option}") from None
        return opts

    def __init__(
        self,
        database: SubtaskDatabase,
        encoder: Encoder | None = None,
        alpha: float = PAPER_DEFAULTS["alpha"],
        beta: float | None = None,
        mode: str = "default",
        min_len: int = PAPER_DEFAULTS["min_len"],
        max_len: int | None = PAPER_DEFAULTS["max_len"],
        index: str | NearestIndex = "exact",
        views: Sequence[str] = DEFAULT_VIEWS,
        index_options: Mapping[str, Any] | None = None,
        uvd_options: Mapping[str, Any] | None = None,
        cache=None,
    ) -> None:
        if not isinstance(database, SubtaskDatabase):
            raise TypeError(f"database must be a SubtaskDatabase, got {type(database).__name__}")
        self.check_options(mode=mode)
        chosen = {"alpha": alpha, "min_len": min_len, "max_len": max_len}
        # Where each value came from, as the output records it (calibrated() says "calibration").
        self.option_source = {k: "paper" if chosen[k] == PAPER_DEFAULTS[k] else "given" for k in PAPER_DEFAULTS}
        opts = self.check_options(alpha=alpha, beta=DEFAULT_BETA[mode] if beta is None else beta,
                                  min_len=min_len, max_len=max_len, uvd_options=uvd_options)
        self.alpha, self.beta = opts["alpha"], opts["beta"]
        self.min_len, self.max_len = opts["min_len"], opts["max_len"]
        self.mode = mode
        self.database = database
        self.encoder = encoder
        self.views = tuple(views)
        self.normalize_views = bool(database.meta.get("normalize_views", True))
        self.uvd_options = dict(opts["uvd_options"] or {})
        self.cache = cache
        if encoder is not None:
            database.check_compatible(encoder, self.views)
        if isinstance(index, NearestIndex):
            if index_options:
                raise ValueError("index_options apply only when index is given by name")
            self.index = index
        elif isinstance(index, str):
            self.index = load_index(index, **dict(index_options or {}))
        else:
            raise TypeError(f"index must be an index name or a NearestIndex, got {type(index).__name__}")
        self.index.fit(
            database.begin, database.end, cache_dir=database.directory,
            key=database.fingerprint() if database.directory is not None else None,
        )

    @classmethod
    def calibrated(cls, database: SubtaskDatabase, encoder: Encoder | None = None, cache=None,
                   **options: Any) -> RDDDecomposer:
        """RDD with the ``alpha``, ``min_len`` and ``max_len`` the database's calibration chose
        (``rdd.core.calibrate``; a database without one is an error); ``options`` given here win."""
        if not isinstance(database, SubtaskDatabase):
            raise TypeError(f"database must be a SubtaskDatabase, got {type(database).__name__}")
        decomposer = cls(database, encoder, cache=cache, **{**database.calibrated_options(), **options})
        decomposer.option_source = {k: "given" if k in options else "calibration" for k in PAPER_DEFAULTS}
        return decomposer

    # The harness builds the calibration stage for a decomposer made this way.
    calibrated.__func__.uses_calibration = True

    def settings(self) -> dict[str, Any]:
        """The options in force (given, calibrated or the paper's: ``option_source`` says which) and the index."""
        return {"alpha": self.alpha, "min_len": self.min_len, "max_len": self.max_len, "mode": self.mode,
                "beta": self.beta, "index": self.index.name, "option_source": dict(self.option_source)}

    def decompose(self, episode: Episode) -> Decomposition:
        """Embed ``episode`` with the encoder and decompose it."""
        if self.encoder is None:
            raise ValueError("RDDDecomposer.decompose(episode) needs an encoder; "
                             "pass encoder= or call decompose_embeddings(frame_vectors)")
        self._check_length(episode.num_frames, f"episode {episode.name!r}")  # before paying for encoding
        fv = episode_frame_vectors(episode, self.encoder, views=self.views, cache=self.cache,
                                   normalize=self.normalize_views)
        result = self.decompose_embeddings(fv)
        result.meta["episode"] = episode.name
        return result

    def _check_length(self, num_frames: int, what: str) -> None:
        if num_frames < self.min_len:  # no partition exists: say so before any work, naming the option
            raise InputError(f"{what}: {num_frames} frame(s), shorter than min_len={self.min_len}, the shortest "
                             "segment RDD cuts (the database's calibration or the min_len option)")

    def _check(self, frame_vectors: np.ndarray) -> np.ndarray:
        fv = np.asarray(frame_vectors, dtype=np.float32)
        if fv.ndim != 2:
            raise ValueError(f"frame_vectors must be a (T, D) array, got shape {fv.shape}")
        self._check_length(fv.shape[0], "frame_vectors")
        if fv.shape[1] != self.database.frame_dim:
            raise ValueError(
                f"frame vectors are {fv.shape[1]}-d but the database holds {self.database.frame_dim}-d "
                "frame vectors: decompose with the encoder and views the database was built with, or rebuild "
                "it (build-db) if those views changed since, as the state view did (joints + 2 values per hand)"
            )
        return fv

    def _candidates(self, t: int, min_len: int, max_len: int | None):
        max_len = max_len if max_len is None else min(max_len, t)
        starts, ends, valid = candidate_intervals(t, min_len, max_len)
        return starts, valid, starts[valid], ends[valid], max_len

    def _milestones(self, fv: np.ndarray, e: np.ndarray) -> np.ndarray:
        return scoring.uvd_milestones_per_end(fv, np.unique(e - 1), **self.uvd_options)

    def _solve(self, j: np.ndarray, starts: np.ndarray, valid: np.ndarray, min_len: int,
               max_len: int | None) -> tuple[float, list, np.ndarray]:
        """Best partition of the candidate scores ``j``; also each segment's position in ``j``."""
        dense = np.full(starts.shape, -np.inf)
        dense[valid] = j
        total, segments = max_sum_partition_dense(dense, min_len, max_len)
        # Map each chosen segment back to its candidate: row end-1, column length-min_len.
        rows = np.array([b - 1 for _, b in segments])
        cols = np.array([b - a - min_len for a, b in segments])
        flat = np.flatnonzero(valid.ravel())
        pos = np.searchsorted(flat, rows * starts.shape[1] + cols)
        return total, segments, pos

    def decompose_embeddings(self, frame_vectors: np.ndarray) -> Decomposition:
        """Decompose a demonstration given its (T, D) frame vectors (the database's layout)."""
        fv = self._check(frame_vectors)
        starts, valid, s, e, max_len = self._candidates(fv.shape[0], self.min_len, self.max_len)
        ids, dist = self.index.search_intervals(fv, s, e)  # all candidates in one batch
        sim = scoring.default_similarity(
            dist, scoring.durations(s, e), self.database.durations[ids], self.alpha
        )
        meta: dict[str, Any] = {**self.settings(), "num_candidates": int(s.size)}
        if self.mode == "ood" or self.beta == 0:
            # Standard RDD (Eq. 3.4): the partition whose mean score is the novelty Delta.
            j = scoring.interval_scores(sim, s, e)
            total, segments, pos = self._solve(j, starts, valid, self.min_len, max_len)
            delta = scoring.novelty(j[pos])
            if self.mode == "default":
                return self._result(total, segments, pos, j, ids, dist, sim, delta, meta, fv)
            meta["default_segments"] = [list(x) for x in segments]
            end_ids, end_dist = self.index.search_ends(fv)  # nearest end frame, per end frame
            ids, dist = end_ids[e - 1], end_dist[e - 1]
            sim = scoring.ood_similarity(dist, s, e, self._milestones(fv, e), self.beta)  # Eq. 3.5
        else:
            # The official code adds beta * G(I) in the default mode too when beta != 0.
            sim = sim + self.beta * scoring.uvd_prior(s, e, self._milestones(fv, e))
            delta = None
        j = scoring.interval_scores(sim, s, e)
        total, segments, pos = self._solve(j, starts, valid, self.min_len, max_len)
        if delta is None:
            delta = scoring.novelty(j[pos])
        return self._result(total, segments, pos, j, ids, dist, sim, delta, meta, fv)

    def _result(self, total, segments, pos, j, ids, dist, sim, delta, meta, fv) -> Decomposition:
        neighbours = []
        for p in pos:
            entry = self.database.entry(int(ids[p]))
            entry["distance"] = float(dist[p])
            entry["similarity"] = float(sim[p])
            neighbours.append(entry)
        meta.update(objective=total, novelty_partition="default" if self.beta == 0 or self.mode == "ood"
                    else "default+beta*G")
        return Decomposition(
            segments=segments,
            scores=[float(x) for x in j[pos]],
            neighbours=neighbours,
            novelty=delta,
            meta=meta,
            confidence=confidence.for_segments(self.database, self.index, fv, segments, [int(ids[p]) for p in pos],
                                              self.min_len, self.max_len),
        )
