"""UVD milestones against a reference built from sklearn/scipy primitives as the official code uses."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import argrelextrema
from sklearn.metrics.pairwise import pairwise_kernels

from rdd.core.milestones import uvd_milestones, uvd_previous_milestone, uvd_previous_milestones_all
from rdd.data.episode import Episode
from rdd.decomposers.uvd import UVDDecomposer
from rdd.encoders.base import Encoder


def reference_embedding_decomp(emb, normalize_curve=False, min_interval=18, window_length=None,
                               gamma=0.08):
    """The official zcczhang/UVD embedding_decomp control flow, with sklearn's kernel + scipy."""
    cur = emb.shape[0] - 1
    goals = [cur]
    window = emb[max(0, cur - (window_length or cur)): cur + 1]
    while cur > (window_length or min_interval):
        g = window[-1]
        d = np.linalg.norm(window - g, axis=1)
        if normalize_curve:
            d = d / np.linalg.norm(window[0] - g)
        x = np.arange(max(0, cur - (window_length or cur)), cur + 1)
        k = pairwise_kernels(x.reshape(-1, 1), x.reshape(-1, 1), metric="rbf", gamma=gamma)
        smooth = (k * d[:, None]).sum(axis=0) / k.sum(axis=0)
        xe = x[argrelextrema(smooth, np.greater)[0]]
        update = False
        for i in range(len(xe) - 1, -1, -1):
            if cur < min_interval:
                break
            if cur - xe[i] > min_interval and xe[i] > min_interval:
                cur = xe[i]
                update = True
                goals.append(cur)
                break
        if not update or cur < min_interval:
            break
        window = emb[max(0, cur - (window_length or cur)): cur + 1]
    return [int(g) for g in goals[::-1]]


def piecewise_trajectory(rng, cuts, length, dim=8):
    """A path through random waypoints with dwell at each cut: a signal with known sub-goals."""
    points = rng.normal(size=(len(cuts) + 2, dim))
    out = np.zeros((length, dim))
    bounds = [0, *cuts, length - 1]
    for j in range(len(bounds) - 1):
        a, b = bounds[j], bounds[j + 1]
        t = np.linspace(0, 1, b - a + 1)[:, None]
        out[a: b + 1] = points[j] * (1 - t) + points[j + 1] * t
    return out + rng.normal(scale=0.01, size=out.shape)


def test_known_subgoals_are_found_near_their_frames():
    rng = np.random.default_rng(0)
    emb = piecewise_trajectory(rng, [60, 130], 200)
    ms = uvd_milestones(emb)
    assert ms[-1] == 199
    assert ms == reference_embedding_decomp(emb)
    assert len(ms) >= 2 and all(0 < m for m in ms)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    length=st.integers(1, 160),
    dim=st.integers(1, 6),
    min_interval=st.integers(1, 25),
    normalize=st.booleans(),
    window=st.one_of(st.none(), st.integers(5, 60)),
    gamma=st.sampled_from([0.08, 0.01, 0.3]),
    f32=st.booleans(),
)
def test_matches_official_control_flow(seed, length, dim, min_interval, normalize, window, gamma,
                                       f32):
    rng = np.random.default_rng(seed)
    emb = np.cumsum(rng.normal(size=(length, dim)), axis=0)
    if f32:
        emb = emb.astype(np.float32)
    with np.errstate(all="ignore"):
        expected = reference_embedding_decomp(emb, normalize, min_interval, window, gamma)
    got = uvd_milestones(emb, min_interval=min_interval, gamma=gamma,
                         normalize_curve=normalize, window_length=window)
    assert got == expected
    assert got[-1] == length - 1 and (length == 1 or 0 not in got)


def test_previous_milestone_is_one_step():
    rng = np.random.default_rng(3)
    emb = piecewise_trajectory(rng, [50, 110, 170], 230)
    ms = uvd_milestones(emb)
    for later, earlier in zip(ms[::-1], ms[::-1][1:], strict=False):
        assert uvd_previous_milestone(emb, later) == earlier
    assert uvd_previous_milestone(emb, ms[0]) is None or ms[0] < 18
    assert uvd_previous_milestone(emb, 10) is None


