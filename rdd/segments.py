"""Segmentation conventions shared by every part (see docs/architecture.md).

A segmentation of a T-frame demonstration is a list of half-open ``(start, end)`` segments that
partition ``[0, T)``. The keyframe of a segment is ``end - 1``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

Segment = tuple[int, int]


def keyframes_to_segments(keyframes: Iterable[int], num_frames: int) -> list[Segment]:
    """Turn ascending keyframes ``k1 < k2 < ... `` into segments ``[0, k1+1), [k1+1, k2+1), ...``.

    The last frame ``num_frames - 1`` is always a keyframe; it is appended when missing.
    """
    ks = sorted({int(k) for k in keyframes})
    if num_frames <= 0:
        raise ValueError(f"num_frames must be positive, got {num_frames}")
    if ks and (ks[0] < 0 or ks[-1] > num_frames - 1):
        raise ValueError(f"keyframes {ks} fall outside [0, {num_frames - 1}]")
    if not ks or ks[-1] != num_frames - 1:
        ks.append(num_frames - 1)
    segments: list[Segment] = []
    start = 0
    for k in ks:
        segments.append((start, k + 1))
        start = k + 1
    return segments


def segments_to_keyframes(segments: Sequence[Segment]) -> list[int]:
    """The keyframe ``end - 1`` of every segment."""
    return [int(e) - 1 for _, e in segments]


def validate_segments(segments: Sequence[Segment], num_frames: int) -> list[Segment]:
    """Check that ``segments`` partition ``[0, num_frames)`` in order; return them as int tuples."""
    out = [(int(s), int(e)) for s, e in segments]
    if not out:
        raise ValueError("a segmentation needs at least one segment")
    if out[0][0] != 0:
        raise ValueError(f"the first segment must start at 0, got {out[0]}")
    if out[-1][1] != num_frames:
        raise ValueError(f"the last segment must end at {num_frames}, got {out[-1]}")
    for (s0, e0), (s1, e1) in zip(out, out[1:], strict=False):
        if e0 != s1:
            raise ValueError(f"segments {(s0, e0)} and {(s1, e1)} are not contiguous")
    for s, e in out:
        if e <= s:
            raise ValueError(f"segment {(s, e)} is empty")
    return out


def boundaries(segments: Sequence[Segment]) -> list[int]:
    """Start frames of every segment after the first (the cut points)."""
    return [int(s) for s, _ in segments[1:]]
