"""`pip install .` as a new user would: a fresh virtual environment gets the library `rdd`, its public
API and its command, and none of the harness (its packages or its dependencies)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
# The public names the package root must give (DESIGN: the database, the decomposers, load_encoder,
# the readers, evaluate).
PUBLIC = ["SubtaskDatabase", "RDDDecomposer", "UVDDecomposer", "UniformDecomposer", "ExpertDecomposer",
          "VLMDecomposer", "load_encoder", "load_episodes", "episode_names", "Episode", "evaluate"]
# The harness's top-level packages and the harness-only dependencies: none may come with the library.
NOT_INSTALLED = ["envs", "policy", "planner", "experiments", "hydra_plugins", "run",
                 "pybullet", "hydra", "omegaconf", "peft", "wandb"]
PROBE = """
import importlib.metadata, importlib.util, json, sys, sysconfig
import rdd
dist = importlib.metadata.distribution("rdd")
print(json.dumps({
    "file": rdd.__file__, "purelib": sysconfig.get_paths()["purelib"],
    "public": {name: callable(getattr(rdd, name)) for name in sys.argv[1].split(",")},
    "miou": rdd.evaluate([(0, 4), (4, 10)], [(0, 5), (5, 10)])["miou"],
    "importable": [m for m in sys.argv[2].split(",") if importlib.util.find_spec(m) is not None],
    "top_level": sorted({f.parts[0] for f in dist.files if f.parts[0] != ".."}),
    "license": dist.metadata["License-Expression"], "version": dist.version,
}))
"""


def _run(cmd: list[str | Path], cwd: Path, env: dict[str, str], timeout: int) -> str:
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, text=True, capture_output=True,
                          timeout=timeout)
    assert proc.returncode == 0, f"{cmd}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout + proc.stderr


@pytest.mark.slow
def test_pip_install_gives_the_library_alone(tmp_path: Path):
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("copying the committed tree needs git and a git checkout")
    copy, venv, elsewhere = tmp_path / "copy", tmp_path / "venv", tmp_path / "elsewhere"
    copy.mkdir()
    elsewhere.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "HEAD"], capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(copy)], input=archive.stdout, check=True)
    # A user's shell: no PYTHONPATH pointing into a checkout, no active environment.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env.update(PIP_CONSTRAINT=str(copy / "constraints.txt"), PIP_DISABLE_PIP_VERSION_CHECK="1")
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    log = _run([py, "-m", "pip", "install", "-v", str(copy)], elsewhere, env, timeout=600)
    # setuptools warns about the old `license = {text = ...}` table while building
    assert "project.license" not in log, [line for line in log.splitlines() if "license" in line.lower()]

    probe = json.loads(_run([py, "-c", PROBE, ",".join(PUBLIC), ",".join(NOT_INSTALLED)], elsewhere, env, 120))
    assert Path(probe["file"]).is_relative_to(probe["purelib"])  # the installed copy, not a checkout
    assert probe["public"] == dict.fromkeys(PUBLIC, True)
    assert probe["miou"] == pytest.approx((4 / 5 + 5 / 6) / 2)  # [0,4) vs [0,5), [4,10) vs [5,10)
    assert probe["importable"] == []
    assert probe["top_level"] == ["rdd", f"rdd-{probe['version']}.dist-info"]
    assert probe["license"] == "MIT"

    demo = _run([py, "-m", "rdd", "demo"], elsewhere, env, 300)
    assert "RDD segments" in demo
    script_help = _run([venv / "bin" / "rdd", "--help"], elsewhere, env, 60)
    assert "decompose" in script_help and script_help.startswith("usage: rdd ")
