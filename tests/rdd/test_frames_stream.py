"""Decoding overlapped with encoding (iter_load, prefetch) and video files hashed once per process."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from rdd.data import frames as frames_mod
from rdd.encoders import load_encoder
from rdd.encoders._stream import encode_view, prefetch


@pytest.fixture
def v30(lerobot_factory):
    """Three episodes of a v3.0 dataset; episodes 0 and 1 share one video file."""
    from rdd.data.lerobot.reader import load_episodes

    return load_episodes(lerobot_factory("v3.0", (30, 36, 24)), max_side=12)


def _source(episode):
    return next(iter(episode.views.values()))


def test_iter_load_yields_what_load_returns(v30):
    for ep in v30:
        src = _source(ep)
        n = len(src)
        for idx in (None, [0, 3, 3, 7, n - 1], [n - 1, 2, 5, 2], []):
            chunks = list(src.iter_load(idx, chunk=4))
            assert all(len(c) <= 4 for c in chunks)
            whole = src.load(idx)
            got = np.concatenate(chunks) if chunks else np.zeros((0, 0, 0, 3), np.uint8)
            if len(whole):
                np.testing.assert_array_equal(got, whole)
            else:
                assert got.shape[0] == 0


def test_missing_frame_error_is_unchanged(v30):
    from rdd.data.lerobot.video import VideoFrames

    src = _source(v30[2])
    late = VideoFrames(src.path, np.append(src.timestamps, src.timestamps[-1] + 5.0), src.tolerance_s)
    for load in (lambda: late.load(), lambda: np.concatenate(list(late.iter_load(chunk=4)))):
        with pytest.raises(ValueError, match=r"no video frame within .* \(1 of 25 frames missing\)"):
            load()


def test_encode_view_equals_encoding_the_loaded_frames(v30):
    from rdd.data.episode import Episode

    enc = load_encoder("pixels", size=4, batch_size=5)
    ep = v30[1]
    view = next(iter(ep.views))
    for idx in (None, [1, 4, 4, 30], [9, 2]):
        np.testing.assert_array_equal(encode_view(enc, ep, view, idx), enc.encode(ep.frames(view, idx)))
    in_memory = Episode(name="m", views={"front": ep.frames(view)})
    np.testing.assert_array_equal(encode_view(enc, in_memory, "front"), enc.encode(ep.frames(view)))
    with pytest.raises(KeyError, match="no view 'nope'"):
        encode_view(enc, ep, "nope")


def test_prefetch_passes_errors_on_and_stops_when_left_early():
    def failing():
        yield 1
        raise OSError("disk gone")

    with pytest.raises(OSError, match="disk gone"):
        list(prefetch(failing()))

    closed = threading.Event()

    def endless():
        try:
            i = 0
            while True:
                yield i
                i += 1
        finally:
            closed.set()

    before = threading.active_count()
    it = prefetch(endless(), depth=2)
    assert [next(it) for _ in range(3)] == [0, 1, 2]
    it.close()
    assert closed.wait(5) and threading.active_count() == before


def test_a_shared_video_file_is_hashed_once(v30, monkeypatch):
    calls = []
    real = frames_mod.update_with_file

    def counting(h, path, block=1 << 20):
        calls.append(str(path))
        return real(h, path, block)

    monkeypatch.setattr(frames_mod, "update_with_file", counting)
    monkeypatch.setattr(frames_mod, "_DIGESTS", {})
    paths = [str(_source(ep).path) for ep in v30]
    assert paths[0] == paths[1] != paths[2]  # the fixture's layout
    prints = [ep.fingerprint() for ep in v30]
    assert len(set(prints)) == 3  # same file, different episodes: different fingerprints
    assert sorted(calls) == sorted({paths[0], paths[2]})
    assert [ep.fingerprint() for ep in v30] == prints and len(calls) == 2

    # A rewritten file (new modification time) is hashed again.
    from rdd.data.lerobot.video import VideoFrames

    src = _source(v30[0])
    st = os.stat(src.path)
    os.utime(src.path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    again = VideoFrames(src.path, src.timestamps, src.tolerance_s, src.max_side)
    assert again.fingerprint() == src.fingerprint()  # same bytes, same fingerprint
    assert len(calls) == 3 and calls[-1] == paths[0]
