"""Resumable steps of ``benchmarks/real_data_table.py``: each writes one output, reused while its
command (and the records of the steps it reads) stay the same.

Beside each output ``X`` a step keeps ``.X.cmd``, its signature (the command and its inputs'
signatures) and when it was made, written only after the step succeeded. A rerun reuses an output whose signature
matches; one that is missing, unfinished or made another way is made again, as is everything that
reads it. Commands run as subprocesses (``python -m rdd ...``), their output going to the log file;
the terminal gets one line per step.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rdd.atomic import write_json_atomic, write_text_atomic
from rdd.errors import InputError

ROOT = Path(__file__).resolve().parents[1]


class StepError(RuntimeError):
    """A step's command failed (its output is in the log)."""


class Steps:
    """Runs or reuses steps under ``out``, logging to ``log_path``; keeps every step's command."""

    def __init__(self, out: Path, log_path: Path, echo: Callable[[str], None] = print) -> None:
        self.out, self.log_path, self.echo = out, log_path, echo
        self.count = 0
        self.commands: dict[str, list[str]] = {}  # section -> commands shown in the table
        self.log_path.parent.mkdir(parents=True, exist_ok=True)

    def log(self, line: str) -> None:
        """Append one line to the log file."""
        with self.log_path.open("a") as fh:
            fh.write(line.rstrip("\n") + "\n")

    def signature(self, output: Path) -> Any:
        """The recorded signature of a finished step's ``output`` (None: not finished)."""
        record = _record(output)
        return json.loads(record.read_text()) if output.exists() and record.is_file() else None

    def step(self, section: str, label: str, output: Path, shown: Sequence[str], action: Callable[[], None],
             deps: Sequence[Path] = (), clear: Sequence[Path] = ()) -> Path:
        """Make ``output`` with ``action()`` unless it exists with the same signature (``shown``, the
        command or, starting with ``#``, what this script does, and the signatures of ``deps``);
        ``clear``: paths a fresh attempt removes first."""
        self.count += 1
        shown = [str(a) for a in shown]
        self.commands.setdefault(section, []).append(_shown(shown))
        inputs = [self.signature(d) for d in deps]
        unfinished = [str(d) for d, s in zip(deps, inputs, strict=True) if s is None]
        if unfinished:
            raise StepError(f"{label}: input steps are unfinished: {unfinished}")
        sig = {"command": shown, "inputs": inputs}
        where = output.relative_to(self.out) if output.is_relative_to(self.out) else output
        done = self.signature(output)
        if done is not None and {k: done.get(k) for k in sig} == sig:
            self.log(f"reuse [{self.count}] {label}: {where}")
            self.echo(f"[{self.count}] {section} {label}: reused {where}")
            return output
        state = "redo (made another way)" if output.exists() else "run"
        for path in (output, _record(output), *clear):
            _remove(path)
        self.log(f"{state} [{self.count}] {label}: {_shown(shown)}")
        start = time.monotonic()
        action()
        if not output.exists():
            raise StepError(f"{label}: finished without writing {output}; see {self.log_path}")
        # When it was made: a step that reads it is redone after it is remade, whatever it holds.
        write_text_atomic(_record(output), json.dumps({**sig, "made": time.time_ns()}))
        wall = time.monotonic() - start
        self.log(f"done [{self.count}] {label} in {wall:.1f} s")
        self.echo(f"[{self.count}] {section} {label}: {where} in {wall:.1f} s")
        return output

    def cli(self, section: str, label: str, output: Path, argv: Sequence[Any], deps: Sequence[Path] = ()) -> Path:
        """A ``python -m rdd ARGV`` step."""
        argv = [str(a) for a in argv]
        return self.step(section, label, output, ["python", "-m", "rdd", *argv],
                         lambda: self.run([sys.executable, "-m", "rdd", *argv], label), deps)

    def script(self, section: str, label: str, output: Path, script: str, argv: Sequence[Any],
               clear: Sequence[Path] = ()) -> Path:
        """A ``python benchmarks/SCRIPT ARGV`` step (``clear``: the other paths it writes)."""
        argv = [str(a) for a in argv]
        return self.step(section, label, output, ["python", f"benchmarks/{script}", *argv],
                         lambda: self.run([sys.executable, str(ROOT / "benchmarks" / script), *argv], label),
                         clear=clear)

    def run(self, cmd: Sequence[str], label: str) -> None:
        """Run ``cmd`` from the checkout, its stdout and stderr appended to the log."""
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
        with self.log_path.open("a") as fh:
            status = subprocess.run(list(cmd), cwd=ROOT, env=env, stdout=fh, stderr=subprocess.STDOUT).returncode
        if status != 0:
            tail = self.log_path.read_text().rstrip().splitlines()[-1:]
            raise StepError(f"{label}: exit {status} ({tail[0] if tail else 'no output'}); see {self.log_path}")


def _shown(shown: Sequence[str]) -> str:
    """A command as a shell line; a step done in this script (``shown`` starts with ``#``) as a comment."""
    return " ".join(shown) if shown and shown[0] == "#" else shlex.join(shown)


def _record(output: Path) -> Path:
    return output.parent / f".{output.name}.cmd"


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


def read_records(path: Path) -> list[dict[str, Any]]:
    """The episode records of a ``decompose``-style JSON."""
    return json.loads(path.read_text())["episodes"]


def write_records(path: Path, records: Sequence[dict[str, Any]], config: dict[str, Any]) -> None:
    """A ``decompose``-style JSON of ``records`` (atomically)."""
    write_json_atomic(path, {"config": config, "episodes": list(records)})


def segment_counts(db: Path) -> list[int]:
    """Sub-tasks per episode of a saved database (its training annotation)."""
    from collections import Counter

    from rdd.database.model import SubtaskDatabase

    return sorted(Counter(SubtaskDatabase.load(db).episodes).values())


def median_count(counts: Sequence[int]) -> int:
    """The median of ``counts``, a half rounded up (uniform's n_segments)."""
    return int(statistics.median(counts) + 0.5)


def means(eval_json: Path) -> dict[str, dict[str, float]]:
    """Method label -> mean metrics (and episode count) of an ``evaluate --out`` file."""
    data = json.loads(eval_json.read_text())
    return {label: {**m["mean"], "num_episodes": m["num_episodes"]} for label, m in data["methods"].items()}


def index_list(text: str, option: str) -> list[int]:
    """``"16-35,1,2"`` -> [16, ..., 35, 1, 2]; a bad item is a one-line error naming ``option``."""
    out: list[int] = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        lo, sep, hi = item.partition("-")
        if not lo.isdigit() or (sep and not hi.isdigit()) or (sep and int(hi) < int(lo)):
            raise InputError(f"{option} {text!r}: item {item!r} is not N or FIRST-LAST")
        out += list(range(int(lo), int(hi if sep else lo) + 1))
    if not out or len(set(out)) != len(out):
        raise InputError(f"{option} {text!r}: expected distinct episode indices, e.g. 16-35 or 36-45,1,2")
    return out
