"""Paper-style tables and plots from a tree of results.json files.

``python -m experiments.tables --runs DIR [--out DIR]`` writes, per experiment found under DIR:
- a success table (Markdown + LaTeX booktabs): one row per method, Avg. Succ. +/- std over seeds,
  Avg. Rank +/- std (methods ranked per task and seed, ties share the mean rank), one column per task;
- an mIoU table (decomposition against the expert on the validation demonstrations);
- paired differences of each method's average success to a reference method (rdd by default) with
  95% bootstrap intervals over the shared seeded episodes (``experiments.stats``);
- a planner table (mode=planner_eval runs): next-instruction exact match, base and finetuned;
- a solver-speed table (mode=speed runs);
- PNG plots: success per task and method, and solver time versus frames.
Skipped runs (e.g. an encoder without weights) are listed under the tables with their reason.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.results import RunRecord, assign_labels, load_runs
from experiments.stats import episode_outcomes, paired_difference
from rdd.atomic import write_text_atomic


def _natural_key(path: Path) -> list[object]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(path))]


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof=1; 0 for a single value)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return math.nan, math.nan
    return float(arr.mean()), float(arr.std(ddof=1)) if arr.size > 1 else 0.0


def average_ranks(scores: Sequence[float]) -> list[float]:
    """1-based ranks, highest score first, ties sharing the mean of their ranks."""
    order = sorted(range(len(scores)), key=lambda i: -scores[i])
    ranks = [0.0] * len(scores)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and scores[order[j + 1]] == scores[order[i]]:
            j += 1
        for k in range(i, j + 1):
            ranks[order[k]] = (i + j) / 2 + 1
        i = j + 1
    return ranks


@dataclass
class Table:
    """A rendered table: header, rows of cells, and which cells are best (bold)."""

    title: str
    header: list[str]
    rows: list[list[str]]
    bold: set[tuple[int, int]]
    note: str = ""

    def markdown(self) -> str:
        """GitHub Markdown."""
        def cell(r: int, c: int, text: str) -> str:
            return f"**{text}**" if (r, c) in self.bold else text

        lines = [f"### {self.title}", ""]
        lines.append("| " + " | ".join(self.header) + " |")
        lines.append("|" + "|".join(["---"] + [":-:"] * (len(self.header) - 1)) + "|")
        for r, row in enumerate(self.rows):
            lines.append("| " + " | ".join(cell(r, c, t) for c, t in enumerate(row)) + " |")
        if self.note:
            lines += ["", self.note]
        return "\n".join(lines) + "\n"

    def latex(self) -> str:
        """A booktabs tabular inside a table environment."""
        def esc(text: str) -> str:
            text = text.replace("\\", r"\textbackslash{}")
            for ch in "_%&#$":
                text = text.replace(ch, "\\" + ch)
            return text.replace("±", r"$\pm$").replace("↑", r"$\uparrow$").replace("↓", r"$\downarrow$")

        def cell(r: int, c: int, text: str) -> str:
            return rf"\textbf{{{esc(text)}}}" if (r, c) in self.bold else esc(text)

        cols = "l" + "c" * (len(self.header) - 1)
        lines = [r"\begin{table}[t]", r"\centering", rf"\caption{{{esc(self.title)}}}"]
        lines += [r"\resizebox{\linewidth}{!}{%", rf"\begin{{tabular}}{{{cols}}}", r"\toprule"]
        lines.append(" & ".join(esc(h) for h in self.header) + r" \\")
        lines.append(r"\midrule")
        for r, row in enumerate(self.rows):
            lines.append(" & ".join(cell(r, c, t) for c, t in enumerate(row)) + r" \\")
        lines += [r"\bottomrule", r"\end{tabular}}", r"\end{table}"]
        return "\n".join(lines) + "\n"


def _pm(mean: float, std: float, scale: float = 100.0, digits: int = 1) -> str:
    if math.isnan(mean):
        return "–"
    return f"{mean * scale:.{digits}f} ± {std * scale:.{digits}f}"


def _methods_in_order(runs: Sequence[RunRecord]) -> list[str]:
    seen: list[str] = []
    for run in runs:
        if run.method not in seen:
            seen.append(run.method)
    return seen


def _latest_per_method_seed(runs: Sequence[RunRecord]) -> dict[tuple[str, int], RunRecord]:
    """One run per (method, seed); a later path (rerun) replaces an earlier one."""
    out: dict[tuple[str, int], RunRecord] = {}
    for run in runs:
        out[(run.method, run.seed)] = run
    return out


def _tasks_in_order(per_task_maps: Iterable[dict]) -> list[str]:
    """Task names in first-seen order over the runs' per-task maps."""
    return list(dict.fromkeys(task for m in per_task_maps for task in m))


