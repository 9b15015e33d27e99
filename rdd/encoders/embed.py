"""Frame vectors: per-view L2-normalised embeddings concatenated over views (docs/architecture.md);
the view ``state`` is the joint state instead of a camera's embedding."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.data.episode import Episode
from rdd.encoders._stream import encode_view
from rdd.encoders.base import Encoder
from rdd.errors import InputError

DEFAULT_VIEWS: tuple[str, ...] = ("front", "wrist")
# The robot's joint state as one more view: no image, no encoder (a camera of that name wins).
STATE_VIEW = "state"
# Chosen on G1 training episodes (database 16-29, scored on 30-35 against the hand rule, boundary F1
# at +-5 frames): arm joints centred 0.55, standardised with this floor 0.69, with the hands 0.90.
STATE_STD_FLOOR = 0.1


def state_vectors(episode: Episode) -> np.ndarray:
    """(T, J + H) the ``state`` view: the joint positions and each hand's (or the gripper's)
    opening, each dimension standardised over the episode.

    The hands come from ``meta["hand_levels"]`` (a LeRobot reader's per-hand level), else the gripper
    flag. Each dimension minus its mean, over its standard deviation, so a hand's 0..1 and an arm's
    radians count alike; the deviation is floored at ``STATE_STD_FLOOR`` of the largest one's, so a
    dimension that barely moves (a hand at rest, sensor noise) stays small instead of being scaled up.
    """
    q = episode.joint_positions
    if q is None or np.asarray(q).ndim != 2 or not np.asarray(q).shape[1]:
        raise InputError(f"episode {episode.name!r}: view {STATE_VIEW!r} needs the episode's joint state "
                         "(joint_positions; a LeRobot dataset's observation.state), and it has none")
    q = np.asarray(q, dtype=np.float64)
    hands = episode.meta.get("hand_levels")
    if hands is None and episode.gripper_open is not None:
        hands = episode.gripper_open
    if hands is not None:
        q = np.concatenate([q, np.asarray(hands, dtype=np.float64).reshape(len(q), -1)], axis=1)
    sd = q.std(axis=0)
    scale = np.maximum(sd, STATE_STD_FLOOR * sd.max()) if sd.max() > 0 else np.ones_like(sd)
    return ((q - q.mean(axis=0)) / scale).astype(np.float32)


def has_view(episode: Episode, view: str) -> bool:
    """Whether ``episode`` can give frame vectors of ``view``: a camera, or its joint state."""
    return view in episode.views or (view == STATE_VIEW and episode.joint_positions is not None)


def l2_normalize(x: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Rows of ``x`` scaled to unit L2 norm (zero rows stay zero)."""
    x = np.asarray(x, dtype=np.float32)
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / np.maximum(norm, eps)


def concat_views(per_view: Sequence[np.ndarray], normalize: bool = True) -> np.ndarray:
    """Frame vectors from per-view embeddings (each (T, D_v)): normalise each view, then concatenate.

    ``normalize=False`` concatenates the raw embeddings (the official RDD code's layout).
    """
    if not per_view:
        raise ValueError("at least one view is needed to build frame vectors")
    lengths = {int(np.asarray(v).shape[0]) for v in per_view}
    if len(lengths) != 1:
        raise ValueError(f"views have different numbers of frames: {sorted(lengths)}")
    parts = [l2_normalize(v) if normalize else np.asarray(v, dtype=np.float32) for v in per_view]
    return np.concatenate(parts, axis=1).astype(np.float32)


def episode_frame_vectors(
    episode: Episode,
    encoder: Encoder,
    views: Sequence[str] = DEFAULT_VIEWS,
    cache=None,
    normalize: bool = True,
    frames: Sequence[int] | np.ndarray | None = None,
) -> np.ndarray:
    """(T, sum of view dims) frame vectors of ``episode`` under ``encoder``.

    ``cache``: an embedding cache (see ``rdd.encoders.cache``) or None for no caching.
    ``frames``: only these frame indices (rows in that order); the encoder then sees only those
    images unless the cache already holds the whole episode. Subsets are not cached.
    """
    idx = None if frames is None else np.asarray(frames, dtype=np.int64)
    if idx is not None and idx.size and (idx.min() < 0 or idx.max() >= episode.num_frames):
        raise ValueError(f"episode {episode.name!r}: frame indices must be in [0, {episode.num_frames})")
    per_view = []
    for view in views:
        if view == STATE_VIEW and view not in episode.views:
            state = state_vectors(episode)
            per_view.append(state if idx is None else state[idx])
            continue
        if idx is None:
            emb = (cache.get_or_compute(episode, encoder, view) if cache is not None
                   else encode_view(encoder, episode, view))
        else:
            full = cache.get(episode, encoder, view) if cache is not None else None
            emb = full[idx] if full is not None else encode_view(encoder, episode, view, idx)
        per_view.append(emb)
    return concat_views(per_view, normalize=normalize)
