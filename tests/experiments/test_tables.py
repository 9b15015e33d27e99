"""Tables from synthetic results.json files whose expected cells are worked out by hand."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.report.results import RESULTS_FORMAT, per_task_success
from experiments.report.table_builders import average_ranks
from experiments.tables import main, write_tables


def _write_run(root: Path, name: str, method: str, seed: int, success: dict[str, list[bool]],
               experiment: str = "table_main", miou: dict[str, float] | None = None,
               status: str = "ok", reason: str = "") -> None:
    episodes = [
        {"task": task, "seed": i, "success": s, "steps": 3, "instructions": ["a", "b"]}
        for task, outcomes in success.items() for i, s in enumerate(outcomes)
    ]
    data = {
        "format": RESULTS_FORMAT,
        "status": status,
        "reason": reason,
        "seed": seed,
        "choices": {"experiment": experiment, "decomposer": method},
        "overrides": [f"decomposer={method}", f"seed={seed}"],
        "episodes": episodes,
        "per_task": per_task_success(episodes) if status == "ok" else None,
    }
    if miou is not None:
        data["decomposition"] = {"miou": sum(miou.values()) / len(miou), "per_task": miou,
                                 "num_demos": 3}
    path = root / name / "results.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(data))


def test_one_seed_of_one_method_shows_no_spread_and_no_rank(tmp_path: Path):
    # 3 of 4 episodes succeed on t1, 1 of 4 on t2: 75 and 25, average 50, one seed
    _write_run(tmp_path, "0", "rdd", 0, {"t1": [True, True, True, False], "t2": [False, True, False, False]})
    md, written = write_tables(tmp_path, tmp_path / "out")
    header = next(line for line in md.splitlines() if line.startswith("| Method"))
    row = next(line for line in md.splitlines() if line.startswith("| rdd") or line.startswith("| **rdd"))
    assert "Avg. Rank" not in header and "±" not in row
    assert [c.strip("* ") for c in row.strip("|").split("|")[1:]] == ["50.0", "75.0", "25.0"]
    assert "sample std" not in md and any(p.suffix == ".png" for p in written)


def test_average_ranks_ties_share_mean_rank():
    assert average_ranks([0.5, 0.9, 0.5, 0.1]) == [2.5, 1.0, 2.5, 4.0]
    assert average_ranks([1.0, 1.0, 1.0]) == [2.0, 2.0, 2.0]


def test_success_table_cells_match_hand_computation(tmp_path: Path):
    # Two methods, two seeds, two tasks, two episodes each.
    # seed 0: A: t1 1.0, t2 0.5 -> avg 0.75; B: t1 0.5, t2 0.5 -> avg 0.5
    # seed 1: A: t1 0.5, t2 0.0 -> avg 0.25; B: t1 1.0, t2 0.0 -> avg 0.5
    _write_run(tmp_path, "0", "A", 0, {"t1": [True, True], "t2": [True, False]}, miou={"t1": 0.8, "t2": 0.6})
    _write_run(tmp_path, "1", "B", 0, {"t1": [True, False], "t2": [False, True]}, miou={"t1": 0.4, "t2": 0.4})
    _write_run(tmp_path, "2", "A", 1, {"t1": [False, True], "t2": [False, False]}, miou={"t1": 0.6, "t2": 0.6})
    _write_run(tmp_path, "3", "B", 1, {"t1": [True, True], "t2": [False, False]}, miou={"t1": 0.2, "t2": 0.4})
    _write_run(tmp_path, "4", "C", 0, {}, status="skipped", reason="no LIV weights at /x/liv/model.pt")
    md, written = write_tables(tmp_path, tmp_path / "out")
    success_md = md.split("decomposition mIoU")[0]
    lines = {line.split(" | ")[0].strip("| *"): line
             for line in success_md.splitlines() if line.startswith("| ")}
    # A: avg over seeds (0.75, 0.25) -> 50.0 ± 35.4 (sample std of 75 and 25 = 35.36)
    assert "50.0 ± 35.4" in lines["A"]
    # B: (0.5, 0.5) -> 50.0 ± 0.0
    assert "50.0 ± 0.0" in lines["B"]
    # Ranks. seed 0: t1 A1 B2; t2 tie 1.5/1.5 -> A 1.25, B 1.75.
    #        seed 1: t1 A2 B1; t2 tie -> A 1.75, B 1.25. Means: A 1.50 ± 0.35, B 1.50 ± 0.35.
    assert "1.50 ± 0.35" in lines["A"] and "1.50 ± 0.35" in lines["B"]
    # Per-task column t1 for A: (1.0, 0.5) -> 75.0 ± 35.4
    assert lines["A"].split(" | ")[3] == "75.0 ± 35.4"
    # mIoU table: A avg (0.7, 0.6) -> 65.0 ± 7.1 ; B (0.4, 0.3) -> 35.0 ± 7.1
    miou_lines = [ln for ln in md.split("decomposition mIoU")[1].splitlines() if ln.startswith("| ")]
    assert any(ln.startswith("| **A** | **65.0 ± 7.1**") or ln.startswith("| A | **65.0 ± 7.1**")
               for ln in miou_lines)
    assert "no LIV weights" in md
    names = {p.name for p in written}
    assert {"table_main.md", "table_main.tex", "table_main_success.png"} <= names
    tex = (tmp_path / "out" / "table_main.tex").read_text()
    assert r"\toprule" in tex and r"\midrule" in tex and r"\bottomrule" in tex
    assert r"50.0 $\pm$ 35.4" in tex


def test_one_table_per_experiment_and_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    _write_run(tmp_path, "a/0", "rdd", 0, {"t1": [True]}, experiment="abl_alpha")
    _write_run(tmp_path, "b/0", "rdd", 0, {"t1": [False]}, experiment="necessity")
    assert main(["--runs", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "## abl_alpha" in out and "## necessity" in out
    assert (tmp_path / "tables" / "abl_alpha.md").is_file()


def test_speed_table_and_plot(tmp_path: Path):
    path = tmp_path / "s" / "results.json"
    path.parent.mkdir()
    rows = [{"frames": 100, "seconds_with_max_len": 0.1, "seconds_without_max_len": 0.2},
            {"frames": 400, "seconds_with_max_len": 0.4, "seconds_without_max_len": 3.2}]
    path.write_text(json.dumps({"format": RESULTS_FORMAT, "status": "ok", "seed": 0,
                                "choices": {"experiment": "speed"}, "overrides": [],
                                "speed": {"max_len": 100, "rows": rows}}))
    md, written = write_tables(tmp_path)
    assert "| 400 | 0.400 | 3.200 | 8.0x |" in md
    assert any(p.name == "speed_speed.png" for p in written)


def test_bad_inputs_name_the_file(tmp_path: Path):
    with pytest.raises(FileNotFoundError, match="no such directory"):
        write_tables(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match="no results.json"):
        write_tables(tmp_path)
    bad = tmp_path / "x" / "results.json"
    bad.parent.mkdir()
    bad.write_text("{not json")
    with pytest.raises(ValueError, match=str(bad)):
        write_tables(tmp_path)


def test_labels_come_from_the_swept_overrides(tmp_path: Path):
    from experiments.report.results import RunRecord, assign_labels

    def rec(overrides: list[str]) -> RunRecord:
        return RunRecord(tmp_path, {"overrides": overrides, "choices": {"decomposer": "rdd"}})

    runs = [rec(["experiment=abl_alpha", f"decomposer.alpha={a}", f"seed={s}", "paths.cache_dir=/c"])
            for a in (0, 0.5) for s in (0, 1)]
    assign_labels(runs)
    assert [r.method for r in runs] == ["alpha=0", "alpha=0", "alpha=0.5", "alpha=0.5"]
    single = [rec(["seed=3"])]
    assign_labels(single)
    assert single[0].method == "rdd"
    # abl_demos' two multiruns (M=3 rdd / uvd; M=1 rdd on single-demo sets): the group choice
    # first, then the settings, M under the paper's symbol
    demos = [rec(["decomposer=rdd"]), rec(["decomposer=uvd"])] + [
        rec(["decomposer=rdd", "data.val_episodes_per_task=1", f"data.val_first_episode={i}"]) for i in (0, 1)]
    assign_labels(demos)
    assert [r.method for r in demos] == ["rdd", "uvd", "rdd, M=1, first demo=0", "rdd, M=1, first demo=1"]
    # a number is labelled one way however the sweep wrote it: 1.0 and 1 are one variant
    betas = [rec([f"decomposer.beta={b}"]) for b in ("0.10", "0.1", "1.0", "1", "2e-1", "top")]
    assign_labels(betas)
    assert [r.method for r in betas] == ["beta=0.1", "beta=0.1", "beta=1", "beta=1", "beta=0.2", "beta=top"]


def test_miou_table_time_and_novelty_columns(tmp_path: Path):
    # rdd: demos take 0.2 and 0.4 s (mean 0.300) with novelty 0.1 and 0.3 (0.200 ± 0.141);
    # uniform: 0.010 s, no novelty ("–").
    _write_run(tmp_path, "0", "rdd", 0, {"t1": [True]}, miou={"t1": 0.5})
    _write_run(tmp_path, "1", "uniform", 0, {"t1": [False]}, miou={"t1": 0.25})
    for name, demos in (("0", [(0.2, 0.1), (0.4, 0.3)]), ("1", [(0.01, None)])):
        path = tmp_path / name / "results.json"
        data = json.loads(path.read_text())
        data["decomposition"]["demos"] = [{"task": "t1", "seconds": s, "novelty": n} for s, n in demos]
        path.write_text(json.dumps(data))
    md, _ = write_tables(tmp_path, tmp_path / "out")
    miou_md = md.split("decomposition mIoU")[1].split(": beside the paper")[0]
    lines = {line.split(" | ")[0].strip("| *"): line for line in miou_md.splitlines() if line.startswith("| ")}
    assert "s / demo" in lines["Method"] and "novelty Δ" in lines["Method"]
    assert lines["rdd"].rstrip(" |").endswith("0.300 | 0.200 ± 0.141")
    assert lines["uniform"].rstrip(" |").endswith("0.010 | –")


def test_paired_table_in_written_tables(tmp_path: Path):
    # rdd succeeds everywhere; uvd fails everywhere on seed 0 and 1 (4 paired episodes): -100 [-100, -100].
    # expert equals rdd: +0.0 [+0.0, +0.0], not significant.
    for seed in (0, 1):
        _write_run(tmp_path, f"r{seed}", "rdd", seed, {"t1": [True], "t2": [True]})
        _write_run(tmp_path, f"u{seed}", "uvd", seed, {"t1": [False], "t2": [False]})
        _write_run(tmp_path, f"e{seed}", "expert", seed, {"t1": [True], "t2": [True]})
    md, _ = write_tables(tmp_path, tmp_path / "out")
    paired = md.split("paired differences")[1].split(": beside the paper")[0]
    rows = {line.split(" | ")[0].strip("| *"): line for line in paired.splitlines()
            if line.startswith("| ")}
    assert "-100.0 | [-100.0, -100.0] | **yes** | 4" in rows["uvd"]
    assert "+0.0 | [+0.0, +0.0] | no | 4" in rows["expert"]


def test_image_dependent_boundaries_and_their_planner_column(tmp_path: Path):
    from experiments.report.result_blocks import image_dependent, planner_eval_block

    def row(task, goal, prev, target, base, tuned):
        return {"task": task, "episode": "e", "frame": 0, "goal": goal, "previous": prev,
                "target": target, "base": "x", "base_hit": base, "finetuned": "y", "finetuned_hit": tuned}

    # stack: after "lift" the same goal leads to "above the plate" once and "above the stack" once
    # (image-dependent, 2 rows); the first step is text-settled. push: one goal, one answer each.
    rows = [row("stack", "stack 2 red", "lift", "above the plate", False, True),
            row("stack", "stack 2 red", "lift", "above the stack", False, False),
            row("stack", "stack 2 red", None, "reach", True, True),
            row("stack", "stack 3 red", "lift", "above the plate", False, True),
            row("push", "push red", None, "move above red", True, True)]
    assert image_dependent(rows) == [True, True, False, False, False]
    block = planner_eval_block(rows, ["stack", "push"], finetuned=True)
    assert block["image_dependent_boundaries"] == 2
    assert block["finetuned_image_dependent"] == 0.5 and block["base_image_dependent"] == 0.0
    dep = block["per_task"]["stack"]["image_dependent"]
    assert dep["boundaries"] == 2 and dep["which"] == [("lift", "above the plate"), ("lift", "above the stack")]
    assert block["per_task"]["push"]["image_dependent"]["boundaries"] == 0
    assert "scene_exact_match" not in block  # no planner described its scenes
    said = ["plate empty", "plate empty", "x", "plate empty", "y"]  # the 2nd is wrong: a block is on it
    true = ["plate empty", "block on plate", "x", "plate empty", "y"]
    scened = [{**r, "scene": s, "scene_true": t} for r, s, t in zip(rows, said, true, strict=True)]
    block_s = planner_eval_block(scened, ["stack", "push"], finetuned=True)
    assert block_s["scene_exact_match"] == 0.8 and block_s["scene_image_dependent"] == 0.5

    data = {"format": RESULTS_FORMAT, "status": "ok", "seed": 0,
            "choices": {"experiment": "planner_eval", "decomposer": "expert"},
            "overrides": ["decomposer=expert"], "planner_eval": json.loads(json.dumps(block))}
    (tmp_path / "0").mkdir()
    (tmp_path / "0" / "results.json").write_text(json.dumps(data))
    md, _ = write_tables(tmp_path, tmp_path / "out")
    lines = [line for line in md.splitlines() if line.startswith("| expert")]
    assert "Image-dependent" in md
    # finetuned: 4 of 5 right overall (80.0), 1 of 2 image-dependent (50.0); base 2 of 5, 0 of 2
    assert lines[0].startswith("| expert | base | 40.0 | 0.0 |")  # one seed: no spread to show
    assert lines[1].startswith("| expert | finetuned | **80.0** | 50.0 |")


@pytest.mark.parametrize("one", ["1", "1.0"])
def test_alpha_table_pairs_against_the_papers_alpha_however_it_was_written(tmp_path: Path, one: str):
    # alpha=0 wins t1's one episode where alpha=1 fails, ties t2: +50 points over the two tasks.
    for name, alpha, outcomes in (("0", "0", {"t1": [True], "t2": [True]}),
                                  ("1", one, {"t1": [False], "t2": [True]})):
        _write_run(tmp_path, name, "rdd", 0, outcomes, experiment="abl_alpha")
        path = tmp_path / name / "results.json"
        data = json.loads(path.read_text())
        data["overrides"] = [f"decomposer.alpha={alpha}", "seed=0"]
        path.write_text(json.dumps(data))
    md, _ = write_tables(tmp_path, tmp_path / "out")
    assert "Δ Avg. Succ. vs alpha=1 " in md  # a number is labelled one way, however it was written
    paired = md.split("paired differences")[1]
    row = next(ln for ln in paired.splitlines() if ln.startswith("| alpha=0 |"))
    assert row.split(" | ")[1] == "+50.0"


def test_success_note_names_each_cpu_kind_its_runs_report(tmp_path: Path):
    """Trained stages round differently on another CPU: the note says which made the table, once per
    kind, and says nothing for results written before runs reported it."""
    from experiments.report.results import RunRecord
    from experiments.report.table_builders import machines_note

    def rec(model, capability):
        hw = {"cpu_count": 2} if model is None else {"cpu_model": model, "torch_cpu_capability": capability}
        return RunRecord(tmp_path, {"hardware": hw})

    assert machines_note([rec(None, None)]) == ""
    xeon, epyc = rec("Intel Xeon", "AVX512"), rec("AMD EPYC", "AVX2")
    assert machines_note([xeon, xeon, rec(None, None)]) == " Run on: Intel Xeon (AVX512)."
    assert machines_note([xeon, epyc, xeon]) == " Run on: Intel Xeon (AVX512); AMD EPYC (AVX2)."


def test_table_main_carries_the_papers_figures_beside_ours(tmp_path: Path):
    # rdd 75 (open_drawer 100, stack_blocks 50), expert 100, rdd_calibrated 25; one seed;
    # rdd's Avg. Rank (1.5 + 2) / 2
    _write_run(tmp_path, "0", "rdd", 0, {"open_drawer": [True, True], "stack_blocks": [True, False]})
    _write_run(tmp_path, "1", "expert", 0, {"open_drawer": [True, True], "stack_blocks": [True, True]})
    _write_run(tmp_path, "2", "rdd_calibrated", 0,
               {"open_drawer": [True, False], "stack_blocks": [False, False]})
    md, _ = write_tables(tmp_path, tmp_path / "out")
    section = md.split(": beside the paper")[1].split("###")[0]
    lines = [line for line in section.splitlines() if line.startswith("| ")]
    assert lines[0] == ("| Method | Figures | Rank here | Rank in paper | Avg. Succ. | Avg. Rank "
                        "| open_drawer | stack_blocks |")
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines[1:]]
    # ours, then the paper's row: Avg. from tab-main, per task from the appendix's tab-main-add
    assert cells[0] == ["rdd", "here", "2", "2", "75.0", "1.75", "100.0", "50.0"]
    assert cells[1] == ["RDD (Ours)", "paper", "", "", "74.9 ± 6.9", "2.2 ± 0.9", "99.2 ± 2.4",
                        "5.2 ± 3.6"]
    assert cells[2][:4] == ["expert", "here", "1", "1"] and cells[3][:2] == ["Expert", "paper"]
    # no counterpart in the paper: dashes, never a number
    assert cells[4][:4] == ["rdd_calibrated", "here", "–", "–"]
    assert cells[5] == ["–", "paper", "", "", "–", "–", "–", "–"]
    assert "tab-main-add" in section and "Expert 57.6 ± 3.3" in section
    tex = (tmp_path / "out" / "table_main.tex").read_text()
    assert r"RDD (Ours) & paper &  &  & 74.9 $\pm$ 6.9" in tex


def test_ablation_rows_map_onto_the_papers_rows(tmp_path: Path):
    # one-demo sets all stand beside the paper's "1 (RDD)"; alpha labels written one way
    from experiments.report.paper_compare import SPECS, paper_row

    assert paper_row(SPECS["abl_demos"], "rdd, M=1, first demo=2") == "1 (RDD)"
    assert paper_row(SPECS["abl_demos"], "uvd") == "3 (UVD)"
    assert paper_row(SPECS["abl_alpha"], "alpha=0.5") == "0.5"
    assert paper_row(SPECS["abl_encoder"], "effnet_lite0") is None
    assert paper_row(SPECS["necessity"], "other_tasks") == "w/o finetuning on target task"
    assert paper_row(SPECS["necessity"], "expert") is None
