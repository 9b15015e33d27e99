"""Interval scoring: vectors, distances, similarities and the paper's Proposition 3.1."""

from __future__ import annotations

import numpy as np
import pytest

from rdd import geometry
from rdd.core import scoring
from rdd.core.milestones import uvd_previous_milestone
from rdd.core.solver import max_sum_partition


def test_interval_vectors_layout():
    fv = np.arange(20, dtype=np.float32).reshape(10, 2)
    v = geometry.interval_vectors(fv, [0, 3], [4, 10])
    np.testing.assert_array_equal(v, [[0, 1, 6, 7], [6, 7, 18, 19]])


def test_angular_distance_is_chord_of_unit_vectors():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(50, 7)), rng.normal(size=(50, 7)) * 3
    chord = np.linalg.norm(a / np.linalg.norm(a, axis=1, keepdims=True)
                           - b / np.linalg.norm(b, axis=1, keepdims=True), axis=1)
    np.testing.assert_allclose(geometry.angular_distance(a, b), chord, atol=1e-9)
    assert geometry.angular_distance(a[0], a[0]) == pytest.approx(0.0, abs=1e-6)
    assert geometry.angular_distance(a[0], -a[0]) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="zero vector"):
        geometry.angular_distance(np.zeros(3), np.ones(3))


def test_default_similarity_by_hand():
    # dist 0.5, query duration 9, neighbour duration 6: -(0.5 + 2 * |1 - 9/6|) = -1.5
    sim = scoring.default_similarity([0.5], [9], [6], alpha=2.0)
    assert sim[0] == pytest.approx(-1.5)
    # a one-frame neighbour (duration 0) counts as duration 1
    assert scoring.default_similarity([0.0], [3], [0], alpha=1.0)[0] == pytest.approx(-2.0)


def test_durations_and_weights():
    np.testing.assert_array_equal(scoring.weights([0, 5], [5, 7]), [5, 2])
    np.testing.assert_array_equal(scoring.durations([0, 5], [5, 7]), [4, 1])


def test_proposition_3_1_split_with_equal_similarity_keeps_score():
    rng = np.random.default_rng(1)
    for _ in range(20):
        start, end = 3, 3 + int(rng.integers(4, 40))
        cuts = sorted(rng.choice(np.arange(start + 1, end), size=int(rng.integers(1, 3)), replace=False))
        bounds = [start, *cuts, end]
        sim = float(rng.normal())
        whole = scoring.interval_scores([sim], [start], [end])[0]
        parts = scoring.interval_scores([sim] * (len(bounds) - 1), bounds[:-1], bounds[1:]).sum()
        assert parts == pytest.approx(whole)


def test_constant_similarity_makes_every_partition_equal():
    # With weight = number of frames, every partition of T frames weighs T: the optimum is sim * T.
    sim, n = -0.37, 23
    value, _ = max_sum_partition(n, lambda s, e: float(scoring.interval_scores([sim], [s], [e])[0]), 2, 7)
    assert value == pytest.approx(sim * n)


def test_uvd_prior_by_hand():
    m = np.array([0, 0, 0, 0, 0, 0, 0, 0, 0, 4.0])  # m(9) = 4
    g = scoring.uvd_prior([2, 4], [10, 10], m)
    np.testing.assert_allclose(g, [-2 / 8, 0.0])
    sim = scoring.ood_similarity([0.1, 0.2], [2, 4], [10, 10], m, beta=0.5)
    np.testing.assert_allclose(sim, [-0.1 - 0.5 * 0.25, -0.2])


def test_milestones_once_per_end_equal_per_interval_uvd():
    rng = np.random.default_rng(2)
    # a path through three waypoints gives UVD milestones to find
    wp = rng.normal(size=(4, 8))
    x = np.concatenate([np.linspace(wp[i], wp[i + 1], 30, endpoint=False) for i in range(3)])
    x = x + 0.01 * rng.normal(size=x.shape)
    ends = np.arange(1, x.shape[0] + 1)
    m = scoring.uvd_milestones_per_end(x, ends - 1, min_interval=5)
    for e in ends:
        ref = uvd_previous_milestone(x, int(e) - 1, min_interval=5)
        assert m[e - 1] == (0 if ref is None else ref)
    assert (m > 0).any()


def test_novelty_is_mean_score():
    assert scoring.novelty([-1.0, -2.0, -6.0]) == pytest.approx(-3.0)
    with pytest.raises(ValueError, match="at least one"):
        scoring.novelty([])


def test_bad_intervals():
    fv = np.ones((5, 2))
    with pytest.raises(ValueError, match="outside"):
        geometry.interval_vectors(fv, [0], [6])
    with pytest.raises(ValueError, match="empty"):
        geometry.interval_vectors(fv, [2], [2])
    with pytest.raises(ValueError, match="integer"):
        geometry.interval_vectors(fv, [0.5], [2])
    with pytest.raises(ValueError, match="differ in length"):
        geometry.interval_vectors(fv, [0, 1], [2])
