"""docs/extending.md runs: its plugin modules and YAMLs, written into a temporary folder, work through
``python -m rdd`` (a decomposer, an encoder, a labeler) and ``run.py mode=decompose`` (the same ones,
and a new task)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "extending.md"
PLUGINS = "halves,mean_colour,gripper_words,lift_block"


def doc_files() -> dict[str, str]:
    """Every code block of the page whose first line is ``# plugins/...``: path -> text."""
    blocks = re.findall(r"```(?:python|yaml)\n(# (plugins/\S+)\n.*?)```", DOC.read_text(), re.S)
    return {path: text for text, path in blocks}


@pytest.fixture(scope="module")
def plugins(tmp_path_factory) -> Path:
    """The page's plugin folder, written as the page shows it."""
    root = tmp_path_factory.mktemp("extending")
    for rel, text in doc_files().items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root / "plugins"


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    """Three native episodes whose gripper closes for the middle third."""
    from rdd.testing.native_synth import write_noise_episodes

    return write_noise_episodes(tmp_path_factory.mktemp("demos"), 3, [1.0, 0.0, 1.0], 6, size=16)


def run(plugins: Path, *argv: str, cwd: Path) -> subprocess.CompletedProcess:
    """A command with the page's ``PYTHONPATH`` and ``RDD_PLUGINS``."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(plugins), str(ROOT)]), "RDD_PLUGINS": PLUGINS,
           "WANDB_MODE": "disabled"}
    return subprocess.run([sys.executable, *argv], cwd=cwd, env=env, text=True, capture_output=True, timeout=600)


def test_the_page_holds_every_example():
    assert set(doc_files()) == {"plugins/halves.py", "plugins/conf/decomposer/halves.yaml",
                                "plugins/mean_colour.py", "plugins/conf/encoder/mean_colour.yaml",
                                "plugins/gripper_words.py", "plugins/conf/labeler/gripper_words.yaml",
                                "plugins/lift_block.py"}


def test_decomposer_and_labeler_through_the_cli(plugins, demos, tmp_path):
    out = tmp_path / "halves.json"
    proc = run(plugins, "-m", "rdd", "decompose", "--format", "native", "--data", str(demos), "--decomposer",
               "halves", "--option", "parts=3", "--labeler", "gripper_words", "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    for rec in json.loads(out.read_text())["episodes"]:
        assert rec["segments"] == [[0, 6], [6, 12], [12, 18]]
        assert rec["instructions"] == ["move with the gripper open", "move with the gripper closed",
                                       "move with the gripper open"]
    bad = run(plugins, "-m", "rdd", "decompose", "--format", "native", "--data", str(demos), "--decomposer",
              "halves", "--option", "parts=0", "--out", str(tmp_path / "bad.json"), cwd=tmp_path)
    assert bad.returncode == 2 and "parts" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1, bad.stderr


def test_encoder_through_the_cli(plugins, demos, tmp_path):
    db = tmp_path / "db"
    built = run(plugins, "-m", "rdd", "build-db", "--format", "native", "--data", str(demos), "--exclude", "ep2",
                "--encoder", "mean_colour", "--encoder-option", "grid=4", "--no-cache", "--out", str(db), cwd=tmp_path)
    assert built.returncode == 0, built.stderr
    assert json.loads((db / "manifest.json").read_text())["encoder"] == "mean_colour"
    out = tmp_path / "rdd.json"
    proc = run(plugins, "-m", "rdd", "decompose", "--format", "native", "--data", str(demos), "--include", "ep2",
               "--decomposer", "rdd", "--db", str(db), "--encoder-option", "grid=4", "--no-cache",
               "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    (rec,) = json.loads(out.read_text())["episodes"]
    assert rec["segments"][0][0] == 0 and rec["segments"][-1][1] == 18


def test_task_decomposer_labeler_and_encoder_through_run_py(plugins, tmp_path_factory):
    """One new task, decomposed by the new decomposer (labelled by the new labeler), then by rdd on
    the new encoder, sharing the task's demos through the stage cache."""
    tmp = tmp_path_factory.mktemp("harness")
    common = ["run.py", "experiment=smoke", "mode=decompose", "tasks=[lift_block]", "threads=1",
              f"hydra.searchpath=[file://{plugins / 'conf'}]", f"paths.cache_dir={tmp / 'cache'}"]
    halves = run(plugins, str(ROOT / common[0]), *common[1:], "decomposer=halves", "decomposer.parts=3",
                 "labeler=gripper_words", f"hydra.run.dir={tmp / 'halves'}", cwd=tmp)
    assert halves.returncode == 0, halves.stderr[-3000:]
    data = json.loads((tmp / "halves" / "results.json").read_text())
    assert data["tasks"] == ["lift_block"]
    demos = data["decomposition"]["demos"]
    assert demos and all(len(d["segments"]) == 3 for d in demos), demos
    rdd = run(plugins, str(ROOT / common[0]), *common[1:], "decomposer=rdd", "encoder=mean_colour",
              f"hydra.run.dir={tmp / 'rdd'}", cwd=tmp)
    assert rdd.returncode == 0, rdd.stderr[-3000:]
    assert json.loads((tmp / "rdd" / "results.json").read_text())["config"]["encoder"]["_target_"] == "mean_colour.build"
