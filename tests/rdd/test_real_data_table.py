"""The real-data table script (benchmarks/real_data_table.py, issue 44.4) end to end at a tiny size on
the real RLBench and G1 data (``RDD_TEST_DATA``) with the fast ``pixels`` encoder: its structure, facts
that hold whatever the scores (a segmentation against itself scores 1, uniform cuts the stated number
of segments, the median of the training annotation), and its resume, read from its log."""

from __future__ import annotations

import json
import re
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "real_data_table.py"
FAST = ["--encoder", "pixels", "--encoder-option", "size=4"]


@pytest.fixture(scope="module")
def table(benchmark_module):
    return benchmark_module("real_data_table")


def last_run(out: Path) -> dict[str, list[str]]:
    """Step labels by what the latest invocation did with them (run, redo, reuse), from its log."""
    section = (out / "log.txt").read_text().split("\n== ")[-1]
    done: dict[str, list[str]] = {"run": [], "redo": [], "reuse": []}
    for m in re.finditer(r"^(run|redo|reuse)\b.*?\[\d+\] (.+?):", section, flags=re.M):
        done[m.group(1)].append(m.group(2))
    return done


def segments(path: Path) -> dict[str, list[list[int]]]:
    return {r["episode"]: r["segments"] for r in json.loads(path.read_text())["episodes"]}


def test_rlbench_leave_one_out_and_its_resume(table, real_data, tmp_path, monkeypatch):
    data = real_data("rlbench/open_drawer/all_variations/episodes")
    monkeypatch.setenv("RDD_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "table"
    names = ["episode0", "episode1", "episode2"]
    argv = ["--out", str(out), "--only", "rlbench", "--rlbench", str(data), "--rlbench-episodes", *names, *FAST]
    part = table.main(argv)["datasets"]["rlbench"]
    rows = {r["method"]: r["scores"]["rule"] for r in part["rows"]}
    assert list(rows) == ["rdd", "rdd_ood", "uvd", "uniform", "rule"]
    # The rule is the ground truth: scored against itself it is 1 on every metric, and marked so.
    assert all(rows["rule"][k] == 1.0 for k in ("miou", "symmetric_miou", "boundary_f1")) and rows["rule"]["trivial"]
    for label, s in rows.items():
        assert s["num_episodes"] == 3 and 0 <= s["miou"] <= 1 and 0 <= s["boundary_f1"] <= 1, label
        assert s["trivial"] == (label == "rule")
    # uniform's n for a fold is the median segment count of the other episodes' rule segments,
    # and it cuts each held-out episode into exactly that many.
    rule = segments(out / "rlbench" / "rule.json")
    for name in names:
        n = part["uniform_n"][name]
        assert n == int(statistics.median(len(rule[o]) for o in names if o != name) + 0.5)
        assert len(segments(out / "rlbench" / f"uniform_n{n}.json")[name]) == n
    md = (out / "table.md").read_text()
    assert md.count("\n| ") == 1 + 5 and "1.000 (trivial)" in md and "F1 +-5" in md
    assert json.loads((out / "results.json").read_text())["datasets"]["rlbench"]["rows"] == part["rows"]
    first = last_run(out)
    assert len(first["run"]) == 13 and not first["reuse"] and not first["redo"]  # 2 + 3 folds x 3 + uniform + evaluate

    with pytest.raises(ValueError, match="table.md is finished; pass --force"):
        table.main(argv)
    assert table.main([*argv, "--force"])["datasets"]["rlbench"]["rows"] == part["rows"]
    assert last_run(out) == {"run": [], "redo": [], "reuse": first["run"]}  # nothing redone

    # A lost output is made again, and so is what reads it; nothing else.
    (out / "rlbench" / "uvd.json").unlink()
    table.main([*argv, "--force"])
    assert last_run(out)["run"] == ["uvd"] and last_run(out)["redo"] == ["evaluate against rule"]
    # Another rdd setting redoes the rdd decompositions and the scores only.
    table.main([*argv, "--force", "--decompose-opt", "--alpha 0.5"])
    redone = last_run(out)["redo"]
    assert sorted(redone) == sorted([f"{m} {n}" for m in ("rdd", "rdd_ood") for n in names] + ["evaluate against rule"])
    config = json.loads((out / "rlbench" / "rdd_ood_episode1.json").read_text())["config"]
    assert config["alpha"] == 0.5 and config["mode"] == "ood"


def test_command_line_errors_are_one_line(tmp_path):
    res = subprocess.run([sys.executable, str(SCRIPT), "--out", str(tmp_path / "t"), "--only", "g1"], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and res.stderr.strip() == "error: --g1 DIR is needed for the g1 table (or --only rlbench)"
    res = subprocess.run([sys.executable, str(SCRIPT), "--out", str(tmp_path / "t"), "--only", "g1", "--g1",
                          str(tmp_path), "--train", "5-3"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "--train '5-3'" in res.stderr and len(res.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_g1_two_annotations(table, real_data, tmp_path, monkeypatch):
    d1, d2 = real_data("lerobot/unitree_g1_pick_bottle"), real_data("lerobot/unitree_g1_pick_bottle_30")
    monkeypatch.setenv("RDD_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "table"
    argv = ["--out", str(out), "--only", "g1", "--g1", str(d1), "--g1", str(d2), "--train", "16-17", "--test", "36",
            *FAST]
    part = table.main(argv)["datasets"]["g1"]
    assert part["train"] == ["episode_000016", "episode_000017"] and part["test"] == ["episode_000036"]
    rows = {r["method"]: r["scores"] for r in part["rows"]}
    n = sorted(set(part["uniform_n"].values()))
    assert list(rows) == ["rdd@rule", "rdd@hysteresis", "rdd_ood@rule", "rdd_ood@hysteresis", "uvd",
                          *[f"uniform_n{k}" for k in n], "rule"]
    assert rows["rule"]["rule"]["miou"] == 1.0 and rows["rule"]["rule"]["trivial"]
    assert not rows["rule"]["hysteresis"]["trivial"] and not rows["uvd"]["rule"]["trivial"]
    # The hysteresis database holds the annotation script's segments of the training episodes.
    hands = segments(out / "g1" / "hysteresis.json")
    from rdd.database.model import SubtaskDatabase

    db = SubtaskDatabase.load(out / "g1" / "db_hysteresis")
    got = {}
    for ep, s, e in zip(db.episodes, db.starts, db.ends, strict=True):
        got.setdefault(ep, []).append([int(s), int(e)])
    assert got == {ep: hands[ep] for ep in part["train"]}
    assert part["uniform_n"]["hysteresis"] == int(statistics.median(len(hands[e]) for e in part["train"]) + 0.5)
    assert segments(out / "g1" / "gt_hysteresis.json") == {"episode_000036": hands["episode_000036"]}
    table.main([*argv, "--force"])
    assert not last_run(out)["run"] and not last_run(out)["redo"]
    # One more uvd row on the joint state: only its decompositions run, and the scores are redone.
    part = table.main([*argv, "--force", "--uvd-views", "state"])["datasets"]["g1"]
    assert [r["method"] for r in part["rows"]][4:6] == ["uvd", "uvd_state"]
    assert last_run(out)["run"] == ["uvd views state (unitree_g1_pick_bottle_30)"]
    assert sorted(last_run(out)["redo"]) == ["evaluate against gt_hysteresis", "evaluate against gt_rule"]
    done = json.loads((out / "g1" / "uvd_state_unitree_g1_pick_bottle_30.json").read_text())
    assert done["config"]["views"] == ["state"]
