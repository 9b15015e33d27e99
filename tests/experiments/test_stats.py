"""Paired bootstrap intervals against distributions worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.report.stats import episode_outcomes, paired_difference, stratified_bootstrap_mean


def test_two_values_interval_is_the_whole_range():
    # Diffs [0, 1]: a resample's mean is 0, 0.5 or 1 with probabilities 1/4, 1/2, 1/4, so the
    # 2.5% and 97.5% quantiles are 0 and 1.
    mean, low, high = stratified_bootstrap_mean([np.array([0.0, 1.0])], n_boot=20_000)
    assert (mean, low, high) == (0.5, 0.0, 1.0)


def test_two_strata_hand_computed_quantiles():
    # Task A diffs [1]; task B diffs [0, 0, 1]. A replicate is (1 + k/3) / 2 with k ~ Bin(3, 1/3):
    # P(k=0..3) = 8/27, 12/27, 6/27, 1/27; cumulative 0.296, 0.741, 0.963, 1. So the 2.5% quantile
    # is (1 + 0) / 2 = 0.5 and the 97.5% quantile is (1 + 1) / 2 = 1; the point estimate is 2/3.
    mean, low, high = stratified_bootstrap_mean([np.array([1.0]), np.array([0.0, 0.0, 1.0])], n_boot=20_000)
    assert mean == pytest.approx(2 / 3)
    assert (low, high) == (0.5, 1.0)


def test_constant_differences_give_a_point_interval_and_significance():
    a = {(0, "t", i): 1.0 for i in range(5)}
    b = {(0, "t", i): 0.0 for i in range(5)}
    d = paired_difference("a", a, "b", b)
    assert (d.mean, d.low, d.high, d.pairs) == (1.0, 1.0, 1.0, 5)
    assert d.significant
    same = paired_difference("b", b, "b2", dict(b))
    assert not same.significant and same.mean == 0.0


def test_differing_episode_sets_are_refused():
    with pytest.raises(ValueError, match="evaluation episodes differ"):
        paired_difference("a", {(0, "t", 1): 1.0}, "b", {(0, "t", 2): 1.0})
    with pytest.raises(ValueError, match="twice"):
        episode_outcomes({0: [{"task": "t", "seed": 1, "success": True}] * 2})
