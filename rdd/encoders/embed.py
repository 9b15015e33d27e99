"""Frame vectors: per-view L2-normalised embeddings concatenated over views (DESIGN.md)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.data.episode import Episode
from rdd.encoders.base import Encoder

DEFAULT_VIEWS: tuple[str, ...] = ("front", "wrist")


def l2_normalize(x: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Rows of ``x`` scaled to unit L2 norm (zero rows stay zero)."""
    x = np.asarray(x, dtype=np.float32)
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / np.maximum(norm, eps)


def concat_views(per_view: Sequence[np.ndarray]) -> np.ndarray:
    """Frame vectors from per-view embeddings (each (T, D_v)): normalise each view, then concatenate."""
    if not per_view:
        raise ValueError("at least one view is needed to build frame vectors")
    lengths = {int(np.asarray(v).shape[0]) for v in per_view}
    if len(lengths) != 1:
        raise ValueError(f"views have different numbers of frames: {sorted(lengths)}")
    return np.concatenate([l2_normalize(v) for v in per_view], axis=1).astype(np.float32)


def episode_frame_vectors(
    episode: Episode,
    encoder: Encoder,
    views: Sequence[str] = DEFAULT_VIEWS,
    cache=None,
) -> np.ndarray:
    """(T, sum of view dims) frame vectors of ``episode`` under ``encoder``.

    ``cache``: an embedding cache (see ``rdd.encoders.cache``) or None for no caching.
    """
    per_view = []
    for view in views:
        if cache is not None:
            emb = cache.get_or_compute(episode, encoder, view)
        else:
            emb = encoder.encode(episode.frames(view))
        per_view.append(emb)
    return concat_views(per_view)
