"""The RDD decomposer: exact recovery of database sub-tasks, optimality against brute force."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from rdd.core.milestones import uvd_previous_milestone
from rdd.data.episode import Episode
from rdd.database.model import DatabaseError, SubtaskDatabase
from rdd.decomposers.base import Decomposition
from rdd.decomposers.rdd import RDDDecomposer
from rdd.demo import SyntheticWorld, build_synthetic_database, run_demo
from rdd.encoders.base import Encoder
from rdd.encoders.embed import concat_views, episode_frame_vectors
from rdd.errors import InputError

CONF = Path(__file__).resolve().parents[2] / "conf" / "decomposer"


@pytest.fixture(scope="module")
def world_db():
    rng = np.random.default_rng(0)
    world = SyntheticWorld.make(seed=0)
    db, demos = build_synthetic_database(world, demos_per_task=4, rng=rng)
    return world, db, demos


def assemble(db_demos, picks):
    """A new demo made of copies of training sub-tasks: (task, demo index, leg) picks."""
    parts, truth, entries, start = [], [], [], 0
    for task, i, k in picks:
        fv, segs = db_demos[task][i]
        s, e = segs[k]
        parts.append(fv[s:e])
        truth.append((start, start + e - s))
        entries.append((f"{task}/train_{i}", s, e))
        start += e - s
    return np.concatenate(parts), truth, entries


@pytest.mark.parametrize("index", ["exact", "annoy", "faiss"])
def test_demo_assembled_from_database_subtasks_decomposes_back(world_db, index):
    world, db, demos = world_db
    rng = np.random.default_rng(5)
    tasks = sorted(demos)
    picks = []
    for _ in range(6):  # sub-tasks drawn from different tasks and demos, in a new order
        task = tasks[int(rng.integers(len(tasks)))]
        i = int(rng.integers(len(demos[task])))
        picks.append((task, i, int(rng.integers(len(demos[task][i][1])))))
    fv, truth, entries = assemble(demos, picks)
    result = RDDDecomposer(db, alpha=1.0, index=index).decompose_embeddings(fv)
    assert isinstance(result, Decomposition)
    assert result.segments == truth
    assert result.keyframes == [e - 1 for _, e in truth]
    got = [(n["episode"], n["start"], n["end"]) for n in result.neighbours]
    assert got == entries
    assert all(n["distance"] == pytest.approx(0.0, abs=1e-3) for n in result.neighbours)
    assert result.novelty == pytest.approx(0.0, abs=0.05)
    assert result.novelty == pytest.approx(np.mean(result.scores))


def brute_force_objective(fv, db, mode, alpha, beta, min_len, max_len, uvd_kwargs):
    """Max over all partitions of the summed J, every score computed directly per interval."""
    x = np.concatenate([db.begin, db.end], 1).astype(np.float64)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    ends = db.end.astype(np.float64) / np.linalg.norm(db.end.astype(np.float64), axis=1, keepdims=True)
    t = fv.shape[0]

    def j(s, e):
        m = uvd_previous_milestone(fv, e - 1, **uvd_kwargs)  # rerun per interval, as officially
        g = -abs(s - (m or 0)) / (e - s)
        if mode == "default":
            q = np.concatenate([fv[s], fv[e - 1]]).astype(np.float64)
            cos = x @ (q / np.linalg.norm(q))
            nn = int(cos.argmax())
            dist = np.sqrt(max(2 - 2 * cos[nn], 0.0))
            sim = -(dist + alpha * abs(1 - (e - 1 - s) / max(db.durations[nn], 1))) + beta * g
        else:  # Eq. 3.5: the entry whose end frame is nearest to the interval's end frame
            a = fv[e - 1].astype(np.float64)
            c = (ends @ (a / np.linalg.norm(a))).max()
            sim = -np.sqrt(max(2 - 2 * c, 0.0)) + beta * g
        return (e - s) * sim

    best = -np.inf
    for k in range(t):
        for cuts in itertools.combinations(range(1, t), k):
            b = (0, *cuts, t)
            if all(min_len <= e - s <= max_len for s, e in itertools.pairwise(b)):
                best = max(best, sum(j(s, e) for s, e in itertools.pairwise(b)))
    return best


@pytest.mark.parametrize("mode", ["default", "ood"])
def test_objective_equals_brute_force(world_db, mode):
    world, db, _ = world_db
    rng = np.random.default_rng(7)
    fv, _ = world.demo("task_1", rng, length_range=(4, 6))
    fv = fv[:14]
    uvd = {"min_interval": 2}
    for beta in (0.0, 0.5):
        dec = RDDDecomposer(db, alpha=0.7, beta=beta, mode=mode, min_len=2, max_len=6, uvd_options=uvd)
        result = dec.decompose_embeddings(fv)
        ref = brute_force_objective(fv, db, mode, 0.7, beta, 2, 6, uvd)
        assert result.meta["objective"] == pytest.approx(ref, abs=1e-4)
        assert sum(result.scores) == pytest.approx(ref, abs=1e-4)
        assert all(2 <= e - s <= 6 for s, e in result.segments)


def ood_brute_force_dp(fv, end_vectors, min_len, max_len):
    """Best partition under J(I) = -min_k delta(f[e-1], E_k) * |I|, each score from scratch."""
    e_unit = end_vectors.astype(np.float64) / np.linalg.norm(end_vectors.astype(np.float64), axis=1,
                                                             keepdims=True)

    def j(s, e):
        f = fv[e - 1].astype(np.float64)
        d = np.sqrt(np.maximum(2 - 2 * (e_unit @ (f / np.linalg.norm(f))), 0.0))
        return -float(d.min()) * (e - s)

    t = fv.shape[0]
    best = [0.0] + [-np.inf] * t
    for e in range(1, t + 1):
        for length in range(min_len, min(max_len, e) + 1):
            best[e] = max(best[e], best[e - length] + j(e - length, e))
    return best[t]


def _adversarial_ood_case(rng, kind):
    d = 6
    if kind == "random":
        ends = rng.normal(size=(40, d))
        begins = rng.normal(size=(40, d))
        fv = rng.normal(size=(17, d))
    elif kind == "concat_decoy":
        # Entries whose begin frame matches every query frame but whose end frames are far:
        # the nearest entry on concat(begin, end) is not the nearest on the end frame alone.
        fv = rng.normal(size=(15, d))
        decoy_b = np.repeat(fv.mean(0, keepdims=True), 30, 0) + 0.01 * rng.normal(size=(30, d))
        decoy_e = -fv[rng.integers(0, 15, 30)] + 0.3 * rng.normal(size=(30, d))
        true_b = rng.normal(size=(15, d)) * 5
        true_e = fv + 0.2 * rng.normal(size=(15, d))
        begins, ends = np.concatenate([decoy_b, true_b]), np.concatenate([decoy_e, true_e])
    else:  # "ties": repeated end vectors and repeated frames
        base = rng.normal(size=(3, d))
        ends = base[rng.integers(0, 3, 25)]
        begins = rng.normal(size=(25, d))
        fv = base[rng.integers(0, 3, 16)]
    return fv.astype(np.float32), begins.astype(np.float32), ends.astype(np.float32)


@pytest.mark.parametrize("kind", ["random", "concat_decoy", "ties"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ood_beta0_equals_brute_force_end_frame_dp(kind, seed):
    rng = np.random.default_rng(seed)
    fv, begins, ends = _adversarial_ood_case(rng, kind)
    db = SubtaskDatabase.from_arrays(begins, ends, rng.integers(1, 9, begins.shape[0]))
    for min_len, max_len in ((2, 5), (1, 7), (3, None)):
        dec = RDDDecomposer(db, mode="ood", beta=0.0, min_len=min_len, max_len=max_len)
        result = dec.decompose_embeddings(fv)
        ref = ood_brute_force_dp(fv, ends, min_len, max_len or fv.shape[0])
        assert result.meta["objective"] == pytest.approx(ref, abs=1e-4)
        # each segment's neighbour is an entry whose end frame is nearest to the segment's end frame
        for (_, e), n in zip(result.segments, result.neighbours, strict=True):
            f = fv[e - 1].astype(np.float64)
            cos = ends.astype(np.float64) @ f / np.linalg.norm(ends, axis=1) / np.linalg.norm(f)
            assert cos[n["entry"]] == pytest.approx(cos.max(), abs=1e-5)
        assert result.meta["novelty_partition"] == "default"


def test_ood_novelty_is_the_default_partitions_mean_score(world_db):
    world, db, _ = world_db
    fv, _ = world.demo("task_2", np.random.default_rng(3))
    ood = RDDDecomposer(db, mode="ood").decompose_embeddings(fv)
    default = RDDDecomposer(db, mode="default").decompose_embeddings(fv)
    assert ood.novelty == pytest.approx(default.novelty)
    assert ood.meta["default_segments"] == [list(x) for x in default.segments]


class PixelMeanEncoder(Encoder):
    """Test encoder: a fixed random projection of 8x8 RGB pixels."""

    name = "test_pixel_mean"
    dim = 5

    def __init__(self) -> None:
        self._w = np.random.default_rng(1).normal(size=(8 * 8 * 3, self.dim)).astype(np.float32)

    @property
    def weights_id(self) -> str:
        return "fixed-seed-1"

    def encode(self, images: np.ndarray) -> np.ndarray:
        return (images.reshape(images.shape[0], -1).astype(np.float32) / 255.0 - 0.5) @ self._w


def _two_segment_episodes(rng) -> list[Episode]:
    """Three 20-frame two-view episodes of random 8x8 images, each cut at frame 7 ("a", "b")."""
    return [Episode(name=f"tr{i}", task="t", views={v: rng.integers(0, 256, (20, 8, 8, 3), dtype=np.uint8)
                                                   for v in ("front", "wrist")},
                    segments=[(0, 7), (7, 20)], instructions=["a", "b"]) for i in range(3)]


def test_decompose_episode_matches_embeddings_and_checks_encoder():
    rng = np.random.default_rng(3)
    enc = PixelMeanEncoder()
    train = _two_segment_episodes(rng)
    db = SubtaskDatabase.build(train, None, enc)
    test_ep = train[1]
    dec = RDDDecomposer(db, encoder=enc)
    from_episode = dec.decompose(test_ep)
    from_vectors = dec.decompose_embeddings(episode_frame_vectors(test_ep, enc))
    assert from_episode.segments == from_vectors.segments == [(0, 7), (7, 20)]
    assert [n["instruction"] for n in from_episode.neighbours] == ["a", "b"]
    assert from_episode.meta["episode"] == "tr1"

    class Other(PixelMeanEncoder):
        name = "other"

    with pytest.raises(DatabaseError, match="encoder 'test_pixel_mean'"):
        RDDDecomposer(db, encoder=Other())
    with pytest.raises(DatabaseError, match="views"):
        RDDDecomposer(db, encoder=enc, views=("front",))
    with pytest.raises(ValueError, match="needs an encoder"):
        RDDDecomposer(db).decompose(test_ep)


def test_episode_shorter_than_min_len_is_an_input_error_before_encoding():
    """No partition of 3 frames into segments of at least 5: one line naming the episode and min_len,
    and the encoder never runs (a long video is not decoded only to fail)."""
    rng = np.random.default_rng(5)
    enc = PixelMeanEncoder()
    db = SubtaskDatabase.build(_two_segment_episodes(rng), None, enc)

    class MustNotEncode(PixelMeanEncoder):
        name = enc.name

        def encode(self, images: np.ndarray) -> np.ndarray:
            raise AssertionError("encoded an episode that no partition fits")

    short = Episode(name="short", task="t", views={v: rng.integers(0, 256, (3, 8, 8, 3), dtype=np.uint8)
                                                   for v in ("front", "wrist")})
    with pytest.raises(InputError, match=r"^episode 'short': 3 frame\(s\), shorter than min_len=5,"):
        RDDDecomposer(db, encoder=MustNotEncode(), min_len=5).decompose(short)
    assert len(RDDDecomposer(db, encoder=enc, min_len=3).decompose(short).segments) == 1


def test_raw_views_database_decomposes_with_raw_frame_vectors():
    rng = np.random.default_rng(4)
    enc = PixelMeanEncoder()
    train = _two_segment_episodes(rng)
    db = SubtaskDatabase.build(train, None, enc, normalize_views=False)
    raw = episode_frame_vectors(train[2], enc, normalize=False)
    np.testing.assert_allclose(db.end[-1], raw[19], rtol=1e-6)
    dec = RDDDecomposer(db, encoder=enc)
    assert dec.normalize_views is False
    got = dec.decompose(train[2])
    assert got.segments == dec.decompose_embeddings(raw).segments == [(0, 7), (7, 20)]
    assert [n["distance"] for n in got.neighbours] == pytest.approx([0.0, 0.0], abs=1e-3)


def test_bad_arguments(world_db):
    _, db, _ = world_db
    with pytest.raises(ValueError, match="mode"):
        RDDDecomposer(db, mode="fast")
    with pytest.raises(ValueError, match="max_len"):
        RDDDecomposer(db, min_len=4, max_len=3)
    with pytest.raises(ValueError, match="unknown index 'kdtree'"):
        RDDDecomposer(db, index="kdtree")
    with pytest.raises(TypeError, match="SubtaskDatabase"):
        RDDDecomposer(np.ones((3, 3)))
    dec = RDDDecomposer(db)
    # the message says what to do: match the database's encoder and views, or rebuild it
    with pytest.raises(ValueError, match=r"7-d but the database holds 128-d.*rebuild it \(build-db\)"):
        dec.decompose_embeddings(np.ones((10, 7), dtype=np.float32))
    with pytest.raises(ValueError, match="shorter than min_len"):
        dec.decompose_embeddings(concat_views([np.ones((1, 64)), np.ones((1, 64))]))


def test_decomposer_configs_instantiate(world_db):
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    _, db, demos = world_db
    fv, truth = demos["task_0"][0]
    for name, mode in (("rdd", "default"), ("rdd_ood", "ood")):
        # as the harness composes it: `index: ${index}` is the index group's choice, `${views}` the run's
        cfg = OmegaConf.create({"index": OmegaConf.load(CONF.parent / "index" / "exact.yaml"),
                                "views": ["front", "wrist"],
                                "decomposer": OmegaConf.load(CONF / f"{name}.yaml")})
        partial = instantiate(cfg.decomposer)
        dec = partial(database=db, encoder=None)
        assert isinstance(dec, RDDDecomposer) and dec.mode == mode
        result = dec.decompose_embeddings(fv)
        assert result.segments[0][0] == 0 and result.segments[-1][1] == fv.shape[0]
        if mode == "default":
            assert result.segments == truth  # a training demo itself is cut at its true boundaries


def test_run_demo_reports_segments(capsys):
    summary = run_demo(seed=1)
    out = capsys.readouterr().out
    assert "RDD segments" in out and "novelty" in out
    assembled, fresh = summary["assembled"], summary["fresh"]
    # copies of database sub-tasks come back exactly, each matched to the entry it was copied from
    assert assembled["segments"] == assembled["truth"] and assembled["exact"]
    assert all(m["distance"] < 1e-3 for m in assembled["matched"])
    # the fresh demo has new noise and lengths: cut points near, not necessarily on, the truth
    segs = fresh["segments"]
    assert segs[0][0] == 0 and segs[-1][1] == fresh["num_frames"]
    assert fresh["boundary_errors"] is not None
    assert max(abs(x) for x in fresh["boundary_errors"]) <= 5
