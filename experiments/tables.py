"""Paper-style tables and plots from a tree of results.json files.

``python -m experiments.tables --runs DIR [--out DIR]`` writes, per experiment found under DIR:
- a success table (Markdown + LaTeX booktabs): one row per method, Avg. Succ. +/- std over seeds,
  Avg. Rank +/- std (methods ranked per task and seed, ties share the mean rank), one column per task;
- an mIoU table (decomposition against the expert on the validation demonstrations);
- paired differences of each method's average success to a reference method (rdd by default) with
  95% bootstrap intervals over the shared seeded episodes (``experiments.report.stats``);
- a planner table (mode=planner_eval runs): next-instruction exact match, base and finetuned;
- a solver-speed table (mode=speed runs);
- last, the success table (the mIoU table for the OOD ablation) again with the paper's figures in
  a row under each method, and each row's rank here and in the paper
  (``experiments.report.paper_compare``; the figures in ``experiments.report.paper_figures``);
- PNG plots: success per task and method, and solver time versus frames.
Skipped runs (e.g. an encoder without weights) are listed under the tables with their reason.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

from experiments.report.paper_compare import SPECS, beside_paper, paper_verbatim
from experiments.report.plots import plot_miou, plot_speed, plot_success
from experiments.report.results import RunRecord, assign_labels, load_runs
from experiments.report.table_builders import (
    miou_table,
    paired_table,
    planner_table,
    speed_table,
    success_table,
)
from experiments.report.table_format import Table
from rdd.atomic import write_text_atomic


def _natural_key(path: Path) -> list[object]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(path))]


# The method each experiment's paired differences are taken against (its label in the tables: the
# paper's alpha, the default encoder; labels write a number one way, 1.0 as 1); the first label
# present is used.
REFERENCE = {"abl_alpha": ("alpha=1",), "abl_encoder": ("effnet_lite0",)}
DEFAULT_REFERENCE = ("rdd",)


def _reference(runs: Sequence[RunRecord], candidates: Sequence[str]) -> str:
    """The first of ``candidates`` that labels one of ``runs`` (else the first, and no paired table)."""
    labels = {r.method for r in runs}
    return next((c for c in candidates if c in labels), candidates[0])


def skipped_note(runs: Sequence[RunRecord]) -> str:
    """Markdown list of skipped or failed runs with their reasons."""
    lines = []
    for run in runs:
        if run.status != "ok":
            lines.append(f"- {run.method} (seed {run.seed}): {run.status}: {run.data.get('reason', '')}")
    return ("Not run:\n" + "\n".join(lines) + "\n") if lines else ""


TITLES = {
    "table_main": "Success rate per decomposer (planner finetuned on M demonstrations per task)",
    "table_main_full": "Success rate per decomposer (paper scale: 10 seeds x 25 episodes)",
    "abl_alpha": "Ablation: RDD length weight alpha",
    "abl_encoder": "Ablation: visual encoder of RDD",
    "abl_demos": "Ablation: number of demonstrations per task",
    "abl_ood_beta": "Ablation: OOD weight beta on tasks held out of the database",
    "necessity": "Necessity of finetuning: base planner zero-shot versus finetuned",
    "speed": "Solver scaling",
}


def build_tables(runs: Sequence[RunRecord]) -> dict[str, list[Table]]:
    """Tables per experiment name."""
    by_exp: dict[str, list[RunRecord]] = defaultdict(list)
    for run in sorted(runs, key=lambda r: _natural_key(r.path)):
        by_exp[run.experiment].append(run)
    out: dict[str, list[Table]] = {}
    for exp, eruns in by_exp.items():
        assign_labels(eruns)
        title = TITLES.get(exp, f"Experiment {exp}")
        success = success_table(title, eruns)
        miou = miou_table(f"{title}: decomposition mIoU against the expert", eruns)
        kind = SPECS[exp].kind if exp in SPECS else None
        tables = [
            success,
            paired_table(f"{title}: paired differences", eruns,
                         _reference(eruns, REFERENCE.get(exp, DEFAULT_REFERENCE))),
            miou,
            planner_table(f"{title}: planner next-instruction exact match", eruns),
            speed_table(f"{title}: solver time", eruns),
            # last, so every table before it prints as it did before the paper's figures were added
            beside_paper(exp, f"{title}: beside the paper",
                         {"success": success, "miou": miou}.get(kind)),
            paper_verbatim(exp, f"{title}: the paper's nearest table"),
        ]
        out[exp] = [t for t in tables if t is not None]
    return out


def write_tables(runs_dir: Path, out_dir: Path | None = None) -> tuple[str, list[Path]]:
    """Write Markdown, LaTeX and PNGs for every experiment under ``runs_dir``; return Markdown."""
    runs = load_runs(runs_dir)
    if not runs:
        raise FileNotFoundError(f"--runs {runs_dir}: no results.json below it")
    out_dir = Path(out_dir) if out_dir is not None else Path(runs_dir) / "tables"
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    md_all = []
    by_exp: dict[str, list[RunRecord]] = defaultdict(list)
    for run in sorted(runs, key=lambda r: _natural_key(r.path)):
        by_exp[run.experiment].append(run)
    for exp, tables in build_tables(runs).items():
        md = "".join(t.markdown() + "\n" for t in tables) + skipped_note(by_exp[exp])
        tex = "".join(t.latex() + "\n" for t in tables)
        for suffix, text in ((".md", md), (".tex", tex)):
            path = out_dir / f"{exp}{suffix}"
            write_text_atomic(path, text)
            written.append(path)
        png = out_dir / f"{exp}_success.png"
        seeds = len({r.seed for r in by_exp[exp]})
        what = "mean ± std over seeds" if seeds > 1 else "one seed"
        if plot_success(by_exp[exp], png, f"{exp}: success per task ({what})"):
            written.append(png)
        png = out_dir / f"{exp}_miou.png"
        if plot_miou(by_exp[exp], png, f"{exp}: decomposition mIoU against the expert ({what})"):
            written.append(png)
        png = out_dir / f"{exp}_speed.png"
        if plot_speed(by_exp[exp], png):
            written.append(png)
        md_all.append(f"## {exp}\n\n{md}")
    return "\n".join(md_all), written


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry point."""
    parser = argparse.ArgumentParser(prog="python -m experiments.tables", description=__doc__.split("\n")[0])
    parser.add_argument("--runs", required=True, type=Path, help="folder searched for results.json files")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default RUNS/tables)")
    args = parser.parse_args(argv)
    try:
        md, written = write_tables(args.runs, args.out)
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(md)
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
