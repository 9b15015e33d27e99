"""RLBench reader: real episodes, and a pickle that tries to run code is refused."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from rdd.data.rlbench import (
    RestrictedUnpickler,
    image_paths,
    load_episode,
    load_episodes,
    restricted_load,
)


class Exploit:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        import os

        return (os.system, (f"touch {self.marker}",))


def test_malicious_pickle_is_refused(tmp_path):
    marker = tmp_path / "pwned"
    bad = tmp_path / "low_dim_obs.pkl"
    bad.write_bytes(pickle.dumps([Exploit(marker)]))
    with pytest.raises(pickle.UnpicklingError, match="refusing to load global"):
        restricted_load(bad)
    assert not marker.exists()
    with pytest.raises(pickle.UnpicklingError, match="builtins.eval"):
        RestrictedUnpickler(__import__("io").BytesIO(
            b"cbuiltins\neval\n(S'1+1'\ntR.")).load()
    with pytest.raises(pickle.UnpicklingError):
        load_episode(tmp_path, views=())


def test_numpy_arrays_survive():
    import io

    arr = np.arange(6, dtype=np.float32).reshape(2, 3)
    out = RestrictedUnpickler(io.BytesIO(pickle.dumps({"a": arr, "s": np.float64(2.5)}))).load()
    np.testing.assert_array_equal(out["a"], arr)
    assert out["s"] == 2.5


def test_missing_files_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="low_dim_obs.pkl"):
        load_episode(tmp_path)
    with pytest.raises(FileNotFoundError, match="no RLBench episodes"):
        load_episodes(tmp_path)


def test_image_paths_frame_by_frame(tmp_path):
    """Each frame's files, one per view in the order asked, frames in number order (10 after 9)."""
    for view in ("front", "wrist"):
        (tmp_path / f"{view}_rgb").mkdir()
        for i in range(12):
            (tmp_path / f"{view}_rgb" / f"{i}.png").write_bytes(b"")  # never opened
    paths = image_paths(tmp_path)
    assert len(paths) == 12
    assert paths[10] == [str(tmp_path / "front_rgb/10.png"), str(tmp_path / "wrist_rgb/10.png")]
    assert image_paths(tmp_path, ("wrist",), 2) == [[str(tmp_path / "wrist_rgb/0.png")],
                                                    [str(tmp_path / "wrist_rgb/1.png")]]
    assert image_paths(tmp_path, ("overhead", "front")) == []  # frames counted in the first view's folder


def test_image_paths_are_the_readers_files(real_data):
    folder = real_data("rlbench") / "open_drawer/all_variations/episodes/episode0"
    ep = load_episode(folder)
    paths = image_paths(folder)
    assert len(paths) == ep.num_frames
    for j, view in enumerate(("front", "wrist")):
        assert [frame[j] for frame in paths] == [str(p) for p in ep.views[view].paths]


def test_real_episodes(real_data):
    DATA = real_data("rlbench")
    eps = load_episodes(DATA)
    assert [e.name for e in eps] == [f"episode{i}" for i in range(6)]
    lengths = [e.num_frames for e in eps]
    assert min(lengths) == 96 and max(lengths) == 125
    e0 = eps[0]
    assert e0.task == "open_drawer" and "drawer" in e0.goal
    assert e0.frames("front", [0, 124]).shape == (2, 128, 128, 3)
    assert e0.frames("wrist", [3]).dtype == np.uint8
    assert e0.joint_velocities.shape == (125, 7) and e0.ee_poses.shape == (125, 7)
    assert set(np.unique(e0.gripper_open)) <= {0.0, 1.0}
    with pytest.raises(FileNotFoundError, match="available views"):
        load_episode(DATA / "open_drawer/all_variations/episodes/episode0", views=("overhead",))


def test_symlinked_episode_folders_are_found(tmp_path, real_data):
    """Datasets are often linked in: episodes behind symlinked folders load, a link cycle is harmless."""
    DATA = real_data("rlbench")
    src = DATA / "open_drawer/all_variations/episodes"
    (tmp_path / "mine").mkdir()
    for name in ("episode0", "episode3"):
        (tmp_path / "mine" / name).symlink_to(src / name, target_is_directory=True)
    (tmp_path / "mine" / "loop").symlink_to(tmp_path / "mine", target_is_directory=True)
    eps = load_episodes(tmp_path / "mine")
    assert [e.name for e in eps] == ["episode0", "episode3"]
    assert eps[1].num_frames == load_episode(src / "episode3").num_frames
