"""Metrics against brute-force frame-set computations."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rdd.metrics import boundary_scores, evaluate_segmentation, miou, symmetric_miou
from rdd.segments import keyframes_to_segments


def brute_iou(a, b):
    sa, sb = set(range(*a)), set(range(*b))
    return len(sa & sb) / len(sa | sb)


def segs(t, cuts):
    return keyframes_to_segments([c - 1 for c in sorted(set(cuts))], t)


@settings(max_examples=100, deadline=None)
@given(t=st.integers(2, 40), data=st.data())
def test_miou_matches_sets(t, data):
    pc = data.draw(st.sets(st.integers(1, t - 1), max_size=6))
    gc = data.draw(st.sets(st.integers(1, t - 1), max_size=6))
    p, g = segs(t, pc), segs(t, gc)
    expected = sum(max(brute_iou(a, b) for b in g) for a in p) / len(p)
    assert miou(p, g) == pytest.approx(expected)
    assert symmetric_miou(p, g) == pytest.approx(symmetric_miou(g, p))
    assert miou(g, g) == 1.0


def test_known_values():
    gt = [(0, 10), (10, 20)]
    assert miou([(0, 20)], gt) == pytest.approx(0.5)  # one segment, best IoU 10/20
    assert miou(gt, [(0, 20)]) == pytest.approx(0.5)
    assert miou([(0, 5), (5, 10), (10, 20)], gt) == pytest.approx((0.5 + 0.5 + 1) / 3)
    # Oversegmenting hurts the paper's mIoU only through each piece's own IoU.
    assert symmetric_miou([(0, 20)], gt) == pytest.approx(0.5)


def test_boundaries_brute_force():
    t = 30
    for pc, gc in itertools.product([(), (5,), (5, 20), (6, 7, 21)], [(), (5,), (8, 20)]):
        p, g = segs(t, pc), segs(t, gc)
        for tol in (0, 1, 3):
            # brute force: best one-to-one matching over all assignments
            best = 0
            for perm in itertools.permutations(range(len(pc)), min(len(pc), len(gc))):
                best = max(best, sum(abs(sorted(pc)[i] - sorted(gc)[j]) <= tol
                                     for j, i in enumerate(perm)))
            r = boundary_scores(p, g, tol)
            assert r["matched"] == best
            if pc:
                assert r["precision"] == pytest.approx(best / len(pc))
            if gc:
                assert r["recall"] == pytest.approx(best / len(gc))


@settings(max_examples=80, deadline=None)
@given(pc=st.sets(st.integers(1, 24), max_size=5), gc=st.sets(st.integers(1, 24), max_size=5),
       tol=st.integers(0, 4))
def test_boundary_matching_is_maximum(pc, gc, tol):
    p, g = sorted(pc), sorted(gc)
    best = 0
    for perm in itertools.permutations(range(len(g)), min(len(p), len(g))):
        best = max(best, sum(abs(p[i] - g[j]) <= tol for i, j in enumerate(perm)))
    if len(p) > len(g):
        best = 0
        for perm in itertools.permutations(range(len(p)), len(g)):
            best = max(best, sum(abs(p[i] - g[j]) <= tol for j, i in enumerate(perm)))
    assert boundary_scores(segs(25, pc), segs(25, gc), tol)["matched"] == best


def test_evaluate_and_errors():
    out = evaluate_segmentation([(0, 5), (5, 10)], [(0, 6), (6, 10)], tolerance=1)
    assert out["boundary_f1"] == 1.0 and out["num_pred"] == 2
    with pytest.raises(ValueError, match="predicted"):
        miou([], [(0, 1)])
