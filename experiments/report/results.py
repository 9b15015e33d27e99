"""The ``results.json`` every run writes, and reading a tree of them back.

Per episode ``{task, seed, success, steps, instructions}``; per task success rates and their
average; decomposition mIoU against the expert on the validation demonstrations; stage timings; the
resolved config. Every table cell is computed from these files, so it traces back to seeds and
episodes.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

RESULTS_FILE = "results.json"
RESULTS_FORMAT = "rdd-results/1"


@dataclass
class EpisodeResult:
    """One closed-loop evaluation episode."""

    task: str
    seed: int
    success: bool
    steps: int
    instructions: list[str] = field(default_factory=list)
    failure: str | None = None  # why it stopped without success (step limit, motion failure, ...)

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "task": self.task,
            "seed": int(self.seed),
            "success": bool(self.success),
            "steps": int(self.steps),
            "instructions": list(self.instructions),
            "failure": self.failure,
        }


def per_task_success(episodes: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """``{task: {success_rate, episodes, successes}}`` in task order of first appearance."""
    out: dict[str, dict[str, float]] = {}
    for ep in episodes:
        row = out.setdefault(ep["task"], {"episodes": 0, "successes": 0})
        row["episodes"] += 1
        row["successes"] += int(bool(ep["success"]))
    for row in out.values():
        row["success_rate"] = row["successes"] / row["episodes"]
    return out


def average_success(per_task: dict[str, dict[str, float]]) -> float | None:
    """Mean of the per-task success rates (each task weighs the same, as in the paper)."""
    if not per_task:
        return None
    return sum(r["success_rate"] for r in per_task.values()) / len(per_task)


@dataclass
class RunRecord:
    """One results.json with the fields tables need."""

    path: Path
    data: dict[str, Any]

    @property
    def status(self) -> str:
        """``ok``, ``skipped`` or ``failed``."""
        return str(self.data.get("status", "ok"))

    @property
    def experiment(self) -> str:
        """The experiment config the run used (``quick``, ``table_main``, ...)."""
        return str(self.data.get("choices", {}).get("experiment") or "none")

    @property
    def seed(self) -> int:
        """The run's seed."""
        return int(self.data.get("seed", 0))

    @property
    def method(self) -> str:
        """Label of the variant this run measures (set by ``assign_labels``, else its decomposer)."""
        return str(self.data.get("_label") or self.data.get("choices", {}).get("decomposer", "run"))


IGNORED_KEYS = ("seed", "experiment", "paths.", "wandb.", "hydra.", "print_table", "threads")


def _plain_number(value: str) -> str:
    """A number written one way (``1.0`` and ``1`` -> ``1``, ``0.10`` -> ``0.1``); else ``value``."""
    try:
        number = float(value)
    except ValueError:
        return value
    if not math.isfinite(number):
        return value
    text = repr(number)
    return text[:-2] if text.endswith(".0") else text


def _parse_overrides(overrides: Iterable[str]) -> dict[str, str]:
    out = {}
    for ov in overrides:
        key, _, value = str(ov).lstrip("+~").partition("=")
        if not key.startswith(IGNORED_KEYS):
            out[key] = _plain_number(value)
    return out


def assign_labels(runs: Sequence[RunRecord]) -> None:
    """Label each run by the overrides that vary across ``runs`` (seed excluded).

    A sweep ``decomposer=rdd,uvd seed=0,1`` gives labels ``rdd`` / ``uvd``; an alpha sweep gives
    ``alpha=0.5``; runs that differ in nothing but the seed fall back to their decomposer.
    """
    parsed = [_parse_overrides(r.data.get("overrides", [])) for r in runs]
    keys = sorted({k for p in parsed for k in p})
    varying = [k for k in keys if len({p.get(k) for p in parsed}) > 1]
    for run, p in zip(runs, parsed, strict=True):
        run.data["_label"] = method_label([f"{k}={p[k]}" for k in varying if k in p],
                                          run.data.get("choices", {}))


# Short names of swept settings in labels (the paper's symbols where it has one).
LABEL_NAMES = {"data.val_episodes_per_task": "M", "data.val_first_episode": "first demo"}


def method_label(overrides: Iterable[str], choices: dict[str, Any]) -> str:
    """``["decomposer=rdd", "decomposer.alpha=0.5"]`` -> ``rdd, alpha=0.5``; else the decomposer.

    Group choices come first, then settings (``data.val_episodes_per_task=1`` reads ``M=1``).
    """
    parsed = _parse_overrides(overrides)
    parts = [value for key, value in parsed.items() if "." not in key]
    for key, value in parsed.items():
        if "." in key:
            parts.append(f"{LABEL_NAMES.get(key, key.rsplit('.', 1)[-1])}={value}")
    if parts:
        return ", ".join(parts)
    if choices.get("planner") == "oracle":
        return "oracle"  # nothing is decomposed: the planner plays back the expert's instructions
    return str(choices.get("decomposer", "run"))


def load_runs(root: Path) -> list[RunRecord]:
    """Every results.json below ``root`` (sorted by path), with a clear error for a corrupt one."""
    root = Path(root)
    if not root.exists():
        raise FileNotFoundError(f"--runs {root}: no such directory")
    runs = []
    for path in sorted(root.rglob(RESULTS_FILE)):
        try:
            with open(path) as fh:
                data = json.load(fh)
        except json.JSONDecodeError as exc:
            raise ValueError(f"corrupt results file {path}: {exc}") from exc
        if not isinstance(data, dict) or data.get("format") != RESULTS_FORMAT:
            raise ValueError(f"{path}: not a results file of format {RESULTS_FORMAT!r}")
        runs.append(RunRecord(path, data))
    return runs
