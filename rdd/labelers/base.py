"""The labeler protocol: what turns an interval of an episode into a sub-task instruction.

Implementations: ``rdd.labelers.retrieval.RetrievalLabeler`` (the nearest database entry's
instruction), ``rdd.labelers.signals.SignalsLabeler`` (what the robot's hand and joint signals show),
``rdd.labelers.vlm.VLMLabeler`` (a vision-language model's instruction for a few frames) and, in the
harness, ``envs.labeler.PrivilegedLabeler`` (from the simulator's record).
One labeler serves every decomposer of a comparison, as the paper labels all methods' intervals
with one model.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from rdd.data.episode import Episode


class Labeler(Protocol):
    """Anything that turns an interval of an episode into an instruction."""

    def label(self, episode: Episode, segment: tuple[int, int]) -> str:
        """Instruction for frames ``[start, end)``."""
        ...


def label_all(labeler: Labeler, episode: Episode, segments: Sequence[tuple[int, int]]) -> list[str]:
    """Instructions for ``segments``: the labeler's own ``label_all`` (one batched call, e.g. a VLM's)
    when it has one, else its ``label`` per segment (all the protocol asks of a labeler)."""
    batched = getattr(labeler, "label_all", None)
    if batched is not None:
        return list(batched(episode, list(segments)))
    return [labeler.label(episode, tuple(s)) for s in segments]
