"""The reproduce driver: plan validation, and at smoke scale two tables, a kill, a resume, a no-op rerun."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from experiments.reproduce import PLANS_DIR, PlanError, available_scales, load_plan, main

ROOT = Path(__file__).resolve().parents[2]


def test_shipped_plans_load_and_name_real_experiments():
    assert {"default", "paper", "smoke"} <= set(available_scales())
    for scale in available_scales():
        plan = load_plan(PLANS_DIR / f"{scale}.yaml")
        assert plan.tables, scale
    default = [t.name for t in load_plan(PLANS_DIR / "default.yaml").tables]
    assert default[0] == "table_main"
    assert {"abl_alpha", "abl_encoder", "abl_demos", "abl_ood_beta", "abl_backend"} <= set(default)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("tables: {}", "non-empty mapping under 'tables'"),
        ("tables: {a: {experiment: no_such}}", "tables.a.experiment: 'no_such' is not in conf/experiment"),
        ("tables: {a: {experiment: smoke, sweep: 1}}", "tables.a: unknown key(s) ['sweep']"),
        ("tables: {a: {experiment: smoke, overrides: [], sweeps: [[]]}}", "not both"),
        ("tables: {a: {experiment: smoke, sweeps: []}}", "tables.a.sweeps: expected a non-empty list"),
        ("tables: {a: {experiment: smoke, sweeps: [[seed=1], seed=2]}}", "tables.a.sweeps[1]: expected a list"),
        ("tables: {a: {experiment: smoke, overrides: [paths.cache_dir=/x]}}", "set by the driver"),
        ("tables: {a: {experiment: smoke, overrides: seed=1}}", "tables.a.overrides: expected a list"),
        ("tables: [", "not valid YAML"),
    ],
)
def test_bad_plans_fail_with_the_key_at_fault(tmp_path: Path, text: str, message: str):
    plan = tmp_path / "p.yaml"
    plan.write_text(text)
    with pytest.raises(PlanError, match=r".*".join(map(__import__("re").escape, [str(plan), message]))):
        load_plan(plan)


def test_cli_errors_are_one_line(tmp_path: Path, capsys):
    assert main(["--scale", "nope"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "nope.yaml" in err and "scales:" in err
    assert main(["--scale", "smoke", "--only", "missing", "--out", str(tmp_path)]) == 2
    assert "missing" in capsys.readouterr().err


def test_several_sweeps_share_one_table_folder(tmp_path: Path):
    plan = tmp_path / "p.yaml"
    plan.write_text("tables: {demos: {experiment: abl_demos, sweeps: "
                    "[[decomposer=rdd], [data.val_episodes_per_task=1, 'data.val_first_episode=0,1,2']]}}")
    (table,) = load_plan(plan).tables
    cmds = table.commands(tmp_path / "runs" / "demos", None)
    assert [c[-1] for c in cmds] == [f"hydra.sweep.dir={tmp_path}/runs/demos/part0",
                                     f"hydra.sweep.dir={tmp_path}/runs/demos/part1"]
    assert cmds[1][2:5] == ["experiment=abl_demos", "data.val_episodes_per_task=1", "data.val_first_episode=0,1,2"]
    paper = {t.name: t for t in load_plan(PLANS_DIR / "default.yaml").tables}["abl_demos"]
    assert len(paper.sweeps) == 2


def test_dry_run_prints_one_multirun_per_table(capsys):
    assert main(["--scale", "smoke", "--dry-run", "--out", "/x", "--cache-dir", "/c"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2
    assert "-m experiment=smoke decomposer=expert,uniform seed=0" in lines[0]
    assert lines[1].endswith("hydra.sweep.dir=/x/runs/smoke_uniform paths.cache_dir=/c")


def _driver(out: Path, cache: Path) -> subprocess.Popen:
    env = {**os.environ, "WANDB_MODE": "disabled", "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "experiments.reproduce", "--scale", "smoke", "--out", str(out),
         "--cache-dir", str(cache)],
        cwd=ROOT, env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        start_new_session=True,  # its own process group, so the kill reaches run.py and its workers
    )


@pytest.mark.slow
def test_two_tables_killed_then_resumed_then_no_work(tmp_path: Path):
    out, cache = tmp_path / "out", tmp_path / "cache"
    first = _driver(out, cache)
    done_main = out / "runs" / "smoke_main" / "DONE.json"
    deadline = time.time() + 1500
    while not done_main.exists() and first.poll() is None and time.time() < deadline:
        time.sleep(0.2)
    assert done_main.exists(), first.communicate()[0][-3000:]
    os.killpg(first.pid, signal.SIGKILL)  # killed while the second table runs (or just before)
    first.wait()
    assert not (out / "runs" / "smoke_uniform" / "DONE.json").exists()

    second = _driver(out, cache)
    text = second.communicate(timeout=1500)[0]
    assert second.returncode == 0, text[-3000:]
    records = {r["table"]: r for r in json.loads((out / "reproduce.json").read_text())["tables"]}
    assert records["smoke_main"]["reused"] and not records["smoke_uniform"]["reused"]
    summary = (out / "summary.md").read_text()
    assert "## smoke_main" in summary and "## smoke_uniform" in summary
    # each table's runs: smoke_main has expert and uniform, smoke_uniform has n_segments 2 and 3
    main_md = next((out / "tables" / "smoke_main").glob("*.md")).read_text()
    assert "| expert" in main_md.replace("**", "") and "| uniform" in main_md.replace("**", "")
    abl_md = next((out / "tables" / "smoke_uniform").glob("*.md")).read_text()
    assert "n_segments=2" in abl_md and "n_segments=3" in abl_md
    assert (out / "tables" / "smoke_main").glob("*.tex")

    before = {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("results.json")}
    third = _driver(out, cache)
    text = third.communicate(timeout=300)[0]
    assert third.returncode == 0, text[-3000:]
    records = json.loads((out / "reproduce.json").read_text())["tables"]
    assert all(r["reused"] for r in records)
    assert {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("results.json")} == before


def _sweep_pgid(out: Path) -> int | None:
    """Process group of the run.py sweep writing under ``out``, if one runs."""
    for cmd in Path("/proc").glob("[0-9]*/cmdline"):
        with contextlib.suppress(OSError):
            text = cmd.read_bytes().replace(b"\0", b" ").decode()
            if "run.py" in text and str(out) in text:
                return os.getpgid(int(cmd.parent.name))
    return None


def test_a_terminated_driver_takes_its_sweep_with_it(tmp_path: Path, processes):
    out, cache = tmp_path / "out", tmp_path / "cache"
    driver = _driver(out, cache)
    deadline = time.time() + 120
    while (pgid := _sweep_pgid(out)) is None and time.time() < deadline:
        time.sleep(0.2)
    assert pgid is not None and pgid != os.getpgid(driver.pid)  # the sweep leads a group of its own
    time.sleep(3)  # let the sweep start its workers
    driver.send_signal(signal.SIGTERM)  # the driver alone, as `kill PID` does
    text = driver.communicate(timeout=120)[0]
    assert driver.returncode == 130, text[-2000:]
    assert "rerun the same command to resume" in text
    deadline = time.time() + 30
    def members() -> list[int]:
        return [pid for pid, _, group in processes() if group == pgid]

    while members() and time.time() < deadline:
        time.sleep(0.2)
    assert members() == []


def test_a_resumed_table_counts_the_wall_time_of_every_call(tmp_path: Path, monkeypatch):
    import experiments.reproduce as reproduce
    import experiments.tables

    table = reproduce.TablePlan("t", "smoke")
    out = tmp_path / "out"
    table_dir = out / "runs" / "t"
    log_path = out / "logs" / "t.log"
    # a call killed without a word (SIGKILL): started at t0, its log last written 100 s later
    t0 = time.time() - 1000
    table_dir.mkdir(parents=True)
    log_path.parent.mkdir(parents=True)
    (table_dir / "ATTEMPTS.json").write_text(json.dumps([{"commit": "a", "started": t0, "seconds": None}]))
    log_path.write_text("killed call's output\n")
    os.utime(log_path, (t0 + 100, t0 + 100))

    def interrupted(cmd, **popen):
        time.sleep(0.3)
        raise KeyboardInterrupt

    monkeypatch.setattr(reproduce, "_run_group", interrupted)
    # the calls after the killed one (whose older driver recorded no machine) run on this "machine"
    monkeypatch.setattr(reproduce, "hardware", lambda: {"cpu_model": "Test CPU", "torch_cpu_capability": "AVX2"})
    with pytest.raises(KeyboardInterrupt):
        reproduce.run_table(table, out, None)
    attempts = json.loads((table_dir / "ATTEMPTS.json").read_text())
    assert [a["ended"] for a in attempts] == ["killed (timed to its log's last write)", "interrupted"]
    assert attempts[0]["seconds"] == pytest.approx(100, abs=0.01)
    assert 0.3 <= attempts[1]["seconds"] < 5

    monkeypatch.setattr(reproduce, "_run_group", lambda cmd, **popen: subprocess.CompletedProcess(cmd, 0))
    monkeypatch.setattr(experiments.tables, "write_tables", lambda runs, dest: ("", []))
    record = reproduce.run_table(table, out, None)
    assert record["seconds"] < 5 and len(record["earlier_calls"]) == 2
    assert record["seconds_all_calls"] == pytest.approx(
        100 + attempts[1]["seconds"] + record["seconds"], abs=0.01)
    assert not (table_dir / "ATTEMPTS.json").exists()
    assert json.loads((table_dir / "DONE.json").read_text())["seconds_all_calls"] == record["seconds_all_calls"]
    summary = reproduce.summary_markdown(reproduce.Plan("s", [table]), [record], out)
    assert f"| t | smoke | {record['seconds_all_calls'] / 60:.1f} | 3 |" in summary
    assert summary.splitlines()[4].endswith("| not recorded; Test CPU (AVX2) |")
