"""Every table of the paper with one command: ``python -m experiments.reproduce [--scale default|paper]``.

A scale is a plan, ``conf/reproduce/<scale>.yaml``: one entry per table, each one Hydra multirun of
``run.py`` (an experiment config plus extra command-line overrides) or several (``sweeps``: e.g.
the paper's demo ablation, M=1 on three disjoint demo sets beside M=3, which is no Cartesian sweep). Tables run one after another;
all of them share the stage cache, so a stage that several tables need (demonstrations, policy,
database, base planner, ...) is built once. A finished table leaves ``DONE.json`` beside its runs
(the command, commit, wall time): a rerun with the same command skips it and does no work; a table
that was interrupted is run again, and its jobs that had finished find every stage in the cache.
Interrupted calls are timed in ``ATTEMPTS.json``, so a finished table's wall time counts every call.
Outputs, under ``--out`` (default ``outputs/reproduce/<scale>``):

- ``runs/<table>/<job>/results.json``: every number, traceable to its seeds, episodes and config;
- ``tables/<table>/<experiment>.{md,tex}`` and PNG plots (``experiments.tables``);
- ``summary.md`` and ``reproduce.json``: all tables, with each table's command and wall time.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from experiments.report.table_format import machine_kind
from experiments.run.job import hardware
from rdd.atomic import write_json_atomic, write_text_atomic

log = logging.getLogger("experiments.reproduce")

REPO_ROOT = Path(__file__).resolve().parents[1]
PLANS_DIR = REPO_ROOT / "conf" / "reproduce"
DONE_FILE = "DONE.json"
ATTEMPTS_FILE = "ATTEMPTS.json"


class PlanError(ValueError):
    """A plan file that cannot be used (missing, malformed, or naming an unknown experiment)."""


@dataclass(frozen=True)
class TablePlan:
    """One table: one or more multiruns of ``experiment``, each with its extra overrides."""

    name: str
    experiment: str
    sweeps: tuple[tuple[str, ...], ...] = ((),)
    description: str = ""

    def sweep_dirs(self, table_dir: Path) -> list[Path]:
        """Where each multirun writes: the table's folder, or ``part<i>`` in it for several."""
        if len(self.sweeps) == 1:
            return [table_dir]
        return [table_dir / f"part{i}" for i in range(len(self.sweeps))]

    def commands(self, table_dir: Path, cache_dir: Path | None) -> list[list[str]]:
        """The ``run.py`` arguments of each of this table's multiruns (the interpreter is prepended to run)."""
        cmds = []
        for overrides, sweep_dir in zip(self.sweeps, self.sweep_dirs(table_dir), strict=True):
            # run.py relative to the repository root (the child's working directory), so the
            # recorded command is the one a reader types.
            cmd = ["run.py", "-m", f"experiment={self.experiment}", *overrides,
                   f"hydra.sweep.dir={sweep_dir}"]
            if cache_dir is not None:
                cmd.append(f"paths.cache_dir={cache_dir}")
            cmds.append(cmd)
        return cmds


@dataclass
class Plan:
    """A scale: its tables in the order they run."""

    scale: str
    tables: list[TablePlan] = field(default_factory=list)


def available_scales() -> list[str]:
    """Names of the plans in ``conf/reproduce``."""
    return sorted(p.stem for p in PLANS_DIR.glob("*.yaml"))


