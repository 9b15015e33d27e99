"""The package root is the library's API: its names, what importing it costs, and the README's example."""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import rdd

ROOT = Path(__file__).resolve().parents[2]
# Public name -> the module that defines it (written out here, not read from rdd).
HOMES = {
    "SubtaskDatabase": "rdd.database.model", "RDDDecomposer": "rdd.decomposers.rdd",
    "UVDDecomposer": "rdd.decomposers.uvd", "UniformDecomposer": "rdd.decomposers.uniform",
    "ExpertDecomposer": "rdd.decomposers.expert", "VLMDecomposer": "rdd.decomposers.vlm",
    "Decomposer": "rdd.decomposers.base", "Decomposition": "rdd.decomposers.base",
    "Encoder": "rdd.encoders.base", "load_encoder": "rdd.encoders",
    "available_encoders": "rdd.encoders", "Episode": "rdd.data.episode",
    "load_episodes": "rdd.data.load", "episode_names": "rdd.data.load", "evaluate": "rdd.metrics",
}
README_PATH = "path/to/open_drawer/all_variations/episodes"


def test_root_names_are_the_library_objects():
    assert sorted(rdd.__all__) == sorted(HOMES)
    for name, home in HOMES.items():
        assert getattr(rdd, name).__module__ == home, name
    from rdd.metrics import evaluate_segmentation

    assert rdd.evaluate is evaluate_segmentation


def test_import_rdd_loads_neither_torch_nor_the_harness():
    code = "import json, sys, rdd; print(json.dumps(sorted(m.split('.')[0] for m in sys.modules)))"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    loaded = set(json.loads(out.stdout))
    assert loaded.isdisjoint({"torch", "envs", "policy", "planner", "experiments", "hydra", "pybullet"})


def _readme_example() -> str:
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## The library"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_example_is_the_package_docstring():
    lines = [line.strip() for line in rdd.__doc__.splitlines() if line.startswith("    ")]
    assert "\n".join(lines) + "\n" == _readme_example()


def test_readme_example_runs_as_printed(real_data, tmp_path: Path):
    episodes = real_data("rlbench/open_drawer/all_variations/episodes")
    example = _readme_example()
    assert len(example.splitlines()) == 6 and README_PATH in example  # import rdd + five lines
    script = tmp_path / "example.py"
    script.write_text(example.replace(README_PATH, str(episodes))
                      + "print(repr(new.num_frames), repr(found.segments))\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "RDD_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed, last = proc.stdout.strip().splitlines()
    num_frames, segments = (ast.literal_eval(part) for part in last.split(" ", 1))
    # a partition of the new episode, and its mIoU against the expert rule in (0, 1]
    assert segments[0][0] == 0 and segments[-1][1] == num_frames
    assert all(start < end for start, end in segments)
    assert all(a[1] == b[0] for a, b in zip(segments, segments[1:], strict=False))
    assert printed.startswith(repr(segments))
    assert 0 < float(printed.rsplit(" ", 1)[1]) <= 1
