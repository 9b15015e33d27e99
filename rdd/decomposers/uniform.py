"""Uniform baseline: equal-length segments."""

from __future__ import annotations

from rdd.checks import FLAG, whole
from rdd.data.episode import Episode
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.registry import register
from rdd.segments import Segment


def uniform_segments(num_frames: int, n_segments: int = 10) -> list[Segment]:
    """``n_segments`` contiguous segments of [0, num_frames) whose lengths differ by at most one.

    Longer segments come first. Fewer frames than segments is an error (no empty segments).
    """
    if n_segments < 1:
        raise ValueError(f"n_segments must be at least 1, got {n_segments}")
    if num_frames < n_segments:
        raise ValueError(
            f"cannot cut {num_frames} frames into n_segments={n_segments} non-empty segments"
        )
    base, extra = divmod(num_frames, n_segments)
    segments: list[Segment] = []
    start = 0
    for j in range(n_segments):
        end = start + base + (1 if j < extra else 0)
        segments.append((start, end))
        start = end
    return segments


@register("decomposer", "uniform")
class UniformDecomposer(Decomposer):
    """Cuts every episode into ``n_segments`` equal parts (as even as integer frames allow)."""

    name = "uniform"
    OPTION_RULES = {"n_segments": whole(1), "clip_to_length": FLAG}

    def __init__(self, n_segments: int = 10, clip_to_length: bool = False):
        opts = self.check_options(n_segments=n_segments, clip_to_length=clip_to_length)
        self.n_segments = opts["n_segments"]
        # When set, an episode shorter than n_segments gets one frame per segment instead of an error.
        self.clip_to_length = opts["clip_to_length"]

    def decompose(self, episode: Episode) -> Decomposition:
        """Equal segments of ``episode``."""
        n = episode.num_frames
        k = min(self.n_segments, n) if self.clip_to_length else self.n_segments
        try:
            segments = uniform_segments(n, k)
        except ValueError as exc:
            raise ValueError(
                f"episode {episode.name!r}: {exc} (set clip_to_length=true to allow fewer)"
            ) from exc
        return Decomposition(segments=segments, meta={"n_segments": k})
