"""Uniform segmentation: partition, near-equal lengths, clear failure when too short."""

from __future__ import annotations

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.decomposers.uniform import UniformDecomposer, uniform_segments
from rdd.segments import validate_segments


@pytest.mark.parametrize("t,n", [(10, 10), (125, 10), (11, 3), (7, 1), (100, 7)])
def test_partition_even(t, n):
    segs = uniform_segments(t, n)
    validate_segments(segs, t)
    lengths = [e - s for s, e in segs]
    assert len(segs) == n and max(lengths) - min(lengths) <= 1 and sum(lengths) == t


def test_too_short_is_clear():
    ep = Episode(name="short", views={}, gripper_open=np.ones(4))
    with pytest.raises(ValueError, match="short.*n_segments=10"):
        UniformDecomposer().decompose(ep)
    assert UniformDecomposer(clip_to_length=True).decompose(ep).segments == [(0, 1), (1, 2), (2, 3), (3, 4)]
    with pytest.raises(ValueError, match="n_segments"):
        UniformDecomposer(n_segments=0)
