"""Bad frames and pickles are an InputError whose one line names the file at fault (issue 39): a
frame of another size, a decompression-bomb or truncated PNG, a pickle holding the wrong type."""

from __future__ import annotations

import pickle
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rdd.data.native import load_episode as load_native
from rdd.data.rlbench import load_episode
from rdd.errors import InputError

N = 4


@pytest.fixture
def rlbench_types(monkeypatch):
    """Stand-ins for rlbench's Demo and Observation, pickled under rlbench's own module names."""
    demo_mod, obs_mod = types.ModuleType("rlbench.demo"), types.ModuleType("rlbench.backend.observation")

    class Demo:
        def __init__(self, observations):
            self._observations = observations

    class Observation:
        def __init__(self, i):
            self.gripper_open = float(i < N // 2)
            self.joint_positions = np.full(7, 0.1 * i)

    Demo.__module__, Demo.__qualname__ = demo_mod.__name__, "Demo"
    Observation.__module__, Observation.__qualname__ = obs_mod.__name__, "Observation"
    demo_mod.Demo, obs_mod.Observation = Demo, Observation
    for name, mod in (("rlbench", types.ModuleType("rlbench")), ("rlbench.backend", types.ModuleType("x")),
                      (demo_mod.__name__, demo_mod), (obs_mod.__name__, obs_mod)):
        monkeypatch.setitem(sys.modules, name, mod)
    return Demo, Observation


@pytest.fixture
def episode(tmp_path, rlbench_types) -> Path:
    """A tiny RLBench episode folder: N 16x16 frames per view and a pickled Demo."""
    Demo, Observation = rlbench_types
    root = tmp_path / "episode0"
    for view in ("front", "wrist"):
        (root / f"{view}_rgb").mkdir(parents=True)
        for i in range(N):
            Image.fromarray(np.full((16, 16, 3), 40 * i, dtype=np.uint8)).save(root / f"{view}_rgb/{i}.png")
    (root / "low_dim_obs.pkl").write_bytes(pickle.dumps(Demo([Observation(i) for i in range(N)])))
    return root


def message(call) -> str:
    with pytest.raises(InputError) as info:
        call()
    assert "\n" not in str(info.value)
    return str(info.value)


def test_good_episode_loads(episode):
    ep = load_episode(episode)
    assert ep.frames("front").shape == (N, 16, 16, 3) and ep.gripper_open.tolist() == [1, 1, 0, 0]


def test_frame_of_another_size_names_file_and_sizes(episode):
    Image.fromarray(np.zeros((8, 12, 3), dtype=np.uint8)).save(episode / "front_rgb/2.png")
    ep = load_episode(episode)
    text = message(lambda: ep.frames("front"))
    assert "front_rgb/2.png" in text and "12x8" in text and "16x16" in text
    # Loaded alone, the odd frame is still compared with the first one.
    assert "front_rgb/2.png" in message(lambda: load_episode(episode).frames("front", [2]))
    assert load_episode(episode).frames("wrist").shape == (N, 16, 16, 3)


@pytest.mark.parametrize("limit", [100, 200])  # 16x16 = 256 pixels: over twice the limit (PIL's error), or its warning
def test_decompression_bomb_is_one_line_naming_the_file(episode, monkeypatch, limit):
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", limit)
    text = message(lambda: load_episode(episode).frames("front", [1]))
    assert "front_rgb/1.png" in text and "decompression bomb" in text


def test_truncated_png_names_the_file(episode):
    path = episode / "wrist_rgb/3.png"
    path.write_bytes(path.read_bytes()[:40])
    assert "wrist_rgb/3.png" in message(lambda: load_episode(episode).frames("wrist"))


@pytest.mark.parametrize("content, got", [
    ([1, 2, 3], "list of 3 items (int)"),
    ({"observations": []}, "a dict"),
    (np.zeros(3), "a ndarray"),
])
def test_pickle_of_the_wrong_type_names_the_pickle_not_the_frames(episode, content, got):
    (episode / "low_dim_obs.pkl").write_bytes(pickle.dumps(content))
    text = message(lambda: load_episode(episode))
    assert "low_dim_obs.pkl" in text and "expected an rlbench Demo" in text and got in text
    assert "png" not in text and "images" not in text


def test_demo_without_observation_list(episode, rlbench_types):
    Demo, _ = rlbench_types
    (episode / "low_dim_obs.pkl").write_bytes(pickle.dumps(Demo(None)))
    text = message(lambda: load_episode(episode))
    assert "low_dim_obs.pkl" in text and "rlbench.demo.Demo" in text and "'_observations' is a NoneType" in text


def test_non_numeric_observation_attribute(episode, rlbench_types):
    Demo, Observation = rlbench_types
    observations = [Observation(i) for i in range(N)]
    observations[1].joint_positions = np.zeros(3)
    (episode / "low_dim_obs.pkl").write_bytes(pickle.dumps(Demo(observations)))
    text = message(lambda: load_episode(episode))
    assert "low_dim_obs.pkl" in text and "'joint_positions'" in text


@pytest.mark.parametrize("name, content, got", [
    ("variation_descriptions.pkl", {"a": 1}, "a dict"),
    ("variation_descriptions.pkl", ["open", 3], "list of 2 items (int, str)"),
    ("variation_number.pkl", "two", "a str"),
])
def test_variation_pickles_of_the_wrong_type(episode, name, content, got):
    (episode / name).write_bytes(pickle.dumps(content))
    text = message(lambda: load_episode(episode))
    assert name in text and got in text


def test_native_object_arrays_name_the_file(tmp_path):
    from rdd.data.episode import Episode
    from rdd.data.native import LOWDIM_FILE, frames_file, save_episode

    root = save_episode(Episode("e", {"front": np.zeros((3, 4, 4, 3), np.uint8)}, gripper_open=np.ones(3)),
                        tmp_path / "e")
    np.savez(root / LOWDIM_FILE, gripper_open=np.array([1, "x", None], dtype=object))
    assert LOWDIM_FILE in message(lambda: load_native(root))
    np.savez(root / LOWDIM_FILE, gripper_open=np.ones(3))
    np.savez(root / frames_file("front"), frames=np.array([None] * 3, dtype=object))
    assert frames_file("front") in message(lambda: load_native(root).frames("front"))
