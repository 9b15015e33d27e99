"""Retrieval indexes: exact equals brute force; annoy and faiss reach high recall."""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path

import numpy as np
import pytest

from rdd.encoders.embed import l2_normalize
from rdd.index import NearestIndex, available_indexes, load_index
from rdd.index.exact import ExactIndex

CONF = Path(__file__).resolve().parents[2] / "conf" / "index"


def brute_force(queries: np.ndarray, begin: np.ndarray, end: np.ndarray):
    """Nearest entry by angular distance on full interval vectors, in float64."""
    x = np.concatenate([begin, end], 1).astype(np.float64)
    q = queries.astype(np.float64)
    cos = (q / np.linalg.norm(q, axis=1, keepdims=True)) @ (x / np.linalg.norm(x, axis=1, keepdims=True)).T
    return cos.argmax(1), np.sqrt(np.maximum(2 - 2 * cos.max(1), 0)), cos


def clustered(rng, n, d, clusters=40, spread=0.15):
    """Frame vectors (two 'views' of d/2 each, normalised per view) around random cluster centres."""
    centres = rng.normal(size=(clusters, d))
    x = centres[rng.integers(clusters, size=n)] + spread * rng.normal(size=(n, d))
    h = d // 2
    return np.concatenate([l2_normalize(x[:, :h]), l2_normalize(x[:, h:])], 1)


def test_exact_search_equals_brute_force():
    rng = np.random.default_rng(0)
    begin, end = rng.normal(size=(700, 12)), rng.normal(size=(700, 12)) * 2  # not normalised
    q = rng.normal(size=(300, 24))
    idx = ExactIndex().fit(begin, end)
    ids, dist = idx.search(q)
    ref_ids, ref_dist, _ = brute_force(q, begin, end)
    np.testing.assert_array_equal(ids, ref_ids)
    np.testing.assert_allclose(dist, ref_dist, atol=1e-5)


@pytest.mark.parametrize("memory_mb", [1, 256])
def test_exact_intervals_equal_brute_force(memory_mb):
    rng = np.random.default_rng(1)
    t, d = 60, 16
    begin, end = clustered(rng, 5000, d), clustered(rng, 5000, d)
    fv = clustered(rng, t, d)
    starts, ends = np.meshgrid(np.arange(t), np.arange(1, t + 1), indexing="ij")
    keep = (ends > starts) & (ends - starts <= 25)
    s, e = starts[keep], ends[keep]
    idx = ExactIndex(memory_mb=memory_mb).fit(begin, end)  # 1 MB forces several database chunks
    if memory_mb == 1:
        assert idx._chunk_entries(2 * t + 25) < 5000
    ids, dist = idx.search_intervals(fv, s, e)
    q = np.concatenate([fv[s], fv[e - 1]], 1)
    ref_ids, ref_dist, cos = brute_force(q, begin, end)
    np.testing.assert_allclose(dist, ref_dist, atol=1e-5)
    # ids agree except where two entries are equally near within float32 rounding
    top2 = np.sort(cos, axis=1)[:, -2:]
    clear = top2[:, 1] - top2[:, 0] > 1e-5
    np.testing.assert_array_equal(ids[clear], ref_ids[clear])
    # scattered (non-contiguous) intervals give the same answers as the grouped fast path
    perm = rng.permutation(s.size)[:200]
    ids2, dist2 = idx.search_intervals(fv, s[perm], e[perm])
    np.testing.assert_array_equal(ids2, ids[perm])
    np.testing.assert_allclose(dist2, dist[perm], atol=1e-6)


def _recall(index: NearestIndex, rng) -> float:
    d = 32
    begin, end = clustered(rng, 3000, d), clustered(rng, 3000, d)
    # queries: database intervals perturbed, as a new demo's sub-tasks are near training ones
    pick = rng.integers(3000, size=300)
    q = np.concatenate([begin[pick], end[pick]], 1) + 0.05 * rng.normal(size=(300, 2 * d))
    index.fit(begin, end)
    ids, dist = index.search(q)
    ref_ids, ref_dist, _ = brute_force(q, begin, end)
    hit = ids == ref_ids
    np.testing.assert_allclose(dist[hit], ref_dist[hit], atol=1e-4)
    return float(hit.mean())


@pytest.mark.parametrize(
    "name,options",
    [("annoy", {}), ("faiss", {"kind": "flat"}), ("faiss", {"kind": "ivf"}), ("faiss", {"kind": "hnsw"})],
)
def test_approximate_indexes_recall(name, options):
    recall = _recall(load_index(name, **options), np.random.default_rng(2))
    assert recall >= 0.9, f"{name} {options}: recall {recall:.3f}"


