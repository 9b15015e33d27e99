"""Our tables beside the paper's figures (:mod:`.paper_figures`): which paper table and row each
experiment and method of ours corresponds to, and the table that pairs them row by row."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from experiments.report.paper_figures import PAPER_TABLES, TASKS, PaperTable
from experiments.report.table_builders import average_ranks
from experiments.report.table_format import Table


@dataclass(frozen=True)
class Spec:
    """How one experiment of ours lines up with the paper: its tables and its rows."""

    summary: str  # label of the paper table whose averages stand beside ours
    per_task: str | None  # label of the paper table with the per-task figures
    rows: dict[str, str]  # our method label -> the paper's row
    kind: str = "success"  # which table of ours is compared: "success" or "miou"
    avg_column: str = "Avg. Succ."
    rank_column: str | None = "Avg. Rank"
    scale: float = 1.0  # the paper's unit -> ours (its IoU is a fraction, our mIoU a %)
    drop: tuple[str, ...] = field(default=())  # label parts the paper does not distinguish


_MAIN = {"expert": "Expert", "rdd": "RDD (Ours)", "uvd": "UVD", "uniform": "Uniform",
         "none": "w/o Finetune"}
_ENCODERS = {"liv": "LIV", "r3m": "R3M", "vip": "VIP", "vc1": "VC-1", "clip": "CLIP",
             "dinov2": "DINOv2", "resnet": "ResNet"}

SPECS: dict[str, Spec] = {
    "table_main": Spec("tab-main", "tab-main-add", _MAIN),
    "table_main_full": Spec("tab-main", "tab-main-add", _MAIN),
    "abl_alpha": Spec("tab-abl-alpha", "tab-abl-alpha-add",
                      {f"alpha={a}": a for a in ("0", "0.5", "1", "2")}),
    "abl_encoder": Spec("tab-abl-enc", "tab-abl-enc-add", _ENCODERS),
    # The paper's one-demo row averages its three single-demo sets; ours lists each set.
    "abl_demos": Spec("tab-abl-ep", "tab-abl-ep-add",
                      {"rdd": "3 (RDD)", "rdd, M=3": "3 (RDD)", "uvd": "3 (UVD)",
                       "uvd, M=3": "3 (UVD)", "rdd, M=1": "1 (RDD)"}, drop=("first demo=",)),
    "abl_ood_beta": Spec("tab-abl-realworld-libero", None,
                         {"beta=0.05": "RDD (beta=0.05)", "beta=0.1": "RDD (beta=0.10)",
                          "beta=0.25": "RDD (beta=0.25)", "uvd": "UVD"},
                         kind="miou", avg_column="LIBERO (OOD)", rank_column=None, scale=100.0),
    "necessity": Spec("tab-main-pretrain-planner", "tab-main-pretrain-planner-multi-task",
                      {"other_tasks": "w/o finetuning on target task", "rdd": "RDD (Ours)"}),
}
# Experiments whose nearest paper table measures something else: shown as the paper prints it.
VERBATIM = {"abl_backend": "tab-faiss_rdd"}
_EXTRA_COLUMNS = ("s / demo", "novelty Δ")  # columns of ours that are not per-task figures


def paper_row(spec: Spec, label: str) -> str | None:
    """The paper's row for our method ``label`` in ``spec``'s tables, or None (no counterpart)."""
    parts = [p for p in label.split(", ") if not p.startswith(spec.drop)]
    return spec.rows.get(", ".join(parts))


def _leading_number(text: str) -> float:
    number = re.match(r"-?\d+(\.\d+)?", text.strip("* "))
    return float(number.group()) if number else math.nan


def _rank_cells(values: list[float]) -> list[str]:
    """Average ranks (highest first) of the finite values, as text; '–' for the others."""
    finite = [v for v in values if not math.isnan(v)]
    ranks = iter(average_ranks(finite)) if finite else iter(())
    return ["–" if math.isnan(v) else f"{next(ranks):g}" for v in values]


def _note(spec: Spec, summary: PaperTable, per_task: PaperTable | None, rows: list[str]) -> str:
    unit = " (the paper's IoU × 100)" if spec.scale != 1.0 else ""
    note = (f"Paper: {spec.avg_column}{unit}"
            + (f" and {spec.rank_column}" if spec.rank_column else "")
            + f" from its table {summary.label} (\"{summary.caption}\")")
    if per_task is not None:
        note += f", per task from {per_task.label} (\"{per_task.caption}\")"
        if "Avg. Succ." in per_task.columns and per_task is not summary:
            avgs = ", ".join(f"{r} {per_task.cell(r, 'Avg. Succ.')}" for r in dict.fromkeys(rows))
            note += f"; that table's averages over all its tasks: {avgs}" if avgs else ""
    return (note + ". The paper averages over its own tasks, not over the columns here; – where "
            "the paper has no counterpart. Rank here / in paper: each method's place by its "
            "average among the methods with a counterpart, in our runs and in the paper (ties "
            "share the mean rank).")


def beside_paper(experiment: str, title: str, ours: Table | None) -> Table | None:
    """``ours`` (the experiment's success or mIoU table) with the paper's row under each method."""
    spec = SPECS.get(experiment)
    if spec is None or ours is None:
        return None
    summary = PAPER_TABLES[spec.summary]
    per_task = PAPER_TABLES[spec.per_task] if spec.per_task else None
    head = ours.header
    avg_at = 1
    rank_at = 2 if len(head) > 2 and head[2].startswith("Avg. Rank") else None
    first_task = 3 if rank_at else 2
    tasks = [h for h in head[first_task:] if h not in _EXTRA_COLUMNS]
    task_at = [head.index(t) for t in tasks]
    matched = [paper_row(spec, row[0]) for row in ours.rows]
    ours_avg = [_leading_number(row[avg_at]) if m else math.nan
                for row, m in zip(ours.rows, matched, strict=True)]
    paper_avg = [(summary.mean(m, spec.avg_column) or math.nan) if m else math.nan for m in matched]
    rank_here, rank_paper = _rank_cells(ours_avg), _rank_cells(paper_avg)

    header = ["Method", "Figures", "Rank here", "Rank in paper", head[avg_at].rstrip(" ↑")]
    header += ["Avg. Rank"] if spec.rank_column else []
    header += tasks
    rows = []
    for i, (row, m) in enumerate(zip(ours.rows, matched, strict=True)):
        mine = [row[0], "here", rank_here[i], rank_paper[i], row[avg_at]]
        mine += [row[rank_at] if rank_at else "–"] if spec.rank_column else []
        rows.append(mine + [row[c] for c in task_at])
        theirs = [m or "–", "paper", "", "", _paper_avg(spec, summary, m)]
        theirs += [(m and summary.cell(m, spec.rank_column)) or "–"] if spec.rank_column else []
        theirs += [(m and per_task and per_task.cell(m, TASKS.get(t, t))) or "–" for t in tasks]
        rows.append(theirs)
    note = _note(spec, summary, per_task, [m for m in matched if m])
    return Table(title, header, rows, set(), note)


def _paper_avg(spec: Spec, table: PaperTable, row: str | None) -> str:
    if row is None or table.cell(row, spec.avg_column) is None:
        return "–"
    if spec.scale == 1.0:
        return str(table.cell(row, spec.avg_column))
    return f"{table.mean(row, spec.avg_column) * spec.scale:.1f}"


def paper_verbatim(experiment: str, title: str) -> Table | None:
    """The paper's nearest table for an experiment with no counterpart of ours, as printed."""
    label = VERBATIM.get(experiment)
    if label is None:
        return None
    paper = PAPER_TABLES[label]
    rows = [[name, *cells] for name, cells in paper.rows.items()]
    note = (f"The paper's table {label} (\"{paper.caption}\"), as printed: it times one index on a "
            "GPU and reports no decomposition quality, so no row of ours has a counterpart in it.")
    return Table(title, ["Paper", *paper.columns], rows, set(), note)