def success_table(title: str, runs: Sequence[RunRecord]) -> Table | None:
    """The paper's main-table form from hierarchical runs."""
    runs = [r for r in runs if r.status == "ok" and r.data.get("per_task")]
    if not runs:
        return None
    methods = _methods_in_order(runs)
    by_key = _latest_per_method_seed(runs)
    tasks = _tasks_in_order(run.data["per_task"] for run in runs)
    seeds = sorted({seed for _, seed in by_key})
    # succ[method][seed][task]
    succ: dict[str, dict[int, dict[str, float]]] = defaultdict(dict)
    for (method, seed), run in by_key.items():
        succ[method][seed] = {t: float(v["success_rate"]) for t, v in run.data["per_task"].items()}
    # Ranks: per seed and task, among the methods that have that (seed, task).
    rank_sum: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    for seed in seeds:
        for task in tasks:
            present = [m for m in methods if task in succ[m].get(seed, {})]
            if len(present) < 1:
                continue
            ranks = average_ranks([succ[m][seed][task] for m in present])
            for m, rk in zip(present, ranks, strict=True):
                rank_sum[m][seed].append(rk)
    header = ["Method", "Avg. Succ. ↑", "Avg. Rank ↓", *tasks]
    rows, avg_means, rank_means = [], [], []
    for m in methods:
        per_seed_avg = [float(np.mean(list(v.values()))) for v in succ[m].values() if v]
        per_seed_rank = [float(np.mean(v)) for v in rank_sum[m].values() if v]
        a_mean, a_std = mean_std(per_seed_avg)
        r_mean, r_std = mean_std(per_seed_rank)
        avg_means.append(a_mean)
        rank_means.append(r_mean)
        row = [m, _pm(a_mean, a_std), _pm(r_mean, r_std, scale=1.0, digits=2)]
        for task in tasks:
            vals = [succ[m][s][task] for s in succ[m] if task in succ[m][s]]
            row.append(_pm(*mean_std(vals)))
        rows.append(row)
    bold = set()
    if rows:
        best_a = np.nanmax(avg_means)
        best_r = np.nanmin(rank_means)
        for i in range(len(rows)):
            if avg_means[i] == best_a:
                bold.add((i, 1))
            if rank_means[i] == best_r:
                bold.add((i, 2))
    n_eps = sorted({int(v["episodes"]) for r in runs for v in r.data["per_task"].values()})
    note = (
        f"Success rate (%) over {len(seeds)} seed(s) {seeds}, {'/'.join(map(str, n_eps))} "
        "evaluation episode(s) per task and seed; ± is the sample std over seeds. "
        "Avg. Rank: methods ranked per task and seed (ties share the mean rank)."
    )
    return Table(title, header, rows, bold, note)


# The method each experiment's paired differences are taken against (its label in the tables: the
# paper's alpha, the default encoder; labels write a number one way, 1.0 as 1); the first label
# present is used.
REFERENCE = {"abl_alpha": ("alpha=1",), "abl_encoder": ("effnet_lite0",)}
DEFAULT_REFERENCE = ("rdd",)


def _reference(runs: Sequence[RunRecord], candidates: Sequence[str]) -> str:
    """The first of ``candidates`` that labels one of ``runs`` (else the first, and no paired table)."""
    labels = {r.method for r in runs}
    return next((c for c in candidates if c in labels), candidates[0])


def paired_table(title: str, runs: Sequence[RunRecord], reference: str, n_boot: int = 10_000) -> Table | None:
    """Each method minus ``reference`` in average success, paired by episode, with 95% bootstrap CIs."""
    runs = [r for r in runs if r.status == "ok" and r.data.get("episodes")]
    by_key = _latest_per_method_seed(runs)
    methods = _methods_in_order(runs)
    if reference not in methods or len(methods) < 2:
        return None

    def outcomes(method: str) -> dict:
        return episode_outcomes({seed: r.data["episodes"] for (m, seed), r in by_key.items() if m == method})

    ref = outcomes(reference)
    header = ["Method", f"Δ Avg. Succ. vs {reference}", "95% CI", "significant", "paired episodes"]
    rows, bold = [], set()
    for m in methods:
        if m == reference:
            continue
        d = paired_difference(m, outcomes(m), reference, ref, n_boot=n_boot)
        rows.append([m, f"{100 * d.mean:+.1f}", f"[{100 * d.low:+.1f}, {100 * d.high:+.1f}]",
                     "yes" if d.significant else "no", str(d.pairs)])
        if d.significant:
            bold.add((len(rows) - 1, 3))
    note = (f"Percentage points; episodes paired on (seed, task, environment seed); percentile bootstrap "
            f"({n_boot} resamples of the episodes within each task, all seeds together). "
            "Significant: the interval excludes 0.")
    return Table(title, header, rows, bold, note)