def test_bad_shape_is_a_clear_error():
    with pytest.raises(ValueError, match=r"\(T, D\)"):
        uvd_milestones(np.zeros(5))


class MeanColour(Encoder):
    """Per-image mean RGB plus position: a tiny deterministic encoder for the decomposer path."""

    name = "mean_colour"
    dim = 3

    @property
    def weights_id(self) -> str:
        return "none"

    def encode(self, images):
        return images.reshape(len(images), -1, 3).mean(axis=1).astype(np.float32) + 1.0


def test_decomposer_segments_partition_episode():
    rng = np.random.default_rng(1)
    traj = piecewise_trajectory(rng, [40, 90], 140, dim=3)
    traj = (traj - traj.min()) / (traj.max() - traj.min())
    frames = np.repeat(np.repeat((traj * 255).astype(np.uint8)[:, None, None, :], 4, 1), 4, 2)
    ep = Episode(name="e", views={"front": frames})
    dec = UVDDecomposer(encoder=MeanColour(), views=("front",))
    out = dec.decompose(ep)
    assert out.segments[0][0] == 0 and out.segments[-1][1] == 140
    assert out.keyframes == out.meta["milestones"]
    with pytest.raises(ValueError, match="encoder"):
        UVDDecomposer().decompose(ep)


def _per_goal(emb, **kw):
    return {g: uvd_previous_milestone(emb, g, **kw) for g in range(emb.shape[0])}


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    length=st.integers(1, 140),
    dim=st.integers(1, 6),
    min_interval=st.integers(0, 25),
    normalize=st.booleans(),
    gamma=st.sampled_from([0.08, 0.01, 0.3]),
    f32=st.booleans(),
    kind=st.sampled_from(["piecewise", "noise", "static", "repeats"]),
)
def test_all_goals_at_once_equal_one_step_per_goal(seed, length, dim, min_interval, normalize, gamma,
                                                   f32, kind):
    rng = np.random.default_rng(seed)
    if kind == "piecewise":
        emb = piecewise_trajectory(rng, sorted(rng.choice(np.arange(1, max(length - 1, 2)), 2)), length, dim) \
            if length > 3 else rng.normal(size=(length, dim))
    elif kind == "noise":
        emb = rng.normal(size=(length, dim))
    elif kind == "static":  # exact repeats at the start and end: flat curves, ties everywhere
        emb = rng.normal(size=(length, dim))
        emb[: length // 3] = emb[0]
        emb[-(length // 4) :] = emb[-1]
    else:  # few distinct frames, many exact repeats
        emb = rng.normal(size=(3, dim))[rng.integers(0, 3, size=length)]
    emb = emb.astype(np.float32 if f32 else np.float64)
    kw = dict(min_interval=min_interval, gamma=gamma, normalize_curve=normalize)
    assert uvd_previous_milestones_all(emb, np.arange(length), **kw) == _per_goal(emb, **kw)


def test_all_goals_equal_per_goal_on_real_rlbench_embeddings(real_data):
    from rdd.data.rlbench import load_episodes
    from rdd.encoders import load_encoder
    from rdd.encoders.embed import episode_frame_vectors

    root = real_data("rlbench/open_drawer/all_variations/episodes")
    ep = load_episodes(root / "episode0")[0]
    fv = episode_frame_vectors(ep, load_encoder("pixels"), views=("front", "wrist"))
    assert uvd_previous_milestones_all(fv, np.arange(fv.shape[0])) == _per_goal(fv)


def test_all_goals_windowed_and_bad_goals():
    rng = np.random.default_rng(1)
    emb = piecewise_trajectory(rng, [30, 70], 100)
    kw = dict(min_interval=5, window_length=40)
    assert uvd_previous_milestones_all(emb, np.arange(100), **kw) == _per_goal(emb, **kw)
    with pytest.raises(ValueError, match="goal frames"):
        uvd_previous_milestones_all(emb, [100])
    assert uvd_previous_milestones_all(emb, []) == {}
