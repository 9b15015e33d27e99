"""EmbeddingCache: hits, misses, key separation, corrupt entries, atomic files."""

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.encoders import load_encoder
from rdd.encoders.cache import EmbeddingCache
from rdd.encoders.embed import episode_frame_vectors


class CountingEncoder:
    """Wraps an encoder and counts the frames it is asked to encode."""

    def __init__(self, inner):
        self.inner = inner
        self.frames_encoded = 0

    def __getattr__(self, item):
        return getattr(self.inner, item)

    def encode(self, images):
        self.frames_encoded += len(images)
        return self.inner.encode(images)


def _episode(seed: int, t: int = 5) -> Episode:
    rng = np.random.default_rng(seed)
    views = {v: rng.integers(0, 256, size=(t, 16, 16, 3), dtype=np.uint8) for v in ("front", "wrist")}
    return Episode(name=f"ep{seed}", views=views)


def test_miss_then_hit_without_reencoding(tmp_path):
    enc = CountingEncoder(load_encoder("pixels", size=4))
    ep = _episode(0)
    cache = EmbeddingCache(tmp_path)
    first = episode_frame_vectors(ep, enc, cache=cache)
    assert cache.stats.misses == 2 and cache.stats.hits == 0 and enc.frames_encoded == 10
    # A fresh cache object over the same folder (a rerun) reads everything back.
    again = EmbeddingCache(tmp_path)
    second = episode_frame_vectors(ep, enc, cache=again)
    assert again.stats.hits == 2 and again.stats.misses == 0 and enc.frames_encoded == 10
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(first, episode_frame_vectors(ep, enc.inner))


def test_key_separates_content_view_and_encoder(tmp_path):
    cache = EmbeddingCache(tmp_path)
    small, big = load_encoder("pixels", size=4), load_encoder("pixels", size=8)
    ep, other = _episode(0), _episode(1)
    a = cache.get_or_compute(ep, small, "front")
    b = cache.get_or_compute(ep, small, "wrist")
    c = cache.get_or_compute(other, small, "front")
    d = cache.get_or_compute(ep, big, "front")
    assert cache.stats.misses == 4 and cache.stats.hits == 0
    assert d.shape == (5, 3 * 8 * 8)
    assert not np.array_equal(a, b) and not np.array_equal(a, c)
    # Same content under another episode name is the same entry.
    renamed = Episode(name="renamed", views={"front": ep.frames("front"), "wrist": ep.frames("wrist")})
    np.testing.assert_array_equal(cache.get_or_compute(renamed, small, "front"), a)
    assert cache.stats.hits == 1


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage"])
def test_corrupt_entry_is_detected_and_recomputed(tmp_path, damage):
    enc = CountingEncoder(load_encoder("pixels", size=4))
    ep = _episode(2)
    cache = EmbeddingCache(tmp_path)
    good = cache.get_or_compute(ep, enc, "front")
    (entry,) = list(tmp_path.rglob("*.npz"))
    raw = bytearray(entry.read_bytes())
    if damage == "truncate":
        raw = raw[: len(raw) // 2]
    elif damage == "flip":
        # Flip one byte inside the stored float data (npz is an uncompressed zip: data sits mid-file).
        needle = good.tobytes()[:8]
        pos = bytes(raw).find(needle)
        assert pos >= 0
        raw[pos + 3] ^= 0xFF
    else:
        raw = bytearray(b"not an npz file at all")
    entry.write_bytes(bytes(raw))
    fresh = EmbeddingCache(tmp_path)
    out = fresh.get_or_compute(ep, enc, "front")
    assert fresh.stats.corrupt == 1 and fresh.stats.misses == 1
    np.testing.assert_array_equal(out, good)
    assert enc.frames_encoded == 10
    # The entry was rewritten and is good again.
    third = EmbeddingCache(tmp_path)
    third.get_or_compute(ep, enc, "front")
    assert third.stats.hits == 1


def test_no_temporary_files_left_and_missing_view(tmp_path):
    cache = EmbeddingCache(tmp_path)
    cache.get_or_compute(_episode(3), load_encoder("pixels", size=2), "wrist")
    assert [p.suffix for p in tmp_path.rglob("*") if p.is_file()] == [".npz"]
    with pytest.raises(KeyError, match="side"):
        cache.get_or_compute(_episode(3), load_encoder("pixels", size=2), "side")