def miou_table(title: str, runs: Sequence[RunRecord]) -> Table | None:
    """Decomposition mIoU against the expert, per method and task, mean ± std over seeds."""
    runs = [r for r in runs if r.status == "ok" and (r.data.get("decomposition") or {}).get("per_task")]
    if not runs:
        return None
    methods = _methods_in_order(runs)
    by_key = _latest_per_method_seed(runs)
    tasks = _tasks_in_order(run.data["decomposition"]["per_task"] for run in runs)
    demos = {m: [d for (mm, _), r in by_key.items() if mm == m for d in r.data["decomposition"].get("demos", [])]
             for m in methods}
    with_time = any("seconds" in d for ds in demos.values() for d in ds)
    with_novelty = any(d.get("novelty") is not None for ds in demos.values() for d in ds)
    header = ["Method", "Avg. mIoU ↑", *tasks]
    header += ["s / demo"] if with_time else []
    header += ["novelty Δ"] if with_novelty else []
    rows, means = [], []
    for m in methods:
        mruns = [r for (mm, _), r in by_key.items() if mm == m]
        avg = [float(r.data["decomposition"]["miou"]) for r in mruns]
        mean, std = mean_std(avg)
        means.append(mean)
        row = [m, _pm(mean, std)]
        for task in tasks:
            vals = [float(r.data["decomposition"]["per_task"][task]) for r in mruns
                    if task in r.data["decomposition"]["per_task"]]
            row.append(_pm(*mean_std(vals)))
        if with_time:
            secs = [float(d["seconds"]) for d in demos[m] if "seconds" in d]
            row.append(f"{np.mean(secs):.3f}" if secs else "–")
        if with_novelty:
            nov = [float(d["novelty"]) for d in demos[m] if d.get("novelty") is not None]
            row.append(_pm(*mean_std(nov), scale=1.0, digits=3) if nov else "–")
        rows.append(row)
    best = np.nanmax(means)
    bold = {(i, 1) for i, v in enumerate(means) if v == best}
    n_demos = sorted({int(r.data["decomposition"].get("num_demos", 0)) for r in runs})
    note = (f"mIoU (%) of each decomposition against the expert keyframe segmentation on "
            f"{'/'.join(map(str, n_demos))} validation demonstration(s); ± is the sample std over seeds."
            + (" s / demo: mean wall time of one decomposition, encoding the demo's frames included"
               " when no earlier job had cached them." if with_time else "")
            + (" novelty Δ: mean ± std over demos of RDD's novelty score (paper Eq. 3.6)." if with_novelty else ""))
    return Table(title, header, rows, bold, note)


def planner_table(title: str, runs: Sequence[RunRecord]) -> Table | None:
    """Planner-only runs: next-instruction exact match per task, base and finetuned, over seeds."""
    runs = [r for r in runs if r.status == "ok" and (r.data.get("planner_eval") or {}).get("per_task")]
    if not runs:
        return None
    by_key = _latest_per_method_seed(runs)
    tasks = _tasks_in_order(run.data["planner_eval"]["per_task"] for run in runs)
    header = ["Method", "Planner", "All tasks ↑", "Image-dependent ↑", *tasks]
    rows, means = [], []
    for m in _methods_in_order(runs):
        mruns = [r for (mm, _), r in by_key.items() if mm == m]
        for name in ("base", "finetuned"):
            if not any(r.data["planner_eval"].get(f"{name}_exact_match") is not None for r in mruns):
                continue
            mean, std = mean_std([float(r.data["planner_eval"][f"{name}_exact_match"]) for r in mruns])
            means.append(mean)
            dep = [r.data["planner_eval"].get(f"{name}_image_dependent") for r in mruns]
            dep = [float(v) for v in dep if v is not None]
            row = [m, name, _pm(mean, std), _pm(*mean_std(dep)) if dep else "–"]
            for task in tasks:
                vals = [float(r.data["planner_eval"]["per_task"][task][name]) for r in mruns
                        if task in r.data["planner_eval"]["per_task"]]
                row.append(_pm(*mean_std(vals)))
            rows.append(row)
    best = np.nanmax(means)
    bold = {(i, 2) for i, v in enumerate(means) if v == best}
    counts = sorted({int(r.data["planner_eval"]["boundaries"]) for r in runs})
    seeds = sorted({r.seed for r in runs})
    deps = sorted({int(r.data["planner_eval"].get("image_dependent_boundaries", 0)) for r in runs})
    note = (f"Exact match (%) of the next instruction at {'/'.join(map(str, counts))} segment starts "
            f"of held-out test-split episodes; {len(seeds)} seed(s) {seeds}; ± is the sample std over seeds. "
            f"Image-dependent: the {'/'.join(map(str, deps))} of them whose goal and previous instruction "
            "also precede another answer in the same task (only the image can settle them).")
    return Table(title, header, rows, bold, note)