def load_plan(path: Path) -> Plan:
    """Read and validate a plan file (``tables: {name: {experiment, overrides, description}}``)."""
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text())
    except FileNotFoundError as exc:
        raise PlanError(f"plan {path}: no such file (scales: {available_scales()})") from exc
    except yaml.YAMLError as exc:
        raise PlanError(f"plan {path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict) or not isinstance(data.get("tables"), dict) or not data["tables"]:
        raise PlanError(f"plan {path}: expected a non-empty mapping under 'tables'")
    experiments = {p.stem for p in (REPO_ROOT / "conf" / "experiment").glob("*.yaml")}
    tables = []
    for name, entry in data["tables"].items():
        where = f"plan {path}: tables.{name}"
        if not isinstance(entry, dict):
            raise PlanError(f"{where}: expected a mapping with 'experiment'")
        unknown = set(entry) - {"experiment", "overrides", "sweeps", "description"}
        if unknown:
            raise PlanError(f"{where}: unknown key(s) {sorted(unknown)} "
                            "(allowed: experiment, overrides, sweeps, description)")
        exp = entry.get("experiment")
        if exp not in experiments:
            raise PlanError(f"{where}.experiment: {exp!r} is not in conf/experiment ({sorted(experiments)})")
        if "overrides" in entry and "sweeps" in entry:
            raise PlanError(f"{where}: give 'overrides' (one multirun) or 'sweeps' (several), not both")
        if "sweeps" in entry:
            sweeps, field_name = entry["sweeps"], "sweeps"
            if not isinstance(sweeps, list) or not sweeps:
                raise PlanError(f"{where}.sweeps: expected a non-empty list of override lists")
        else:
            sweeps, field_name = [entry.get("overrides") or []], "overrides"
        for i, overrides in enumerate(sweeps):
            at = f"{where}.{field_name}" + (f"[{i}]" if field_name == "sweeps" else "")
            if not isinstance(overrides, list) or not all(isinstance(o, str) for o in overrides):
                raise PlanError(f"{at}: expected a list of strings")
            for o in overrides:
                if o.startswith(("hydra.sweep.dir", "paths.cache_dir", "experiment=")):
                    raise PlanError(f"{at}: {o!r} is set by the driver")
        tables.append(TablePlan(str(name), exp, tuple(tuple(o) for o in sweeps),
                                str(entry.get("description", ""))))
    return Plan(Path(path).stem, tables)


def _commit() -> str:
    try:
        out = subprocess.run(["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"], capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO_ROOT), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return out + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _done(table_dir: Path, commands: list[list[str]]) -> dict[str, Any] | None:
    """The finished-table record if these commands already completed here."""
    path = table_dir / DONE_FILE
    try:
        data = json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None
    return data if data.get("commands") == commands else None


def run_table(table: TablePlan, out: Path, cache_dir: Path | None, force: bool = False) -> dict[str, Any]:
    """Run one table's multirun (unless already done), then write its tables; its record."""
    from experiments.tables import write_tables

    table_dir = out / "runs" / table.name
    commands = table.commands(table_dir, cache_dir)
    record = None if force else _done(table_dir, commands)
    if record is not None:
        log.info("%s: already done (%.0f s when it ran); skipped", table.name, record["seconds"])
        return {**record, "reused": True}
    log_path = out / "logs" / f"{table.name}.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    table_dir.mkdir(parents=True, exist_ok=True)
    commit = _commit()  # the code the table starts from (a commit landing mid-run is not its code)
    earlier = _earlier_attempts(table_dir / ATTEMPTS_FILE, log_path)
    # trained stages round differently on another CPU: each call says which machine made it
    machine = machine_kind(hardware()) or "unknown"
    attempt: dict[str, Any] = {"commit": commit, "machine": machine, "started": time.time(), "seconds": None}
    write_json_atomic(table_dir / ATTEMPTS_FILE, [*earlier, attempt])
    start = time.perf_counter()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")])}
    try:
        for command in commands:
            log.info("%s: running %s (log: %s)", table.name, shlex.join(command), log_path)
            with open(log_path, "a") as fh:
                fh.write(f"\n$ python {shlex.join(command)}\n")
                fh.flush()
                proc = _run_group([sys.executable, *command], cwd=REPO_ROOT, stdout=fh, env=env)
            if proc.returncode != 0:
                raise RuntimeError(f"table {table.name}: run.py exited with {proc.returncode} after "
                                   f"{time.perf_counter() - start:.0f} s; see {log_path}")
    except BaseException as exc:
        attempt.update(seconds=time.perf_counter() - start,
                       ended="interrupted" if isinstance(exc, KeyboardInterrupt) else "failed")
        write_json_atomic(table_dir / ATTEMPTS_FILE, [*earlier, attempt])
        raise
    seconds = time.perf_counter() - start
    _md, written = write_tables(table_dir, out / "tables" / table.name)
    record = {"table": table.name, "experiment": table.experiment, "commands": commands,
              "commit": commit, "machine": machine, "seconds": seconds,
              "seconds_all_calls": seconds + sum(a["seconds"] for a in earlier),
              "earlier_calls": earlier, "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
              "outputs": [str(p.relative_to(out)) for p in written]}
    write_json_atomic(table_dir / DONE_FILE, record)
    (table_dir / ATTEMPTS_FILE).unlink(missing_ok=True)
    log.info("%s: done in %.0f s", table.name, seconds)
    return {**record, "reused": False}


def _earlier_attempts(path: Path, log_path: Path) -> list[dict[str, Any]]:
    """This table's earlier calls that did not finish, each with its wall time; a call killed
    without a word (SIGKILL, power loss) is timed to the last write to the table's log."""
    try:
        attempts = json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return []
    for a in attempts:
        if a.get("seconds") is None:
            try:
                last = log_path.stat().st_mtime
            except FileNotFoundError:
                last = a["started"]
            a.update(seconds=max(0.0, last - a["started"]), ended="killed (timed to its log's last write)")
    return attempts


def _run_group(cmd: list[str], **popen) -> subprocess.CompletedProcess:
    """``cmd`` in a process group of its own, which goes down with the driver: stopping the driver
    (Ctrl-C, SIGTERM) also stops run.py's sweep workers, which would otherwise keep writing into
    the stage cache."""
    proc = subprocess.Popen(cmd, stderr=subprocess.STDOUT, start_new_session=True, **popen)
    try:
        return subprocess.CompletedProcess(cmd, proc.wait())
    except BaseException:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=10)
            time.sleep(0.5)
            os.killpg(proc.pid, signal.SIGKILL)  # whatever of the group is still there
        proc.wait()
        raise


