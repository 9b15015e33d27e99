"""The tables of one experiment's runs: success and rank, paired differences, mIoU, planner, speed."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence

import numpy as np

from experiments.report.results import RunRecord
from experiments.report.stats import episode_outcomes, paired_difference
from experiments.report.table_format import Table, machine_kind, mean_std, plus_minus


def average_ranks(scores: Sequence[float]) -> list[float]:
    """1-based ranks, highest score first, ties sharing the mean of their ranks."""
    from scipy.stats import rankdata  # lazy: scipy.stats takes most of a second to import

    # rankdata ranks the lowest first; negating makes the highest score rank 1
    return rankdata(-np.asarray(scores, dtype=np.float64), method="average").tolist()


def methods_in_order(runs: Sequence[RunRecord]) -> list[str]:
    seen: list[str] = []
    for run in runs:
        if run.method not in seen:
            seen.append(run.method)
    return seen


def latest_per_method_seed(runs: Sequence[RunRecord]) -> dict[tuple[str, int], RunRecord]:
    """One run per (method, seed); a later path (rerun) replaces an earlier one."""
    out: dict[tuple[str, int], RunRecord] = {}
    for run in runs:
        out[(run.method, run.seed)] = run
    return out


def _spread_note(n_seeds: int) -> str:
    """The end of a table note's sentence: what ± means, said only when there is a spread to show."""
    return "; ± is the sample std over seeds." if n_seeds > 1 else "."


def machines_note(runs: Sequence[RunRecord]) -> str:
    """`` Run on: <CPU> (<vector width>).``, naming each CPU kind the runs report (trained stages
    round differently on another one); empty for results that do not say."""
    kinds = dict.fromkeys(k for r in runs if (k := machine_kind(r.data.get("hardware"))))
    return f" Run on: {'; '.join(kinds)}." if kinds else ""


def _tasks_in_order(per_task_maps: Iterable[dict]) -> list[str]:
    """Task names in first-seen order over the runs' per-task maps."""
    return list(dict.fromkeys(task for m in per_task_maps for task in m))


def success_table(title: str, runs: Sequence[RunRecord]) -> Table | None:
    """The paper's main-table form from hierarchical runs."""
    runs = [r for r in runs if r.status == "ok" and r.data.get("per_task")]
    if not runs:
        return None
    methods = methods_in_order(runs)
    by_key = latest_per_method_seed(runs)
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
    ranked = len(methods) > 1  # a rank among one method says nothing
    header = ["Method", "Avg. Succ. ↑", *(["Avg. Rank ↓"] if ranked else []), *tasks]
    rows, avg_means, rank_means = [], [], []
    for m in methods:
        per_seed_avg = [float(np.mean(list(v.values()))) for v in succ[m].values() if v]
        per_seed_rank = [float(np.mean(v)) for v in rank_sum[m].values() if v]
        a_mean, a_std = mean_std(per_seed_avg)
        r_mean, r_std = mean_std(per_seed_rank)
        avg_means.append(a_mean)
        rank_means.append(r_mean)
        row = [m, plus_minus(a_mean, a_std), *([plus_minus(r_mean, r_std, scale=1.0, digits=2)] if ranked else [])]
        for task in tasks:
            vals = [succ[m][s][task] for s in succ[m] if task in succ[m][s]]
            row.append(plus_minus(*mean_std(vals)))
        rows.append(row)
    bold = set()
    if rows:
        best_a = np.nanmax(avg_means)
        best_r = np.nanmin(rank_means)
        for i in range(len(rows)):
            if avg_means[i] == best_a:
                bold.add((i, 1))
            if ranked and rank_means[i] == best_r:
                bold.add((i, 2))
    n_eps = sorted({int(v["episodes"]) for r in runs for v in r.data["per_task"].values()})
    note = (
        f"Success rate (%) over {len(seeds)} seed(s) {seeds}, {'/'.join(map(str, n_eps))} "
        "evaluation episode(s) per task and seed"
        + _spread_note(len(seeds))
        + (" Avg. Rank: methods ranked per task and seed (ties share the mean rank)." if ranked else "")
        + machines_note(runs)
    )
    return Table(title, header, rows, bold, note)

