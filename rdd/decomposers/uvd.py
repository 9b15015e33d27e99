"""UVD (Zhang et al., ICRA 2024) as a decomposer: milestones (``rdd.core.milestones``) of an episode's
frame vectors become its keyframes."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.checks import FLAG, number, whole
from rdd.core.milestones import uvd_milestones
from rdd.data.episode import Episode
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.encoders.base import Encoder
from rdd.encoders.embed import DEFAULT_VIEWS, episode_frame_vectors
from rdd.registry import register
from rdd.segments import keyframes_to_segments

# UVD's own options (also RDD's uvd_options, which reach the same milestone search).
UVD_RULES = {"min_interval": whole(1), "gamma": number(0.0, exclusive_min=True), "normalize_curve": FLAG,
             "window_length": whole(1, allow_none=True)}


@register("decomposer", "uvd")
class UVDDecomposer(Decomposer):
    """UVD applied to an episode's frame vectors (per-view L2-normalised embeddings, concatenated)."""

    name = "uvd"
    OPTION_RULES = UVD_RULES

    def __init__(
        self,
        encoder: Encoder | None = None,
        views: Sequence[str] = DEFAULT_VIEWS,
        min_interval: int = 18,
        gamma: float = 0.08,
        normalize_curve: bool = False,
        window_length: int | None = None,
        cache=None,
    ):
        self.encoder = encoder
        self.views = tuple(views)
        opts = self.check_options(min_interval=min_interval, gamma=gamma, normalize_curve=normalize_curve,
                                  window_length=window_length)
        self.min_interval, self.gamma = opts["min_interval"], opts["gamma"]
        self.normalize_curve, self.window_length = opts["normalize_curve"], opts["window_length"]
        self.cache = cache

    def decompose_embeddings(self, frame_vectors: np.ndarray) -> Decomposition:
        """Segments from a (T, D) array of frame vectors."""
        milestones = uvd_milestones(
            frame_vectors,
            min_interval=self.min_interval,
            gamma=self.gamma,
            normalize_curve=self.normalize_curve,
            window_length=self.window_length,
        )
        segments = keyframes_to_segments(milestones, int(np.asarray(frame_vectors).shape[0]))
        return Decomposition(segments=segments, meta={"milestones": milestones})

    def decompose(self, episode: Episode) -> Decomposition:
        """Segment ``episode`` with UVD on its frame vectors under ``self.encoder``."""
        if self.encoder is None:
            raise ValueError(
                "UVDDecomposer needs an encoder (pass encoder=..., e.g. rdd.encoders.load_encoder)"
            )
        vectors = episode_frame_vectors(episode, self.encoder, self.views, cache=self.cache)
        result = self.decompose_embeddings(vectors)
        result.meta["encoder"] = getattr(self.encoder, "name", type(self.encoder).__name__)
        return result
