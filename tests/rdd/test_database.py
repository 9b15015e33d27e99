"""Sub-task database: build from episodes, save/load round trip, and every bad input's error."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rdd.data.episode import Episode
from rdd.database.model import DatabaseError, SubtaskDatabase
from rdd.encoders.base import Encoder
from rdd.encoders.embed import episode_frame_vectors


class ProjectionEncoder(Encoder):
    """A fixed random projection of mean-pooled pixels (test encoder, deterministic)."""

    name = "test_projection"

    def __init__(self, dim: int = 6, seed: int = 0) -> None:
        self.dim = dim
        self.seed = seed
        self._w = np.random.default_rng(seed).normal(size=(4 * 4 * 3, dim)).astype(np.float32)

    @property
    def weights_id(self) -> str:
        return f"proj-{self.dim}-{self.seed}"

    def encode(self, images: np.ndarray) -> np.ndarray:
        x = images.astype(np.float32).reshape(images.shape[0], 4, 2, 4, 2, 3).mean(axis=(2, 4))
        return (x.reshape(images.shape[0], -1) / 255.0 - 0.5) @ self._w


def make_episode(name: str, t: int, seed: int, segments, instructions) -> Episode:
    rng = np.random.default_rng(seed)
    views = {v: rng.integers(0, 256, size=(t, 8, 8, 3), dtype=np.uint8) for v in ("front", "wrist")}
    return Episode(name=name, views=views, task="stack", segments=segments, instructions=instructions)


@pytest.fixture
def episodes():
    return [
        make_episode("ep0", 12, 0, [(0, 5), (5, 12)], ["pick the block", "place it"]),
        make_episode("ep1", 9, 1, [(0, 3), (3, 4), (4, 9)], ["reach", "grasp", "lift"]),
    ]


def test_build_keeps_vectors_and_provenance(episodes):
    enc = ProjectionEncoder()
    db = SubtaskDatabase.build(episodes, None, enc)
    assert len(db) == 5 and db.frame_dim == 12
    fv1 = episode_frame_vectors(episodes[1], enc)
    np.testing.assert_allclose(db.begin[3], fv1[3])  # entry 3 is ep1 [3, 4): begin = end = frame 3
    np.testing.assert_allclose(db.end[3], fv1[3])
    np.testing.assert_allclose(db.end[4], fv1[8])
    assert list(db.durations) == [4, 6, 2, 0, 4]
    assert db.entry(1) == {"entry": 1, "episode": "ep0", "task": "stack", "instruction": "place it",
                           "start": 5, "end": 12, "duration": 6}
    assert db.meta["encoder"] == "test_projection" and db.meta["views"] == ["front", "wrist"]


def test_build_with_other_segmentation_has_no_labels_unless_given(episodes):
    enc = ProjectionEncoder()
    segs = [[(0, 12)], [(0, 9)]]
    db = SubtaskDatabase.build(episodes, segs, enc)
    assert db.labels == ["", ""]
    db = SubtaskDatabase.build(episodes, segs, enc, instructions=[["do all"], ["do it"]])
    assert db.labels == ["do all", "do it"]
    # an episode without its own segmentation: its instructions describe the one passed in
    for ep, text in zip(episodes, (["whole"], ["all of it"]), strict=True):
        ep.segments, ep.instructions = None, text
    assert SubtaskDatabase.build(episodes, segs, enc).labels == ["whole", "all of it"]


def test_build_errors(episodes):
    enc = ProjectionEncoder()
    with pytest.raises(ValueError, match="ep0.*must end at 12"):
        SubtaskDatabase.build(episodes, [[(0, 5)], [(0, 9)]], enc)
    with pytest.raises(ValueError, match="1 segmentations given for 2 episodes"):
        SubtaskDatabase.build(episodes, [[(0, 12)]], enc)
    with pytest.raises(ValueError, match="ep1.*2 instructions for 3 segments"):
        SubtaskDatabase.build(episodes, None, enc, instructions=[["a", "b"], ["a", "b"]])
    with pytest.raises(KeyError, match="no view 'side'"):
        SubtaskDatabase.build(episodes, None, enc, views=("side",))


def test_save_load_round_trip(tmp_path, episodes):
    enc = ProjectionEncoder()
    db = SubtaskDatabase.build(episodes, None, enc)
    db.save(tmp_path / "db")
    back = SubtaskDatabase.load(tmp_path / "db", encoder=enc, views=("front", "wrist"))
    np.testing.assert_array_equal(back.begin, db.begin)
    np.testing.assert_array_equal(back.end, db.end)
    np.testing.assert_array_equal(back.durations, db.durations)
    assert [back.entry(i) for i in range(len(db))] == [db.entry(i) for i in range(len(db))]
    assert back.fingerprint() == db.fingerprint()
    assert back.directory == tmp_path / "db"
    manifest = json.loads((tmp_path / "db" / "manifest.json").read_text())
    assert manifest["count"] == 5 and manifest["frame_dim"] == 12
    assert manifest["encoder"] == "test_projection" and manifest["weights_id"] == enc.weights_id
    assert set(manifest["checksums"]) == {"begin.npy", "end.npy", "durations.npy", "entries.json"}
    assert not list((tmp_path / "db").glob("*.tmp"))


@pytest.fixture
def saved(tmp_path, episodes):
    SubtaskDatabase.build(episodes, None, ProjectionEncoder()).save(tmp_path / "db")
    return tmp_path / "db"


def test_load_with_other_encoder_or_views(saved):
    with pytest.raises(DatabaseError, match="encoder 'test_projection'.*weights proj-6-0.*proj-6-1"):
        SubtaskDatabase.load(saved, encoder=ProjectionEncoder(seed=1))
    with pytest.raises(DatabaseError, match=r"views \['front', 'wrist'\], not \['front'\]"):
        SubtaskDatabase.load(saved, views=("front",))


def test_load_dimension_mismatch(saved):
    class Wider(ProjectionEncoder):
        @property
        def weights_id(self) -> str:
            return "proj-6-0"  # same name and weights id, but a different output size

    with pytest.raises(DatabaseError, match="12-d frame vectors.*8-d"):
        SubtaskDatabase.load(saved, encoder=Wider(dim=8))


def test_load_missing_and_corrupt_files(saved, tmp_path):
    with pytest.raises(DatabaseError, match="does not exist"):
        SubtaskDatabase.load(tmp_path / "nowhere")
    (saved / "end.npy").write_bytes((saved / "end.npy").read_bytes()[:-4] + b"\x00\x00\x00\x01")
    with pytest.raises(DatabaseError, match=r"end\.npy is corrupt"):
        SubtaskDatabase.load(saved)
    (saved / "end.npy").unlink()
    with pytest.raises(DatabaseError, match=r"end\.npy is missing"):
        SubtaskDatabase.load(saved)
    (saved / "manifest.json").write_text("{not json")
    with pytest.raises(DatabaseError, match="not valid JSON"):
        SubtaskDatabase.load(saved)
    (saved / "manifest.json").unlink()
    with pytest.raises(DatabaseError, match=r"manifest\.json is missing"):
        SubtaskDatabase.load(saved)


def test_load_shape_disagreeing_with_manifest(saved):
    manifest = json.loads((saved / "manifest.json").read_text())
    manifest["frame_dim"] = 7
    (saved / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatabaseError, match=r"begin\.npy has shape \(5, 12\), manifest says \(5, 7\)"):
        SubtaskDatabase.load(saved)
    manifest["format_version"] = 99
    (saved / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatabaseError, match="format_version 99"):
        SubtaskDatabase.load(saved)


def test_from_arrays_errors():
    b = np.ones((3, 4))
    with pytest.raises(ValueError, match="differ in shape"):
        SubtaskDatabase.from_arrays(b, np.ones((3, 5)), [1, 1, 1])
    with pytest.raises(ValueError, match=r"durations must have shape \(3,\)"):
        SubtaskDatabase.from_arrays(b, b, [1, 1])
    with pytest.raises(ValueError, match=">= 0"):
        SubtaskDatabase.from_arrays(b, b, [1, -1, 1])
    with pytest.raises(ValueError, match="labels has 2 items"):
        SubtaskDatabase.from_arrays(b, b, [1, 1, 1], labels=["a", "b"])
    with pytest.raises(ValueError, match="meta\\['episodes'\\] has 1 items"):
        SubtaskDatabase.from_arrays(b, b, [1, 1, 1], meta={"episodes": ["x"]})
    with pytest.raises(ValueError, match="NaN"):
        SubtaskDatabase.from_arrays(np.full((3, 4), np.nan), b, [1, 1, 1])
    with pytest.raises(ValueError, match="at least one entry"):
        SubtaskDatabase.from_arrays(np.ones((0, 4)), np.ones((0, 4)), [])


class CountingEncoder(ProjectionEncoder):
    """Counts the images it is asked to encode."""

    def __init__(self) -> None:
        super().__init__()
        self.images = 0

    def encode(self, images: np.ndarray) -> np.ndarray:
        self.images += images.shape[0]
        return super().encode(images)


def test_build_encodes_only_boundary_frames_unless_kept(episodes):
    enc = CountingEncoder()
    db = SubtaskDatabase.build(episodes, None, enc)
    # ep0 [0,5),[5,12): frames 0,4,5,11; ep1 [0,3),[3,4),[4,9): frames 0,2,3,4,8; two views each
    assert enc.images == 2 * (4 + 5)
    full = SubtaskDatabase.build(episodes, None, ProjectionEncoder())
    np.testing.assert_allclose(db.begin, full.begin, atol=1e-6)
    np.testing.assert_allclose(db.end, full.end, atol=1e-6)
    assert db.frames == {}
    enc = CountingEncoder()
    kept = SubtaskDatabase.build(episodes, None, enc, keep_frames=["ep1"])
    assert enc.images == 2 * (4 + 9)
    np.testing.assert_allclose(kept.frames["ep1"], episode_frame_vectors(episodes[1], ProjectionEncoder()))
    with pytest.raises(ValueError, match="not being built.*'nope'"):
        SubtaskDatabase.build(episodes, None, enc, keep_frames=["nope"])


def test_raw_views_and_goal_is_no_instruction(episodes):
    enc = ProjectionEncoder()
    raw = SubtaskDatabase.build(episodes, None, enc, normalize_views=False)
    f0 = enc.encode(episodes[0].frames("front", [0]))[0]
    np.testing.assert_allclose(raw.begin[0, :6], f0, rtol=1e-5)
    assert raw.meta["normalize_views"] is False
    for ep, goal in zip(episodes, ("open the drawer", "close it"), strict=True):
        ep.instructions, ep.goal = None, goal
    db = SubtaskDatabase.build(episodes, None, enc)
    # an unannotated segment has no sub-task: the goal is the episode's, not an instruction
    assert db.labels == [""] * 5 and db.tasks == [episodes[0].task] * 2 + [episodes[1].task] * 3


def test_save_refuses_to_replace_unless_asked_and_keeps_frames(tmp_path, episodes):
    from rdd.atomic import TargetExistsError

    enc = ProjectionEncoder()
    db = SubtaskDatabase.build(episodes, None, enc, keep_frames=["ep0"], normalize_views=False)
    db.meta["calibration"] = {"chosen": {"alpha": 0.25, "min_len": 3, "max_len": 9}, "score": 0.9}
    db.save(tmp_path / "db")
    other = SubtaskDatabase.build(episodes[:1], None, enc)
    with pytest.raises(TargetExistsError, match="already exists"):
        other.save(tmp_path / "db")
    back = SubtaskDatabase.load(tmp_path / "db")
    assert len(back) == 5 and set(back.frames) == {"ep0"}
    np.testing.assert_array_equal(back.frames["ep0"], db.frames["ep0"])
    assert back.meta["normalize_views"] is False
    assert back.calibrated_options() == {"alpha": 0.25, "min_len": 3, "max_len": 9}
    assert back.episode_segments("ep1") == [(0, 3), (3, 4), (4, 9)]
    other.save(tmp_path / "db", overwrite=True)
    assert len(SubtaskDatabase.load(tmp_path / "db")) == 2
    with pytest.raises(DatabaseError, match="no calibration"):
        SubtaskDatabase.load(tmp_path / "db").calibrated_options()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["db"]  # no temporary left behind


def test_concat_of_parts_built_apart_is_the_database_built_at_once(episodes, tmp_path):
    enc = ProjectionEncoder()
    extra = make_episode("ep2", 7, 2, [(0, 2), (2, 7)], ["push", "release"])
    whole = SubtaskDatabase.build([*episodes, extra], None, enc)
    whole.save(tmp_path / "whole")
    # parts built and saved separately, as concurrent jobs build per-task parts, then reloaded
    for name, eps in (("a", episodes), ("b", [extra])):
        SubtaskDatabase.build(eps, None, enc).save(tmp_path / name)
    merged = SubtaskDatabase.concat([SubtaskDatabase.load(tmp_path / "a"), SubtaskDatabase.load(tmp_path / "b")])
    merged.save(tmp_path / "merged")
    for name in ("begin.npy", "end.npy", "durations.npy", "entries.json"):
        assert (tmp_path / "merged" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
    a = json.loads((tmp_path / "whole" / "manifest.json").read_text())
    b = json.loads((tmp_path / "merged" / "manifest.json").read_text())
    assert a == b


def test_concat_refuses_parts_of_different_encoders(episodes):
    a = SubtaskDatabase.build(episodes[:1], None, ProjectionEncoder(seed=0))
    b = SubtaskDatabase.build(episodes[1:], None, ProjectionEncoder(seed=1))
    with pytest.raises(ValueError, match="part 1 has weights_id='proj-6-1'"):
        SubtaskDatabase.concat([a, b])
    with pytest.raises(ValueError, match="at least one"):
        SubtaskDatabase.concat([])
