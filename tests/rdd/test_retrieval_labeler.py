"""Retrieval labeler: the nearest database entry's instruction (interval vectors: docs/architecture.md)."""

from __future__ import annotations

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.database.model import DatabaseError, SubtaskDatabase
from rdd.encoders.pixels import PixelsEncoder
from rdd.labelers.retrieval import RetrievalLabeler

COLOURS = {"a": (250, 10, 10), "b": (10, 250, 10), "c": (10, 10, 250), "d": (250, 250, 10)}


def _episode(name: str, plan: list[tuple[str, int]], noise: int, seed: int) -> Episode:
    """Frames of solid colours (one colour per phase) plus a little noise; segments = phases."""
    rng = np.random.default_rng(seed)
    frames, segments, instructions, t = [], [], [], 0
    for key, n in plan:
        img = np.broadcast_to(np.array(COLOURS[key], dtype=np.int16), (n, 32, 32, 3))
        frames.append(np.clip(img + rng.integers(-noise, noise + 1, img.shape), 0, 255).astype(np.uint8))
        segments.append((t, t + n))
        instructions.append(f"do {key}")
        t += n
    video = np.concatenate(frames)
    return Episode(name, {"front": video, "wrist": video[:, ::-1].copy()}, segments=segments,
                   instructions=instructions)


@pytest.fixture(scope="module")
def labeler():
    enc = PixelsEncoder(size=8)
    train = [_episode("train0", [("a", 6), ("b", 5), ("c", 7)], 3, 0),
             _episode("train1", [("d", 5), ("a", 6)], 3, 1)]
    db = SubtaskDatabase.build(train, None, enc, views=("front", "wrist"))
    return RetrievalLabeler(db, enc, index="exact")


def test_intervals_get_the_nearest_entrys_instruction(labeler):
    query = _episode("query", [("c", 4), ("d", 9), ("b", 3)], 5, 7)
    assert labeler.label_all(query, query.segments) == ["do c", "do d", "do b"]
    assert labeler.label(query, (4, 13)) == "do d"


def test_matches_brute_force_angular_nearest(labeler):
    query = _episode("query2", [("a", 5), ("b", 5), ("c", 5)], 40, 3)
    from rdd.encoders.embed import episode_frame_vectors

    fv = episode_frame_vectors(query, labeler.encoder, views=("front", "wrist"))
    db = labeler.database
    entries = np.concatenate([db.begin, db.end], axis=1)
    entries /= np.linalg.norm(entries, axis=1, keepdims=True)
    rng = np.random.default_rng(0)
    for _ in range(15):
        s, e = sorted(rng.choice(16, size=2, replace=False).tolist())
        q = np.concatenate([fv[s], fv[e - 1]])
        q /= np.linalg.norm(q)
        expected = db.labels[int(np.argmax(entries @ q))]
        assert labeler.label(query, (s, e)) == expected


def test_rejects_a_database_from_another_encoder(labeler):
    with pytest.raises(DatabaseError, match="encoder"):
        RetrievalLabeler(labeler.database, PixelsEncoder(size=4))
