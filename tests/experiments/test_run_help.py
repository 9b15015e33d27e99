"""``python run.py --help`` shows what can be chosen, and everything it shows can be chosen."""

import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

ROOT = Path(__file__).resolve().parents[2]


def _help() -> str:
    out = subprocess.run([sys.executable, "run.py", "--help"], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_help_lists_groups_modes_and_tasks_that_compose():
    pytest.importorskip("pybullet")
    import experiments.config.schemas  # noqa: F401  (registers the typed schema)

    text = _help()
    groups = dict(line.strip().split(": ", 1) for line in text.splitlines()
                  if line.startswith("  ") and ": " in line)
    assert "scale" not in groups and "reproduce" not in groups  # not choices: they fail as overrides
    assert {"decomposer", "encoder", "index", "planner", "experiment"} <= set(groups)
    modes = next(line for line in text.splitlines() if line.startswith("mode: ")).split(": ")[1].split(", ")
    assert set(modes) == {"hierarchical", "decompose", "speed", "planner_eval"}
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        for group in ("decomposer", "index", "planner", "experiment"):
            for option in groups[group].split(", "):
                cfg = compose(config_name="config", overrides=[f"{group}={option}"])
                assert cfg is not None
        for mode in modes:
            assert str(compose(config_name="config", overrides=[f"mode={mode}"]).mode).endswith(mode)
    assert "push_buttons" in text and "close_jar" in text
