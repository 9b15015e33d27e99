"""Retrieval labeler: an interval gets the instruction of its nearest sub-task database entry.

The interval vector is built exactly as the database's entries are (``concat(frame[start],
frame[end-1])`` of per-view L2-normalised embeddings, same encoder and views), and the nearest
entry under angular distance supplies the instruction.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.data.episode import Episode
from rdd.database.model import SubtaskDatabase
from rdd.encoders.base import Encoder
from rdd.encoders.embed import episode_frame_vectors
from rdd.index import load_index
from rdd.index.base import NearestIndex
from rdd.registry import register
from rdd.segments import Segment


@register("labeler", "retrieval")
class RetrievalLabeler:
    """Labels intervals with the instruction of the nearest entry of a :class:`SubtaskDatabase`."""

    name = "retrieval"

    def __init__(self, database: SubtaskDatabase, encoder: Encoder, index: NearestIndex | str = "exact",
                 cache=None) -> None:
        views = database.meta.get("views")
        if not views:
            raise ValueError("the retrieval labeler needs a database whose meta names its 'views'")
        database.check_compatible(encoder=encoder, views=views)
        if not any(database.labels):
            raise ValueError("the retrieval labeler needs a database with instructions (all labels are empty)")
        self.database = database
        self.encoder = encoder
        self.views = tuple(views)
        self.cache = cache
        self.index = load_index(index) if isinstance(index, str) else index
        self.index.fit(database.begin, database.end)
        self._fv: dict[str, np.ndarray] = {}  # frame vectors of the last episodes seen, by fingerprint

    def _frame_vectors(self, episode: Episode) -> np.ndarray:
        key = f"{episode.name}:{episode.fingerprint(self.views)}"
        if key not in self._fv:
            if len(self._fv) >= 8:  # keep memory bounded across long evaluation loops
                self._fv.pop(next(iter(self._fv)))
            self._fv[key] = episode_frame_vectors(
                episode, self.encoder, views=self.views, cache=self.cache,
                normalize=bool(self.database.meta.get("normalize_views", True)))
        return self._fv[key]

    def nearest(self, episode: Episode, segments: Sequence[Segment]) -> tuple[np.ndarray, np.ndarray]:
        """Nearest entry ids and angular distances of ``segments`` of ``episode``."""
        fv = self._frame_vectors(episode)
        starts = np.array([int(s) for s, _ in segments], dtype=np.int64)
        ends = np.array([int(e) for _, e in segments], dtype=np.int64)
        return self.index.search_intervals(fv, starts, ends)

    def label(self, episode: Episode, segment: Segment) -> str:
        """The nearest entry's instruction for frames ``[start, end)``."""
        return self.label_all(episode, [segment])[0]

    def label_all(self, episode: Episode, segments: Sequence[Segment]) -> list[str]:
        """Labels of several intervals of one episode (one batched search)."""
        ids, _ = self.nearest(episode, segments)
        return [self.database.labels[int(i)] for i in ids]
