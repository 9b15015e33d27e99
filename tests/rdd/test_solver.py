"""The partition solver against brute force over every partition."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rdd.core.solver import candidate_intervals, max_sum_partition, max_sum_partition_dense


def all_partitions(n: int, min_len: int, max_len: int | None):
    """Every partition of [0, n) into segments with min_len <= length <= max_len (by cut subsets)."""
    hi = n if max_len is None else max_len
    for k in range(0, n):
        for cuts in itertools.combinations(range(1, n), k):
            bounds = (0, *cuts, n)
            segs = list(itertools.pairwise(bounds))
            if all(min_len <= e - s <= hi for s, e in segs):
                yield segs


def score_table(n: int, seed: int) -> dict[tuple[int, int], float]:
    rng = np.random.default_rng(seed)
    return {(s, e): float(rng.normal()) for s in range(n) for e in range(s + 1, n + 1)}


def dense_from_table(table, n, min_len, max_len):
    starts, ends, valid = candidate_intervals(n, min_len, max_len)
    out = np.full(starts.shape, -np.inf)
    for idx in zip(*np.nonzero(valid), strict=True):
        out[idx] = table[(int(starts[idx]), int(ends[idx]))]
    return out


@settings(max_examples=150, deadline=None)
@given(
    n=st.integers(1, 10),
    min_len=st.integers(1, 4),
    extra=st.one_of(st.none(), st.integers(0, 5)),
    seed=st.integers(0, 10_000),
)
def test_matches_brute_force(n, min_len, extra, seed):
    max_len = None if extra is None else min_len + extra
    table = score_table(n, seed)
    parts = list(all_partitions(n, min_len, max_len))
    if not parts:
        with pytest.raises(ValueError, match="no valid partition"):
            max_sum_partition(n, lambda s, e: table[(s, e)], min_len, max_len)
        if n >= min_len:
            with pytest.raises(ValueError, match="no valid partition"):
                max_sum_partition_dense(dense_from_table(table, n, min_len, max_len), min_len, max_len)
        return
    brute = max(sum(table[seg] for seg in p) for p in parts)
    value, segs = max_sum_partition(n, lambda s, e: table[(s, e)], min_len, max_len)
    assert value == pytest.approx(brute, abs=1e-9)
    assert segs in parts  # a valid partition: every segment (the first included) within bounds
    assert sum(table[s] for s in segs) == pytest.approx(brute, abs=1e-9)
    dvalue, dsegs = max_sum_partition_dense(dense_from_table(table, n, min_len, max_len), min_len, max_len)
    assert dvalue == pytest.approx(brute, abs=1e-9)
    assert dsegs == segs


def test_first_segment_may_have_exactly_min_len():
    # the best partition of 6 frames with min_len 2 starts with a 2-frame segment
    def score(s, e):
        return 10.0 if (s, e) == (0, 2) else 1.0

    value, segs = max_sum_partition(6, score, min_len=2, max_len=4)
    # 10 for [0, 2) plus the 4 remaining frames cut into two 2-frame segments (1 + 1)
    assert segs == [(0, 2), (2, 4), (4, 6)]
    assert value == pytest.approx(12.0)


def test_every_segment_respects_bounds_when_forced():
    # lengths must be 3..3 -> the only partition of 9 frames is three segments of 3
    value, segs = max_sum_partition(9, lambda s, e: -1.0, min_len=3, max_len=3)
    assert segs == [(0, 3), (3, 6), (6, 9)]
    assert value == -3.0


@pytest.mark.parametrize(
    "n,min_len,max_len,msg",
    [
        (1, 2, None, "shorter than min_len"),
        (5, 3, 4, "no valid partition"),  # 5 = 3 + 2 impossible, 4 + 1 impossible
        (0, 1, None, "positive integer"),
        (5, 0, None, "min_len"),
        (5, 3, 2, "max_len"),
    ],
)
def test_bad_inputs(n, min_len, max_len, msg):
    with pytest.raises(ValueError, match=msg):
        max_sum_partition(n, lambda s, e: 0.0, min_len, max_len)


def test_dense_shape_errors():
    with pytest.raises(ValueError, match="columns"):
        max_sum_partition_dense(np.zeros((6, 3)), min_len=2, max_len=3)
    with pytest.raises(ValueError, match="2-D"):
        max_sum_partition_dense(np.zeros(6), min_len=2)
    with pytest.raises(ValueError, match="NaN"):
        max_sum_partition_dense(np.full((4, 3), np.nan), min_len=2)


def test_candidate_layout():
    starts, ends, valid = candidate_intervals(5, min_len=2, max_len=3)
    assert starts.shape == (5, 2)
    assert (ends[:, 0] == np.arange(1, 6)).all()
    assert ((ends - starts) == np.array([2, 3])).all()
    assert (valid == (starts >= 0)).all()