def paired_table(title: str, runs: Sequence[RunRecord], reference: str, n_boot: int = 10_000) -> Table | None:
    """Each method minus ``reference`` in average success, paired by episode, with 95% bootstrap CIs."""
    runs = [r for r in runs if r.status == "ok" and r.data.get("episodes")]
    by_key = latest_per_method_seed(runs)
    methods = methods_in_order(runs)
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
    methods = methods_in_order(runs)
    by_key = latest_per_method_seed(runs)
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
        row = [m, plus_minus(mean, std)]
        for task in tasks:
            vals = [float(r.data["decomposition"]["per_task"][task]) for r in mruns
                    if task in r.data["decomposition"]["per_task"]]
            row.append(plus_minus(*mean_std(vals)))
        if with_time:
            secs = [float(d["seconds"]) for d in demos[m] if "seconds" in d]
            row.append(f"{np.mean(secs):.3f}" if secs else "–")
        if with_novelty:
            nov = [float(d["novelty"]) for d in demos[m] if d.get("novelty") is not None]
            row.append(plus_minus(*mean_std(nov), scale=1.0, digits=3) if nov else "–")
        rows.append(row)
    best = np.nanmax(means)
    bold = {(i, 1) for i, v in enumerate(means) if v == best}
    n_demos = sorted({int(r.data["decomposition"].get("num_demos", 0)) for r in runs})
    note = (f"mIoU (%) of each decomposition against the expert keyframe segmentation on "
            f"{'/'.join(map(str, n_demos))} validation demonstration(s)"
            + _spread_note(len({s for _, s in by_key}))
            + (" s / demo: mean wall time of one decomposition, encoding the demo's frames included"
               " when no earlier job had cached them." if with_time else "")
            + (" novelty Δ: mean ± std over demos of RDD's novelty score (paper Eq. 3.6)." if with_novelty else ""))
    return Table(title, header, rows, bold, note)


def planner_table(title: str, runs: Sequence[RunRecord]) -> Table | None:
    """Planner-only runs: next-instruction exact match per task, base and finetuned, over seeds."""
    runs = [r for r in runs if r.status == "ok" and (r.data.get("planner_eval") or {}).get("per_task")]
    if not runs:
        return None
    by_key = latest_per_method_seed(runs)
    tasks = _tasks_in_order(run.data["planner_eval"]["per_task"] for run in runs)
    header = ["Method", "Planner", "All tasks ↑", "Image-dependent ↑", *tasks]
    rows, means = [], []
    for m in methods_in_order(runs):
        mruns = [r for (mm, _), r in by_key.items() if mm == m]
        for name in ("base", "finetuned"):
            if not any(r.data["planner_eval"].get(f"{name}_exact_match") is not None for r in mruns):
                continue
            mean, std = mean_std([float(r.data["planner_eval"][f"{name}_exact_match"]) for r in mruns])
            means.append(mean)
            dep = [r.data["planner_eval"].get(f"{name}_image_dependent") for r in mruns]
            dep = [float(v) for v in dep if v is not None]
            row = [m, name, plus_minus(mean, std), plus_minus(*mean_std(dep)) if dep else "–"]
            for task in tasks:
                vals = [float(r.data["planner_eval"]["per_task"][task][name]) for r in mruns
                        if task in r.data["planner_eval"]["per_task"]]
                row.append(plus_minus(*mean_std(vals)))
            rows.append(row)
    best = np.nanmax(means)
    bold = {(i, 2) for i, v in enumerate(means) if v == best}
    counts = sorted({int(r.data["planner_eval"]["boundaries"]) for r in runs})
    seeds = sorted({r.seed for r in runs})
    deps = sorted({int(r.data["planner_eval"].get("image_dependent_boundaries", 0)) for r in runs})
    note = (f"Exact match (%) of the next instruction at {'/'.join(map(str, counts))} segment starts "
            f"of held-out test-split episodes; {len(seeds)} seed(s) {seeds}"
            + _spread_note(len(seeds)) + " " +
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
