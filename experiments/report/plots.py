"""PNG plots of an experiment's runs: success per task and method, decomposition mIoU per task and
method, solver time versus frames."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from experiments.report.results import RunRecord
from experiments.report.table_builders import latest_per_method_seed, methods_in_order, speed_table
from experiments.report.table_format import mean_std


def _method_mious(runs: Sequence[RunRecord]) -> dict[str, float]:
    """Each method's decomposition mIoU (%), mean over its seeds; methods without one are left out."""
    vals: dict[str, list[float]] = {}
    for (m, _), r in latest_per_method_seed(runs).items():
        miou = (r.data.get("decomposition") or {}).get("miou")
        if miou is not None:
            vals.setdefault(m, []).append(100 * float(miou))
    return {m: float(np.mean(v)) for m, v in vals.items()}


def _bar_labels(ax, x, heights, tops, texts, colour: str, width: float) -> None:
    """A label above each bar (above its error bar); a 0 bar is drawn as a line in its colour so it shows."""
    for xi, h, top, text in zip(x, heights, tops, texts, strict=True):
        if h <= 0:
            ax.plot([xi - 0.45 * width, xi + 0.45 * width], [0.6, 0.6], color=colour, linewidth=3,
                    solid_capstyle="butt")
        ax.text(xi, top + 1.5, text, ha="center", va="bottom", fontsize=7 if width >= 0.2 else 6,
                linespacing=0.95)


def plot_success(runs: Sequence[RunRecord], path: Path, title: str) -> bool:
    """Grouped bar chart: success per task (x) and method (bars), mean over seeds with std bars; each
    bar says its value and how many episodes stand behind it, the legend each method's mIoU."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [r for r in runs if r.status == "ok" and r.data.get("per_task")]
    if not runs:
        return False
    methods = methods_in_order(runs)
    tasks: list[str] = []
    for run in runs:
        tasks += [t for t in run.data["per_task"] if t not in tasks]
    by_key = latest_per_method_seed(runs)
    mious = _method_mious(runs)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(tasks) * max(1, len(methods)) ** 0.5 + 2.5), 3.8))
    width = min(0.8 / len(methods), 0.4)  # one method: not one wide slab per task
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, m in enumerate(methods):
        means, stds, texts = [], [], []
        for task in tasks:
            cells = [r.data["per_task"][task] for (mm, _), r in by_key.items() if mm == m and task in r.data["per_task"]]
            mean, std = mean_std([c["success_rate"] for c in cells])
            means.append(100 * mean)
            stds.append(100 * std)
            done, total = sum(int(c["successes"]) for c in cells), sum(int(c["episodes"]) for c in cells)
            # one seed: its successes of its episodes; several: the episodes the mean stands on
            texts.append("" if not cells else f"{100 * mean:.0f}%\n{done}/{total}" if len(cells) == 1
                         else f"{100 * mean:.0f}%\nn={total}")
        x = np.arange(len(tasks)) + (i - (len(methods) - 1) / 2) * width
        spread = not all(np.isnan(stds))  # one seed has no std bar to draw
        label = f"{m} (mIoU {mious[m]:.1f})" if m in mious else m
        colour = colours[i % len(colours)]
        ax.bar(x, means, width, yerr=np.nan_to_num(stds) if spread else None, label=label, capsize=2,
               color=colour)
        tops = [mm + (np.nan_to_num(sd) if spread else 0) for mm, sd in zip(means, stds, strict=True)]
        _bar_labels(ax, x, np.nan_to_num(means), np.nan_to_num(tops), texts, colour, width)
    ax.set_xticks(np.arange(len(tasks)), [t.replace("_", "\n") for t in tasks], fontsize=7)
    _finish_percent_bars(fig, ax, "success (%)", title, path)
    return True


def plot_miou(runs: Sequence[RunRecord], path: Path, title: str) -> bool:
    """Decomposition mIoU against the expert per task (x) and method (bars), and their mean; each bar
    says its value and how many demos it averages."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [r for r in runs if r.status == "ok" and (r.data.get("decomposition") or {}).get("per_task")]
    if not runs:
        return False
    methods = methods_in_order(runs)
    by_key = latest_per_method_seed(runs)
    tasks: list[str] = []
    for run in runs:
        tasks += [t for t in run.data["decomposition"]["per_task"] if t not in tasks]
    groups = [*tasks, "mean"]
    fig, ax = plt.subplots(figsize=(max(5.0, 1.2 * len(groups) * max(1, len(methods)) ** 0.5 + 2.5), 3.6))
    width = min(0.8 / len(methods), 0.4)  # one method: not one wide slab per task
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, m in enumerate(methods):
        blocks = [r.data["decomposition"] for (mm, _), r in by_key.items() if mm == m]
        values, texts = [], []
        for g in groups:
            vals = [100 * float(b["miou"] if g == "mean" else b["per_task"][g]) for b in blocks
                    if (b.get("miou") if g == "mean" else b["per_task"].get(g)) is not None]
            # the demos behind the bar, over the method's seeds (results.json lists each demo)
            n = sum(1 for b in blocks for d in b.get("demos", []) if g == "mean" or d["task"] == g)
            values.append(float(np.mean(vals)) if vals else np.nan)
            texts.append("" if not vals else f"{np.mean(vals):.1f}" + (f"\nn={n}" if n else ""))
        x = np.arange(len(groups)) + (i - (len(methods) - 1) / 2) * width
        colour = colours[i % len(colours)]
        ax.bar(x, np.nan_to_num(values), width, label=m, color=colour)
        _bar_labels(ax, x, np.nan_to_num(values), np.nan_to_num(values), texts, colour, width)
    ax.axvline(len(tasks) - 0.5, color="0.7", linewidth=0.8)
    ax.set_xticks(np.arange(len(groups)), [g.replace("_", "\n") for g in groups], fontsize=7)
    _finish_percent_bars(fig, ax, "mIoU vs expert (%)", title, path)
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


def _finish_percent_bars(fig, ax, ylabel: str, title: str, path: Path) -> None:
    """The percent axis (room above 100 for the bar labels), title and legend of a bar plot; save it."""
    ax.set_ylabel(ylabel)
    ax.set_ylim(0, 118)
    ax.set_yticks(range(0, 101, 20))
    ax.set_title(title, fontsize=9)
    # beside the axes: inside, it covered the bars of the tasks near 100 %
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    fig.tight_layout()
    _save_fig(fig, path)
