"""The tables' figures say what a talk needs: each bar's value and episode count, a 0 % bar that
shows, each method's mIoU, and an mIoU comparison per method."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.report import plots
from experiments.report.results import RESULTS_FORMAT, load_runs, per_task_success


def _run(root: Path, name: str, method: str, seed: int, success: dict[str, list[bool]],
         miou: dict[str, list[float]]) -> None:
    episodes = [{"task": t, "seed": i, "success": s, "steps": 3, "instructions": ["a"]}
                for t, outcomes in success.items() for i, s in enumerate(outcomes)]
    demos = [{"task": t, "miou": v} for t, vals in miou.items() for v in vals]
    per_task = {t: sum(v) / len(v) for t, v in miou.items()}
    data = {"format": RESULTS_FORMAT, "status": "ok", "seed": seed,
            "choices": {"experiment": "quick", "decomposer": method}, "overrides": [f"decomposer={method}"],
            "episodes": episodes, "per_task": per_task_success(episodes),
            "decomposition": {"miou": sum(d["miou"] for d in demos) / len(demos), "per_task": per_task,
                              "num_demos": len(demos), "demos": demos}}
    (root / name).mkdir(parents=True)
    (root / name / "results.json").write_text(json.dumps(data))


@pytest.fixture
def drawn(tmp_path, monkeypatch):
    """The figures of a two-method run tree, kept open for inspection instead of saved."""
    _run(tmp_path, "a", "rdd", 0, {"open_drawer": [True, True, True, False], "push_buttons": [False] * 4},
         {"open_drawer": [0.8, 0.7, 0.9], "push_buttons": [0.6, 0.8, 0.7]})
    _run(tmp_path, "b", "uvd", 0, {"open_drawer": [True, False, False, False], "push_buttons": [True] * 4},
         {"open_drawer": [0.5, 0.4, 0.6], "push_buttons": [0.5, 0.5, 0.5]})
    figs = {}
    monkeypatch.setattr(plots, "_save_fig", lambda fig, path: figs.__setitem__(path.name, fig))
    runs = load_runs(tmp_path)
    assert plots.plot_success(runs, tmp_path / "s.png", "quick")
    assert plots.plot_miou(runs, tmp_path / "m.png", "quick")
    return {name: fig.axes[0] for name, fig in figs.items()}


def test_success_bars_say_value_and_episodes_and_the_legend_the_miou(drawn):
    ax = drawn["s.png"]
    texts = [t.get_text() for t in ax.texts]
    assert texts == ["75%\n3/4", "0%\n0/4", "25%\n1/4", "100%\n4/4"]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["rdd (mIoU 75.0)", "uvd (mIoU 50.0)"]
    # the 0 % bar of rdd on push_buttons is a line in rdd's colour at the baseline
    from matplotlib.colors import to_rgb

    (zero,) = [ln for ln in ax.lines if max(ln.get_ydata()) < 1]
    rdd_bar = ax.patches[1]  # rdd's push_buttons bar, 0 high
    assert rdd_bar.get_height() == 0 and to_rgb(zero.get_color()) == to_rgb(rdd_bar.get_facecolor())
    assert min(zero.get_xdata()) >= rdd_bar.get_x() and max(zero.get_xdata()) <= rdd_bar.get_x() + rdd_bar.get_width()


def test_miou_per_method_and_task_with_the_mean(drawn):
    ax = drawn["m.png"]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["open\ndrawer", "push\nbuttons", "mean"]
    assert [t.get_text() for t in ax.texts] == ["80.0\nn=3", "70.0\nn=3", "75.0\nn=6",
                                                 "50.0\nn=3", "50.0\nn=3", "50.0\nn=6"]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["rdd", "uvd"]
