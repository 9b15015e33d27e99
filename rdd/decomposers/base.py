"""The decomposer interface and its result type."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from rdd.data.episode import Episode
from rdd.errors import InputError
from rdd.segments import Segment, segments_to_keyframes


@dataclass
class Decomposition:
    """A segmentation of one demonstration with optional per-segment details."""

    segments: list[Segment]
    scores: list[float] | None = None  # per-segment objective term J(I)
    neighbours: list[dict[str, Any]] | None = None  # per-segment matched database entry
    novelty: float | None = None  # RDD's Delta: mean interval score of the optimal partition
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def keyframes(self) -> list[int]:
        """The keyframe ``end - 1`` of each segment."""
        return segments_to_keyframes(self.segments)


class Decomposer(ABC):
    """Cuts a demonstration into sub-task segments."""

    name: str = "decomposer"

    @abstractmethod
    def decompose(self, episode: Episode) -> Decomposition:
        """Segment ``episode``."""

    def settings(self) -> dict[str, Any]:
        """Options in force that its arguments did not fix (RDD: chosen by calibration); none here."""
        return {}


# ----------------------------------------------------------------------------- option checks
# Every decomposer validates its options with these, so a bad value fails at construction with
# one line naming the decomposer, the option and the accepted range (``n_segments=2.5`` is not
# silently truncated, ``alpha=nan`` is not a NaN score later); the error's ``option`` lets a front
# end name the flag or key its user typed.
def check_int(owner: str, name: str, value: Any, minimum: int | None = None, allow_none: bool = False) -> int | None:
    """``value`` as an int (integral numbers only, no bools), at least ``minimum``."""
    if value is None and allow_none:
        return None
    ok = (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(float(value))
          and float(value).is_integer())
    if not ok:
        at_least = "" if minimum is None else f" >= {minimum}"
        raise InputError(f"{owner}: option {name} must be a whole number{at_least}, got {value!r}", option=name)
    out = int(value)
    if minimum is not None and out < minimum:
        raise InputError(f"{owner}: option {name} must be >= {minimum}, got {value!r}", option=name)
    return out


def check_float(owner: str, name: str, value: Any, minimum: float | None = None, maximum: float | None = None,
                exclusive_min: bool = False, allow_none: bool = False) -> float | None:
    """``value`` as a finite float within ``[minimum, maximum]`` (``(minimum, ...`` when exclusive)."""
    if value is None and allow_none:
        return None
    low = "" if minimum is None else f"{'>' if exclusive_min else '>='} {minimum}"
    high = "" if maximum is None else f"<= {maximum}"
    bounds = " and ".join(x for x in (low, high) if x)
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(float(value)):
        raise InputError(f"{owner}: option {name} must be a finite number{' ' + bounds if bounds else ''}, "
                         f"got {value!r}", option=name)
    out = float(value)
    low_bad = minimum is not None and (out <= minimum if exclusive_min else out < minimum)
    if low_bad or (maximum is not None and out > maximum):
        raise InputError(f"{owner}: option {name} must be {bounds}, got {value!r}", option=name)
    return out


def check_choice(owner: str, name: str, value: Any, choices: Sequence[Any]) -> Any:
    """``value`` if it is one of ``choices``."""
    if value not in choices:
        raise InputError(f"{owner}: option {name} must be one of {list(choices)}, got {value!r}", option=name)
    return value
