"""A segmentation that already exists: a file's (a ``decompose`` output, or one a person reviewed with
``python -m rdd review``) or, without a file, the episode's own sub-task annotations.

``--decomposer given --option file=reviewed.json`` turns a reviewed file back into every output
``decompose`` writes (``--write-lerobot`` included), with its instructions; an episode the file does
not hold, or holds with another frame count, is an error naming the file, the episode and the field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rdd.checks import Rule
from rdd.data.episode import Episode
from rdd.decomposers.base import Decomposer, Decomposition
from rdd.errors import InputError
from rdd.registry import register


def _path(owner: str, name: str, value: Any) -> str | None:
    if value is not None and (not isinstance(value, (str, Path)) or not str(value)):
        raise InputError(f"{owner}: option {name} must be null (the episodes' own annotations) or the path of "
                         f"a decompose output, got {value!r}", option=name)
    return None if value is None else str(value)


@register("decomposer", "given")
class GivenDecomposer(Decomposer):
    """Each episode's segments (and instructions) as ``file`` records them, else as the episode's
    own annotation (``episode.segments``, e.g. LeRobot's sub-tasks)."""

    name = "given"
    OPTION_RULES: dict[str, Rule] = {"file": _path}

    def __init__(self, file: str | None = None) -> None:
        from rdd.review.session import read_predictions

        self.file = self.check_options(file=file)["file"]
        self.records = {} if self.file is None else {
            r["episode"]: r for r in read_predictions(self.file, flag="given: option file")["episodes"]}

    def decompose(self, episode: Episode) -> Decomposition:
        """The file's (or the episode's own) segments of ``episode``."""
        if self.file is None:
            if episode.segments is None:
                raise InputError(f"given: episode {episode.name!r} carries no sub-task annotation; pass "
                                 "--option file=FILE (a decompose output or a reviewed file)")
            return Decomposition(segments=list(episode.segments), instructions=episode.instructions)
        rec = self.records.get(episode.name)
        if rec is None:
            raise InputError(f"given: option file {self.file}: no episode {episode.name!r} (field 'episode')")
        if rec["num_frames"] != episode.num_frames:
            raise InputError(f"given: option file {self.file}: episode {episode.name!r} field 'num_frames' is "
                             f"{rec['num_frames']}, but the data has {episode.num_frames} frames")
        texts = rec.get("instructions")
        return Decomposition(segments=[(int(s), int(e)) for s, e in rec["segments"]],
                             instructions=None if texts is None else ["" if t is None else str(t) for t in texts],
                             meta={"file": self.file})
