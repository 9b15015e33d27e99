"""The entries a sub-task database is built from: each labelled segment's boundary frame vectors."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rdd.data.episode import Episode
from rdd.database.store import PER_ENTRY
from rdd.encoders.base import Encoder
from rdd.encoders.embed import episode_frame_vectors
from rdd.segments import Segment, validate_segments

Entries = tuple[list[np.ndarray], list[np.ndarray], list[int], list[str], dict[str, list], dict[str, np.ndarray]]


def segment_entries(
    episodes: Sequence[Episode],
    segmentations: Sequence[Sequence[Segment]] | None,
    encoder: Encoder,
    views: Sequence[str],
    cache,
    instructions: Sequence[Sequence[str]] | None,
    normalize_views: bool,
    keep_frames: Sequence[str],
) -> Entries:
    """Begin and end frame vectors, durations, instructions and per-entry provenance of every
    segment of ``episodes``, and the whole frame vectors of those in ``keep_frames``
    (the arguments of :meth:`rdd.database.model.SubtaskDatabase.build`)."""
    if segmentations is not None and len(segmentations) != len(episodes):
        raise ValueError(
            f"{len(segmentations)} segmentations given for {len(episodes)} episodes"
        )
    if instructions is not None and len(instructions) != len(episodes):
        raise ValueError(f"{len(instructions)} instruction lists given for {len(episodes)} episodes")
    names = [ep.name for ep in episodes]
    unknown = sorted(set(keep_frames) - set(names))
    if unknown:
        raise ValueError(f"keep_frames names episodes that are not being built: {unknown}")
    if len(set(names)) != len(names) and keep_frames:
        raise ValueError("episode names must be unique to keep frames for calibration")
    begin, end, durations, labels = [], [], [], []
    meta_lists: dict[str, list] = {k: [] for k in PER_ENTRY}
    frames: dict[str, np.ndarray] = {}
    for i, ep in enumerate(episodes):
        segs = segmentations[i] if segmentations is not None else ep.segments
        if segs is None:
            raise ValueError(f"episode {ep.name!r} has no segmentation (pass segmentations=)")
        try:
            segs = validate_segments(segs, ep.num_frames)
        except ValueError as exc:
            raise ValueError(f"episode {ep.name!r}: {exc}") from exc
        if instructions is not None:
            instr = list(instructions[i])
        elif ep.instructions is not None and (
            ep.segments is None or [tuple(int(v) for v in s) for s in ep.segments] == segs
        ):
            # the episode's instructions describe this segmentation (its own, or it has none)
            instr = list(ep.instructions)
        else:
            # An unannotated segment has no sub-task: the episode's goal (a LeRobot task string, an
            # RLBench variation description) stays in the entry's task, never its instruction.
            instr = [""] * len(segs)
        if len(instr) != len(segs):
            raise ValueError(
                f"episode {ep.name!r}: {len(instr)} instructions for {len(segs)} segments"
            )
        if ep.name in keep_frames:
            fv = episode_frame_vectors(ep, encoder, views=views, cache=cache, normalize=normalize_views)
            frames[ep.name] = fv
            rows = {f: f for f in range(ep.num_frames)}
        else:
            needed = sorted({f for s, e in segs for f in (s, e - 1)})
            fv = episode_frame_vectors(ep, encoder, views=views, cache=cache,
                                       normalize=normalize_views, frames=needed)
            rows = {f: r for r, f in enumerate(needed)}
        for (s, e), text in zip(segs, instr, strict=True):
            begin.append(fv[rows[s]])
            end.append(fv[rows[e - 1]])
            durations.append(e - 1 - s)
            labels.append(text)
            meta_lists["episodes"].append(ep.name)
            meta_lists["tasks"].append(ep.task)
            meta_lists["starts"].append(s)
            meta_lists["ends"].append(e)
    if not begin:
        raise ValueError("no segments to build a database from (no episodes given)")
    return begin, end, durations, labels, meta_lists, frames


def merge_entries(parts: Sequence[Entries]) -> Entries:
    """The entries of several :func:`segment_entries` results, in order (as one call over all their
    episodes would give)."""
    begin, end, durations, labels = [], [], [], []
    meta_lists: dict[str, list] = {k: [] for k in PER_ENTRY}
    frames: dict[str, np.ndarray] = {}
    for b, e, d, lab, meta, fr in parts:
        begin += b
        end += e
        durations += d
        labels += lab
        for k in PER_ENTRY:
            meta_lists[k] += meta[k]
        clash = sorted(set(frames) & set(fr))
        if clash:
            raise ValueError(f"episode names must be unique to keep frames for calibration: {clash}")
        frames.update(fr)
    return begin, end, durations, labels, meta_lists, frames
