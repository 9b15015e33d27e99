"""The decomposer interface and its result type."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

from rdd.checks import CheckedOptions
from rdd.data.episode import Episode
from rdd.segments import Segment, segments_to_keyframes


@dataclass
class Decomposition:
    """A segmentation of one demonstration with optional per-segment details."""

    segments: list[Segment]
    scores: list[float] | None = None  # per-segment objective term J(I)
    neighbours: list[dict[str, Any]] | None = None  # per-segment matched database entry
    novelty: float | None = None  # RDD's Delta: mean interval score of the optimal partition
    meta: dict[str, Any] = field(default_factory=dict)
    confidence: list[float] | None = None  # per segment, in [0, 1] (rdd.core.confidence)
    instructions: list[str] | None = None  # per segment, when the decomposer names them itself

    @property
    def keyframes(self) -> list[int]:
        """The keyframe ``end - 1`` of each segment."""
        return segments_to_keyframes(self.segments)


class Decomposer(CheckedOptions, ABC):
    """Cuts a demonstration into sub-task segments.

    Each option's range is declared once, in ``OPTION_RULES``: the constructor and ``check_options``
    (which needs no runtime object) both apply it, so a bad value fails with one line naming the
    decomposer, the option and the range (``n_segments=2.5`` is not silently truncated,
    ``alpha=nan`` is not a NaN score later).
    """

    name: str = "decomposer"
    OPTION_KIND = "decomposer"

    @abstractmethod
    def decompose(self, episode: Episode) -> Decomposition:
        """Segment ``episode``."""

    def settings(self) -> dict[str, Any]:
        """Options in force that its arguments did not fix (RDD: chosen by calibration); none here."""
        return {}
