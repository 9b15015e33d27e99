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
# Saved with a database holding the state view, checked on load: 1 took a hand's level as the mean of
# its dims, 2 the median of its finger dims (a database of another version would be matched wrongly).
STATE_VIEW_VERSION = 2
# Chosen on G1 training episodes (database 16-29, scored on 30-35 against the hand rule, boundary F1
# at +-5 frames): arm joints centred 0.55, standardised with this floor 0.69, with the hands 0.90.
STATE_STD_FLOOR = 0.1
# Each hand's level also enters in its own units (0 closed .. 1 open), centred at half open and
# spanning 16 standardised units: an annotation with fixed thresholds on the hands (the hysteresis
# one) is told apart by where a hand is, not where it is in this episode's range. Chosen by 4-fold
# cross-validation over G1 training episodes 16-35 against both annotations (boundary F1 at +-5:
# rule 0.73 -> 0.74, hysteresis 0.49 -> 0.66; weights 12-20 gave 0.71-0.76 and 0.64-0.71).
STATE_LEVEL_CENTRE = 0.5
STATE_LEVEL_SPAN = 16.0


def state_vectors(episode: Episode) -> np.ndarray:
    """(T, J + 2H) the ``state`` view: the joint positions and each hand's (or the gripper's)
    opening, each dimension standardised over the episode, then each opening in its own units.

    The hands come from ``meta["hand_openings"]`` (a LeRobot reader's per-hand median of the finger
    dims), else ``meta["hand_levels"]`` (the mean of a hand's dims), else the gripper flag. Each
    dimension minus its mean, over its standard deviation, so a hand's 0..1 and an arm's radians count
    alike; the deviation is floored at ``STATE_STD_FLOOR`` of the largest one's, so a
    dimension that barely moves (a hand at rest, sensor noise) stays small instead of being scaled up.
    The last H columns are ``(level - STATE_LEVEL_CENTRE) * STATE_LEVEL_SPAN``, the same in every episode.
    """
    q = episode.joint_positions
    if q is None or np.asarray(q).ndim != 2 or not np.asarray(q).shape[1]:
        raise InputError(f"episode {episode.name!r}: view {STATE_VIEW!r} needs the episode's joint state "
                         "(joint_positions; a LeRobot dataset's observation.state), and it has none")
    q = np.asarray(q, dtype=np.float64)
    hands = episode.meta.get("hand_openings")
    if hands is None:
        hands = episode.meta.get("hand_levels")
    if hands is None and episode.gripper_open is not None:
        hands = episode.gripper_open
    levels = np.zeros((len(q), 0)) if hands is None else np.asarray(hands, dtype=np.float64).reshape(len(q), -1)
    q = np.concatenate([q, levels], axis=1)
    sd = q.std(axis=0)
    scale = np.maximum(sd, STATE_STD_FLOOR * sd.max()) if sd.max() > 0 else np.ones_like(sd)
    absolute = (levels - STATE_LEVEL_CENTRE) * STATE_LEVEL_SPAN
    return np.concatenate([(q - q.mean(axis=0)) / scale, absolute], axis=1).astype(np.float32)


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