def test_annoy_forest_saved_beside_database(tmp_path):
    rng = np.random.default_rng(3)
    begin, end = clustered(rng, 300, 8), clustered(rng, 300, 8)
    a = load_index("annoy").fit(begin, end, cache_dir=tmp_path, key="abc123")
    assert a.path is not None and a.path.parent == tmp_path and a.path.suffix == ".ann"
    b = load_index("annoy").fit(begin, end, cache_dir=tmp_path, key="abc123")
    assert b.path == a.path
    q = np.concatenate([begin[:20], end[:20]], 1)
    np.testing.assert_array_equal(a.search(q)[0], b.search(q)[0])
    # Damage (issue 62): changed or truncated bytes are never mapped; a warning, built again.
    import rdd.index.annoy as annoy_module

    good, ids = a.path.read_bytes(), a.search(q)[0]
    path = a.path
    del a, b  # they map the file that is damaged next
    for damaged in (good[:-4] + b"\xff\xff\xff\xff", good[: len(good) // 2]):
        path.unlink()  # a new file: damage in place would also change what a live map reads
        path.write_bytes(damaged)
        with caplog_at(annoy_module.log) as records:
            c = load_index("annoy").fit(begin, end, cache_dir=tmp_path, key="abc123")
        assert records == [f"annoy index file {path}: its sha256 does not match the one written with it "
                           "(damaged); building the forest again"]
        np.testing.assert_array_equal(c.search(q)[0], ids)
        assert path.read_bytes() == good
        del c
    assert len(list(tmp_path.glob("*.ann"))) == 1


def test_exact_clusters_saved_beside_database(tmp_path, monkeypatch):
    """The exact index's clustering is saved beside the database, read back by the next fit (no
    clustering then), keyed by the database and the options, and a damaged file is named."""
    import rdd.index.exact as exact_module

    rng = np.random.default_rng(5)
    begin, end = clustered(rng, 600, 8), clustered(rng, 600, 8)
    fv = clustered(rng, 30, 8)
    s, e = np.arange(0, 28), np.arange(2, 30)
    a = ExactIndex(cluster_size=8).fit(begin, end, cache_dir=tmp_path, key="abc123")
    saved = list(tmp_path.glob("exact-cells-*.npz"))
    assert len(saved) == 1

    def refuse(*args, **kwargs):
        raise AssertionError("the saved clusters were not used")

    monkeypatch.setattr(exact_module, "fit_cells", refuse)
    b = ExactIndex(cluster_size=8).fit(begin, end, cache_dir=tmp_path, key="abc123")
    np.testing.assert_array_equal(b._perm, a._perm)
    ids_a, dist_a = a.search_intervals(fv, s, e)
    ids_b, dist_b = b.search_intervals(fv, s, e)
    np.testing.assert_array_equal(ids_a, ids_b)
    np.testing.assert_array_equal(dist_a, dist_b)
    monkeypatch.undo()
    ExactIndex(cluster_size=16).fit(begin, end, cache_dir=tmp_path, key="abc123")  # other options
    ExactIndex(cluster_size=8).fit(begin, end, cache_dir=tmp_path, key="def456")  # other database
    assert len(list(tmp_path.glob("exact-cells-*.npz"))) == 3
    good = saved[0].read_bytes()
    # Damage (issue 62): a truncated file, or one whose bytes changed, is never used: a warning names
    # it, the clusters are made again and rewritten, and the search gives the same answer.
    flipped = bytearray(good)
    flipped[len(good) // 2] ^= 0xFF
    for damaged in (b"not an npz", good[: len(good) // 2], bytes(flipped)):
        saved[0].write_bytes(damaged)
        with caplog_at(exact_module.log) as records:
            c = ExactIndex(cluster_size=8).fit(begin, end, cache_dir=tmp_path, key="abc123")
        assert any(str(saved[0]) in r and "clustering again" in r for r in records), records
        np.testing.assert_array_equal(c.search_intervals(fv, s, e)[0], ids_a)
        assert saved[0].read_bytes() == good


@contextlib.contextmanager
def caplog_at(logger):
    """The messages ``logger`` emits inside the block."""
    records: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record.getMessage())

    handler = Keep()
    logger.addHandler(handler)
    try:
        yield records
    finally:
        logger.removeHandler(handler)


def test_load_index_by_module_name_and_errors():
    assert {"annoy", "exact", "faiss"} <= set(available_indexes())
    assert isinstance(load_index("exact"), ExactIndex)
    with pytest.raises(ValueError, match="unknown index 'nope'"):
        load_index("nope")
    with pytest.raises(ValueError, match=r"unknown index '\.\./x'; available: \['annoy', 'exact', 'faiss'\]"):
        load_index("../x")
    with pytest.raises(ValueError, match="kind"):
        load_index("faiss", kind="pq")
    with pytest.raises(ValueError, match="n_trees"):
        load_index("annoy", n_trees=0)


def test_index_configs_instantiate():
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    for name in ("annoy", "faiss", "exact"):
        cfg = OmegaConf.load(CONF / f"{name}.yaml")
        index = instantiate(cfg)
        assert isinstance(index, NearestIndex) and index.name == name


def test_search_input_errors():
    rng = np.random.default_rng(4)
    idx = ExactIndex()
    with pytest.raises(RuntimeError, match="fit"):
        idx.search(np.ones((1, 4)))
    idx.fit(rng.normal(size=(10, 2)), rng.normal(size=(10, 2)))
    with pytest.raises(ValueError, match=r"\(Q, 4\)"):
        idx.search(np.ones((3, 5)))
    with pytest.raises(ValueError, match="zero"):
        idx.search(np.zeros((1, 4)))
    with pytest.raises(ValueError, match="NaN"):
        idx.search(np.full((1, 4), np.nan))
    with pytest.raises(ValueError, match=r"\(T, 2\)"):
        idx.search_intervals(np.ones((5, 3)), [0], [2])
    with pytest.raises(ValueError, match="outside"):
        idx.search_intervals(np.ones((5, 2)), [0], [6])
    with pytest.raises(ValueError, match="same shape|one shape"):
        ExactIndex().fit(np.ones((3, 2)), np.ones((3, 3)))
    with pytest.raises(ValueError, match="empty"):
        ExactIndex().fit(np.ones((0, 2)), np.ones((0, 2)))


def test_exact_pruning_skips_entries_and_stays_exact():
    rng = np.random.default_rng(6)
    d, t = 32, 80
    # a database of sub-tasks between a few waypoints, and a demo walking through the same waypoints
    way = clustered(rng, 30, d, clusters=30, spread=0.0)
    pairs = rng.integers(30, size=(4000, 2))
    begin = l2_normalize(way[pairs[:, 0]] + 0.05 * rng.normal(size=(4000, d)))
    end = l2_normalize(way[pairs[:, 1]] + 0.05 * rng.normal(size=(4000, d)))
    path = way[rng.integers(30, size=5)]
    fv = l2_normalize(np.concatenate([np.linspace(path[i], path[i + 1], 16, endpoint=False) for i in range(4)]
                                     + [path[4:5].repeat(16, 0)]))
    starts, ends = np.meshgrid(np.arange(t), np.arange(1, t + 1), indexing="ij")
    keep = (ends - starts >= 2) & (ends - starts <= 30)
    s, e = starts[keep], ends[keep]
    pruned = ExactIndex(prune=True, cluster_size=16).fit(begin, end)
    ids, dist = pruned.search_intervals(fv, s, e)
    assert pruned.last_searched_fraction < 0.5  # the bounds really skip blocks here
    dense = ExactIndex(prune=False).fit(begin, end)
    ids_d, dist_d = dense.search_intervals(fv, s, e)
    assert dense.last_searched_fraction == pytest.approx(1.0)
    # float32 products over different block shapes round differently (about 1e-6 after the sqrt)
    np.testing.assert_allclose(dist, dist_d, atol=1e-5)
    ref_ids, ref_dist, cos = brute_force(np.concatenate([fv[s], fv[e - 1]], 1), begin, end)
    np.testing.assert_allclose(dist, ref_dist, atol=1e-5)
    top2 = np.sort(cos, axis=1)[:, -2:]
    clear = top2[:, 1] - top2[:, 0] > 1e-5
    np.testing.assert_array_equal(ids[clear], ref_ids[clear])


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_pruned_exact_equals_brute_force_on_adversarial_databases(seed):
    """Cap-bound pruning never drops the nearest entry: tight and loose clusters, duplicated
    entries, zero begin parts, entries of very different lengths, zero frames."""
    rng = np.random.default_rng(seed)
    d, t, n = 24, 70, 3000
    way = rng.normal(size=(40, d))
    pairs = rng.integers(40, size=(n, 2))
    spread = [0.01, 0.05, 0.3, 1.0][seed]  # from tight caps to nearly unclustered data
    begin = way[pairs[:, 0]] + spread * rng.normal(size=(n, d))
    end = way[pairs[:, 1]] + spread * rng.normal(size=(n, d))
    begin[:50] = begin[50:100]  # exact duplicates
    end[:50] = end[50:100]
    begin[100:140] = 0.0  # an interval of end frame only (a zero end frame is refused at fit)
    begin[140:400] *= rng.uniform(0.05, 20.0, size=(260, 1))  # lengths vary per entry and part
    end[140:400] *= rng.uniform(0.05, 20.0, size=(260, 1))
    path = way[rng.integers(40, size=6)]
    fv = np.concatenate([np.linspace(path[i], path[i + 1], 14, endpoint=False) for i in range(5)])
    fv = fv + 0.02 * rng.normal(size=fv.shape)
    fv[7] = 0.0  # a zero frame: its intervals are scored on their other end alone
    starts, ends = np.meshgrid(np.arange(t), np.arange(1, t + 1), indexing="ij")
    keep = (ends - starts >= 2) & (ends - starts <= 40)
    s, e = starts[keep], ends[keep]
    idx = ExactIndex(prune=True, cluster_size=8).fit(begin, end)
    ids, dist = idx.search_intervals(fv, s, e)
    if spread <= 0.05:
        assert idx.last_searched_fraction < 0.5  # tight clusters: most entries are never scored
    ref_ids, ref_dist, cos = brute_force(np.concatenate([fv[s], fv[e - 1]], 1), begin, end)
    np.testing.assert_allclose(dist, ref_dist, atol=1e-5)
    top2 = np.sort(cos, axis=1)[:, -2:]
    clear = top2[:, 1] - top2[:, 0] > 1e-5
    np.testing.assert_array_equal(ids[clear], ref_ids[clear])


def test_exact_search_ends_shortlist_equals_brute_force():
    """OOD retrieval (nearest end frame) over the cap-bound shortlist equals a float64 scan."""
    rng = np.random.default_rng(9)
    d, n = 16, 4000
    way = rng.normal(size=(30, d))
    begin = way[rng.integers(30, size=n)] + 0.02 * rng.normal(size=(n, d))
    end = (way[rng.integers(30, size=n)] + 0.02 * rng.normal(size=(n, d))) * rng.uniform(0.1, 10, (n, 1))
    end[:40] = end[40:80]  # exact duplicates: the lowest id wins
    frames = way[rng.integers(5, size=60)] + 0.05 * rng.normal(size=(60, d))  # a demo near 5 waypoints
    idx = ExactIndex(prune=True, cluster_size=8).fit(begin, end)
    unit = (frames / np.linalg.norm(frames, axis=1, keepdims=True)).astype(np.float32)
    shortlist = idx._end_shortlist(unit)
    assert shortlist is not None and shortlist.size < n  # the bounds really rule entries out
    ids, dist = idx.search_ends(frames)
    cos = (frames / np.linalg.norm(frames, axis=1, keepdims=True)) @ (end / np.linalg.norm(end, axis=1, keepdims=True)).T
    np.testing.assert_allclose(dist, np.sqrt(np.maximum(2 - 2 * cos.max(1), 0)), atol=1e-6)
    np.testing.assert_array_equal(ids, cos.argmax(1))


def test_a_saved_database_holds_what_its_first_query_needs(tmp_path, monkeypatch):
    """save() builds the exact index's clusters and keeps the data's fingerprint beside the manifest:
    the first decomposer on the loaded database neither clusters nor hashes the vectors again; a
    fingerprint file that the manifest does not vouch for is ignored (the data are hashed)."""
    import json

    import rdd.database.model as model_module
    import rdd.index.exact as exact_module
    from rdd.database.model import SubtaskDatabase
    from rdd.decomposers.rdd import RDDDecomposer

    rng = np.random.default_rng(7)
    n = 200
    begin, end = l2_normalize(clustered(rng, n, 8)), l2_normalize(clustered(rng, n, 8))
    db = SubtaskDatabase.from_arrays(begin, end, rng.integers(1, 20, n), [f"t{i % 5}" for i in range(n)])
    fresh = db.fingerprint()
    db.save(tmp_path / "db")
    assert len(list((tmp_path / "db").glob("exact-cells-*.npz"))) == 1

    def refuse(*args, **kwargs):
        raise AssertionError("built again on load")

    monkeypatch.setattr(exact_module, "fit_cells", refuse)
    monkeypatch.setattr(model_module.SubtaskDatabase, "_hash", refuse)
    loaded = SubtaskDatabase.load(tmp_path / "db")
    assert loaded.fingerprint() == fresh
    RDDDecomposer(loaded)
    monkeypatch.undo()
    kept = tmp_path / "db" / "fingerprint.json"
    kept.write_text(json.dumps({**json.loads(kept.read_text()), "checksums": {}}))
    assert SubtaskDatabase.load(tmp_path / "db").fingerprint() == fresh
