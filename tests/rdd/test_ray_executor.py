"""``--executor ray`` (issue 47): build-db and decompose run as tasks on a local Ray cluster write the
same bytes as a local run, resume from a local run's staged parts, and report errors as a local run
does. Needs the cluster extra (make install-cluster); without it only the missing-Ray error is tested."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from rdd.cli import main
from rdd.data.episode import Episode
from rdd.data.native import save_episode
from rdd.decomposers.uvd import UVDDecomposer
from rdd.progress import EpisodeBar
from rdd.testing.trees import tree_bytes

INSTALL = "make install-cluster"
NAMES = [f"ep{k}" for k in range(6)]  # the episodes of the native_six fixture


def uvd(data: Path, out: Path, fmt: str = "native") -> list[str]:
    return ["decompose", "--format", fmt, "--data", str(data), "--decomposer", "uvd", "--encoder", "pixels",
            "--encoder-option", "size=4", "--option", "min_interval=3", "--no-cache", "--out", str(out)]


def build(data: Path, out: Path) -> list[str]:
    return ["build-db", "--format", "native", "--data", str(data), "--encoder", "pixels", "--encoder-option",
            "size=4", "--no-cache", "--calibration-sample", "2", "--out", str(out)]


def parts_of(out: Path) -> list[Path]:
    folder = out.parent / f".{out.name}.parts"
    return sorted(p for p in folder.rglob("*.*") if not p.name.startswith(".")) if folder.exists() else []


def test_missing_ray_is_one_line_naming_the_install(native_six, tmp_path, monkeypatch, cli_fails):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    cli_fails(*uvd(native_six, tmp_path / "x.json"), "--executor", "ray", expect=("--executor ray needs Ray", INSTALL))
    assert not (tmp_path / "x.json").exists() and not parts_of(tmp_path / "x.json")
    cli_fails(*uvd(native_six, tmp_path / "x.json"), "--ray-address", "auto", expect=("--ray-address auto",
                                                                                "needs --executor ray"))


def test_default_starts_and_stops_its_own_local_cluster(native_six, tmp_path):
    ray = pytest.importorskip("ray", reason=f"Ray not installed ({INSTALL})")
    assert not ray.is_initialized()
    assert main(uvd(native_six, tmp_path / "local.json")) == 0
    assert main([*uvd(native_six, tmp_path / "ray.json"), "--executor", "ray", "--workers", "2"]) == 0
    assert (tmp_path / "ray.json").read_bytes() == (tmp_path / "local.json").read_bytes()
    assert not ray.is_initialized() and not parts_of(tmp_path / "ray.json")


@pytest.fixture(scope="module")
def ray_session():
    """A small local Ray cluster for the module: 2 CPUs, a 256 MiB object store, no dashboard."""
    ray = pytest.importorskip("ray", reason=f"Ray not installed ({INSTALL})")
    ray.init(num_cpus=2, object_store_memory=256 << 20, include_dashboard=False, log_to_driver=False,
             configure_logging=False)
    yield ray
    ray.shutdown()


def test_build_db_on_ray_writes_the_local_database(ray_session, native_six, tmp_path):
    assert main(build(native_six, tmp_path / "local")) == 0
    assert main([*build(native_six, tmp_path / "ray"), "--executor", "ray", "--workers", "2"]) == 0
    assert tree_bytes(tmp_path / "ray") == tree_bytes(tmp_path / "local")
    assert ray_session.is_initialized()  # a session the process started is left running


def test_decompose_lerobot_v30_on_ray(ray_session, lerobot_factory, tmp_path):
    data = lerobot_factory("v3.0")
    assert main(uvd(data, tmp_path / "local.json", "lerobot")) == 0
    assert main([*uvd(data, tmp_path / "ray.json", "lerobot"), "--executor", "ray", "--workers", "2"]) == 0
    assert (tmp_path / "ray.json").read_bytes() == (tmp_path / "local.json").read_bytes()


def test_ray_resumes_a_stopped_local_run(ray_session, native_six, tmp_path, monkeypatch):
    assert main(uvd(native_six, tmp_path / "ref.json")) == 0
    out = tmp_path / "out.json"
    original, calls = UVDDecomposer.decompose, []

    def stop_at_third(self, episode):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(episode.name)
        return original(self, episode)

    monkeypatch.setattr(UVDDecomposer, "decompose", stop_at_third)
    assert main(uvd(native_six, out)) == 130
    monkeypatch.undo()
    assert len(parts_of(out)) == 2
    advanced: list[str] = []
    monkeypatch.setattr(EpisodeBar, "advance", lambda self, name, frames, seconds: advanced.append(name))
    assert main([*uvd(native_six, out), "--executor", "ray", "--workers", "2"]) == 0
    assert sorted(advanced) == NAMES[2:]  # the two staged episodes were not sent again
    assert out.read_bytes() == (tmp_path / "ref.json").read_bytes()
    assert not parts_of(out)


def test_an_episode_error_stops_the_job_as_locally(ray_session, tmp_path, cli_fails):
    data = tmp_path / "ds"
    frames = np.zeros((16, 8, 8, 3), dtype=np.uint8)
    for name, grip in (("a", np.repeat([1.0, 0.0], 8)), ("b", None), ("c", np.repeat([1.0, 0.0], 8))):
        save_episode(Episode(name=name, views={"front": frames}, gripper_open=grip, joint_velocities=np.ones((16, 7)),
                             goal="toy", task="toy"),
                     data / name)
    args = ["decompose", "--format", "native", "--data", str(data), "--decomposer", "expert"]
    expect = ("episode 'b'", "gripper_open")
    local = cli_fails(*args, "--out", tmp_path / "a.json", expect=expect)
    remote = cli_fails(*args, "--out", tmp_path / "b.json", "--executor", "ray", "--workers", "2", expect=expect)
    assert local.replace("a.json", "b.json") == remote and len(remote.strip().splitlines()) == 1
    assert not (tmp_path / "b.json").exists()
