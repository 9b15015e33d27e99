"""The labeler protocol: what turns an interval of an episode into a sub-task instruction.

Implementations: ``rdd.labelers.retrieval.RetrievalLabeler`` (the nearest database entry's
instruction), ``rdd.labelers.signals.SignalsLabeler`` (what the robot's hand and joint signals show),
``rdd.labelers.vlm.VLMLabeler`` (a vision-language model's instruction for a few frames) and, in the
harness, ``envs.labeler.PrivilegedLabeler`` (from the simulator's record).
One labeler serves every decomposer of a comparison, as the paper labels all methods' intervals
with one model.
"""

from __future__ import annotations

from typing import Protocol

from rdd.data.episode import Episode


class Labeler(Protocol):
    """Anything that turns an interval of an episode into an instruction."""

    def label(self, episode: Episode, segment: tuple[int, int]) -> str:
        """Instruction for frames ``[start, end)``."""
        ...
