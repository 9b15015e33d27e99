"""PNG plots of an experiment's runs: success per task and method, solver time versus frames."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from experiments.report.results import RunRecord
from experiments.report.table_builders import latest_per_method_seed, methods_in_order, speed_table
from experiments.report.table_format import mean_std


def plot_success(runs: Sequence[RunRecord], path: Path, title: str) -> bool:
    """Grouped bar chart: success per task (x) and method (bars), mean over seeds with std bars."""
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
        spread = not all(np.isnan(stds))  # one seed has no std bar to draw
        ax.bar(x, means, width, yerr=np.nan_to_num(stds) if spread else None, label=m, capsize=2)
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
