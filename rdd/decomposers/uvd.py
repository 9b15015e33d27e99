"""UVD (Zhang et al., ICRA 2024): milestones found by walking backwards over embedding distances.

Matches the official ``embedding_decomp`` of zcczhang/UVD with its default "embed" settings
(kernel smoothing, strict local maxima, ``min_interval`` spacing); read there, written anew here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.data.episode import Episode
from rdd.decomposers.base import Decomposer, Decomposition, check_choice, check_float, check_int
from rdd.encoders.base import Encoder
from rdd.encoders.embed import DEFAULT_VIEWS, episode_frame_vectors
from rdd.segments import keyframes_to_segments


def _as_float_matrix(embeddings: np.ndarray) -> np.ndarray:
    """The (T, D) array as floats, keeping its float dtype (the official code computes in it)."""
    emb = np.asarray(embeddings)
    if emb.ndim != 2:
        raise ValueError(f"UVD needs a (T, D) embedding array, got shape {emb.shape}")
    if not np.issubdtype(emb.dtype, np.floating):
        emb = emb.astype(np.float64)
    return emb


def kernel_smooth(x: np.ndarray, y: np.ndarray, gamma: float) -> np.ndarray:
    """Nadaraya-Watson regression of ``y`` on ``x`` with RBF weights exp(-gamma (x_i - x)^2)."""
    xf = np.asarray(x, dtype=np.float64)
    # Squared distances of integer positions are exact, so this equals sklearn's rbf_kernel.
    weights = np.exp((xf[:, None] - xf[None, :]) ** 2 * -gamma)
    return (weights * np.asarray(y)[:, None]).sum(axis=0) / weights.sum(axis=0)


def strict_local_maxima(values: np.ndarray) -> np.ndarray:
    """Indices i (end points excluded) with values[i] > values[i-1] and values[i] > values[i+1]."""
    v = np.asarray(values)
    if v.shape[0] < 3:
        return np.zeros(0, dtype=np.int64)
    inner = (v[1:-1] > v[:-2]) & (v[1:-1] > v[2:])
    return np.nonzero(inner)[0] + 1


def uvd_distance_curve(
    embeddings: np.ndarray,
    goal: int,
    gamma: float = 0.08,
    normalize_curve: bool = False,
    window_length: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Frame positions and the smoothed distance-to-goal curve UVD inspects for one backward step."""
    emb = _as_float_matrix(embeddings)
    goal = int(goal)
    if not 0 <= goal < emb.shape[0]:
        raise ValueError(f"goal frame {goal} is outside [0, {emb.shape[0] - 1}]")
    start = max(0, goal - (window_length or goal))
    window = emb[start : goal + 1]
    distances = np.linalg.norm(window - window[-1], axis=1)
    if normalize_curve:
        with np.errstate(divide="ignore", invalid="ignore"):
            distances = distances / np.linalg.norm(window[0] - window[-1])
    x = np.arange(start, goal + 1)
    with np.errstate(invalid="ignore"):
        return x, kernel_smooth(x, distances, gamma)


def uvd_previous_milestone(
    embeddings: np.ndarray,
    goal: int,
    min_interval: int = 18,
    gamma: float = 0.08,
    normalize_curve: bool = False,
    window_length: int | None = None,
) -> int | None:
    """The milestone one backward UVD step from frame ``goal`` finds, or None when there is none.

    The latest strict local maximum p of the smoothed distance-to-goal curve with
    ``goal - p > min_interval`` and ``p > min_interval``.
    """
    x, curve = uvd_distance_curve(embeddings, goal, gamma, normalize_curve, window_length)
    for p in x[strict_local_maxima(curve)][::-1]:
        if int(goal) - int(p) > min_interval and int(p) > min_interval:
            return int(p)
    return None


def uvd_milestones(
    embeddings: np.ndarray,
    min_interval: int = 18,
    gamma: float = 0.08,
    normalize_curve: bool = False,
    window_length: int | None = None,
) -> list[int]:
    """UVD milestones of a (T, D) embedding sequence, ascending, always ending at T-1."""
    emb = _as_float_matrix(embeddings)
    if emb.shape[0] == 0:
        raise ValueError("UVD needs at least one frame")
    goal = emb.shape[0] - 1
    milestones = [goal]
    while goal > (window_length or min_interval):
        previous = uvd_previous_milestone(
            emb, goal, min_interval, gamma, normalize_curve, window_length
        )
        if previous is None:
            break
        goal = previous
        milestones.append(goal)
        if goal < min_interval:
            break
    return milestones[::-1]


class UVDDecomposer(Decomposer):
    """UVD applied to an episode's frame vectors (per-view L2-normalised embeddings, concatenated)."""

    name = "uvd"

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
        owner = "decomposer uvd"
        self.min_interval = check_int(owner, "min_interval", min_interval, minimum=1)
        self.gamma = check_float(owner, "gamma", gamma, minimum=0.0, exclusive_min=True)
        self.normalize_curve = check_choice(owner, "normalize_curve", normalize_curve, (True, False))
        self.window_length = check_int(owner, "window_length", window_length, minimum=1, allow_none=True)
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