def speed_table(title: str, runs: Sequence[RunRecord]) -> Table | None:
    """Solver wall time versus number of frames, with and without L_max."""
    runs = [r for r in runs if r.status == "ok" and r.data.get("speed")]
    if not runs:
        return None
    rows_by_t: dict[int, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    max_len = None
    for run in runs:
        max_len = run.data["speed"].get("max_len", max_len)
        for row in run.data["speed"]["rows"]:
            rows_by_t[int(row["frames"])]["with"].append(float(row["seconds_with_max_len"]))
            rows_by_t[int(row["frames"])]["without"].append(float(row["seconds_without_max_len"]))
    header = ["Frames T", f"with L_max={max_len} (s)", "without L_max (s)", "speed-up"]
    rows = []
    for t in sorted(rows_by_t):
        w = float(np.mean(rows_by_t[t]["with"]))
        wo = float(np.mean(rows_by_t[t]["without"]))
        rows.append([str(t), f"{w:.3f}", f"{wo:.3f}", f"{wo / w:.1f}x" if w > 0 else "–"])
    return Table(title, header, rows, set(), "Decomposition wall time (candidate retrieval + solver).")


def skipped_note(runs: Sequence[RunRecord]) -> str:
    """Markdown list of skipped or failed runs with their reasons."""
    lines = []
    for run in runs:
        if run.status != "ok":
            lines.append(f"- {run.method} (seed {run.seed}): {run.status}: {run.data.get('reason', '')}")
    return ("Not run:\n" + "\n".join(lines) + "\n") if lines else ""


def plot_success(runs: Sequence[RunRecord], path: Path, title: str) -> bool:
    """Grouped bar chart: success per task (x) and method (bars), mean over seeds with std bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [r for r in runs if r.status == "ok" and r.data.get("per_task")]
    if not runs:
        return False
    methods = _methods_in_order(runs)
    tasks: list[str] = []
    for run in runs:
        tasks += [t for t in run.data["per_task"] if t not in tasks]
    by_key = _latest_per_method_seed(runs)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(tasks) + 2), 3.6))
    width = 0.8 / len(methods)
    for i, m in enumerate(methods):
        means, stds = [], []
        for task in tasks:
            vals = [r.data["per_task"][task]["success_rate"] for (mm, _), r in by_key.items()
                    if mm == m and task in r.data["per_task"]]
            mean, std = mean_std(vals)
            means.append(100 * mean)
            stds.append(100 * std)
        x = np.arange(len(tasks)) + (i - (len(methods) - 1) / 2) * width
        ax.bar(x, means, width, yerr=stds, label=m, capsize=2)
    ax.set_xticks(np.arange(len(tasks)), [t.replace("_", "\n") for t in tasks], fontsize=7)
    ax.set_ylabel("success (%)")
    ax.set_ylim(0, 105)
    ax.set_title(title, fontsize=9)
    # beside the axes: inside, it covered the bars of the tasks near 100 %
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    fig.tight_layout()
    _save_fig(fig, path)
    return True


def plot_speed(runs: Sequence[RunRecord], path: Path) -> bool:
    """Solver time versus frames, with and without L_max (log-log)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = speed_table("speed", runs)
    if table is None:
        return False
    t = [int(r[0]) for r in table.rows]
    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    ax.plot(t, [float(r[1]) for r in table.rows], "o-", label=table.header[1].replace(" (s)", ""))
    ax.plot(t, [float(r[2]) for r in table.rows], "s-", label="without L_max")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("frames T")
    ax.set_ylabel("decomposition time (s)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save_fig(fig, path)
    return True


def _save_fig(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    from rdd.atomic import atomic_file

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_file(path) as fh:
        fig.savefig(fh, dpi=130, format="png")
    plt.close(fig)


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
        tables = [
            success_table(title, eruns),
            paired_table(f"{title}: paired differences", eruns,
                         _reference(eruns, REFERENCE.get(exp, DEFAULT_REFERENCE))),
            miou_table(f"{title}: decomposition mIoU against the expert", eruns),
            planner_table(f"{title}: planner next-instruction exact match", eruns),
            speed_table(f"{title}: solver time", eruns),
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
        if plot_success(by_exp[exp], png, f"{exp}: success per task (mean ± std over seeds)"):
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