def _terminate(signum: int, _frame: Any) -> None:
    """SIGTERM as an interruption, so the running table's process group is stopped too."""
    raise KeyboardInterrupt(f"signal {signum}")


def _all_calls(record: dict[str, Any]) -> float:
    """A table's wall time over every call that worked on it (records of older drivers: the last)."""
    return record.get("seconds_all_calls", record["seconds"])


def _machines(record: dict[str, Any]) -> str:
    """The machines of a table's calls, earlier ones first ("not recorded" for older drivers')."""
    calls = [*record.get("earlier_calls", []), record]
    return "; ".join(dict.fromkeys(c.get("machine") or "not recorded" for c in calls))


def summary_markdown(plan: Plan, records: Sequence[dict[str, Any]], out: Path) -> str:
    """All tables of a plan in one Markdown page, each with its command and wall time."""
    lines = [f"# Reproduction at scale `{plan.scale}`", "",
             "| table | experiment | wall time (min) | calls | commit | machine |", "|---|---|--:|--:|---|---|"]
    for r in records:
        lines.append(f"| {r['table']} | {r['experiment']} | {_all_calls(r) / 60:.1f} | "
                     f"{1 + len(r.get('earlier_calls', []))} | {r['commit'][:12]} | {_machines(r)} |")
    total = sum(_all_calls(r) for r in records)
    lines += ["", f"Total wall time of the runs: {total / 60:.1f} min.", ""]
    for table, r in zip(plan.tables, records, strict=True):
        lines += [f"## {table.name}", ""]
        if table.description:
            lines += [table.description, ""]
        lines += ["```", *("python " + shlex.join(c) for c in r["commands"]), "```", ""]
        for md in sorted((out / "tables" / table.name).glob("*.md")):
            lines.append(md.read_text())
        for png in sorted((out / "tables" / table.name).glob("*.png")):
            lines.append(f"![{png.stem}]({png.relative_to(out)})\n")
    return "\n".join(lines)


def reproduce(plan: Plan, out: Path, cache_dir: Path | None = None, only: Sequence[str] = (),
              force: bool = False) -> list[dict[str, Any]]:
    """Run every table of ``plan`` (or those in ``only``) and write the summary; the records."""
    names = [t.name for t in plan.tables]
    unknown = [n for n in only if n not in names]
    if unknown:
        raise PlanError(f"--only {unknown}: not in the {plan.scale} plan ({names})")
    tables = [t for t in plan.tables if not only or t.name in only]
    from tqdm import tqdm

    records = []
    bar = tqdm(tables, desc=f"reproduce ({plan.scale})", unit="table", disable=None)
    for table in bar:
        bar.set_postfix_str(table.name)
        records.append(run_table(table, out, cache_dir, force=force))
    sub = Plan(plan.scale, tables)
    write_text_atomic(out / "summary.md", summary_markdown(sub, records, out))
    write_json_atomic(out / "reproduce.json", {"scale": plan.scale, "tables": records})
    return records


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point."""
    parser = argparse.ArgumentParser(prog="python -m experiments.reproduce", description=__doc__.split("\n")[0])
    parser.add_argument("--scale", default="default",
                        help=f"plan in conf/reproduce ({', '.join(available_scales())}); default: default")
    parser.add_argument("--plan", type=Path, default=None, help="a plan file instead of --scale")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default outputs/reproduce/<scale>)")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="stage cache shared by every table (default: run.py's, $RDD_CACHE_DIR or .cache/rdd)")
    parser.add_argument("--only", nargs="+", default=(), metavar="TABLE", help="run these tables only")
    parser.add_argument("--force", action="store_true", help="rerun tables already marked done")
    parser.add_argument("--dry-run", action="store_true", help="print the commands and exit")
    parser.add_argument("-v", "--verbose", action="store_true", help="full tracebacks")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    signal.signal(signal.SIGTERM, _terminate)
    try:
        plan = load_plan(args.plan or PLANS_DIR / f"{args.scale}.yaml")
        out = (args.out or REPO_ROOT / "outputs" / "reproduce" / plan.scale).resolve()
        cache = args.cache_dir.resolve() if args.cache_dir else None
        if args.dry_run:
            for t in plan.tables:
                if not args.only or t.name in args.only:
                    for cmd in t.commands(out / "runs" / t.name, cache):
                        print(shlex.join(["python", *cmd]))
            return 0
        records = reproduce(plan, out, cache, only=args.only, force=args.force)
    except (PlanError, RuntimeError, FileNotFoundError, ValueError) as exc:
        if args.verbose:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: finished tables are kept; rerun the same command to resume", file=sys.stderr)
        return 130
    total = sum(r["seconds"] for r in records if not r["reused"])
    print(f"{len(records)} table(s) in {out} ({total / 60:.1f} min of new runs); summary: {out / 'summary.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
