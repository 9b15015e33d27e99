"""The summary blocks of ``results.json`` computed from a run's rows: decomposition mIoU, planner
exact match (overall and where only the image tells), the main metric and the tracker's metrics."""

from __future__ import annotations

from typing import Any

import numpy as np


def main_metric(results: dict[str, Any]) -> float | None:
    """Average success; planner exact match for planner-eval runs; mIoU for decomposition runs."""
    if results.get("average_success") is not None:
        return results["average_success"]
    pe = results.get("planner_eval") or {}
    if pe:
        return pe.get("finetuned_exact_match", pe.get("base_exact_match"))
    return (results.get("decomposition") or {}).get("miou")


def tracker_metrics(results: dict[str, Any]) -> dict[str, Any]:
    """The flat metrics a tracker (wandb) logs for a run."""
    out: dict[str, Any] = {}
    if results.get("average_success") is not None:
        out["success/average"] = results["average_success"]
    for task, row in (results.get("per_task") or {}).items():
        out[f"success/{task}"] = row["success_rate"]
    for name in ("base", "finetuned"):
        value = (results.get("planner_eval") or {}).get(f"{name}_exact_match")
        if value is not None:
            out[f"planner/{name}_exact_match"] = value
    dec = results.get("decomposition") or {}
    if dec.get("miou") is not None:
        out["decomposition/miou"] = dec["miou"]
    for name, t in (results.get("timings") or {}).items():
        out[f"time/{name}"] = t["seconds"]
    return out


def decomposition_block(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """mIoU over the decomposed demos, per task, and each demo's row."""
    per_task: dict[str, list[float]] = {}
    for r in rows:
        per_task.setdefault(r["task"], []).append(r["miou"])
    return {
        "miou": float(np.mean([r["miou"] for r in rows])) if rows else None,
        "per_task": {t: float(np.mean(v)) for t, v in per_task.items()},
        "num_demos": len(rows),
        "demos": [{k: r[k] for k in ("episode", "task", "num_frames", "segments", "instructions",
                                     "expert_segments", "miou", "novelty", "seconds")} for r in rows],
    }



def image_dependent(rows: list[dict[str, Any]]) -> list[bool]:
    """Per boundary: whether its text cannot settle it, i.e. another boundary of the same task with
    the same goal and previous instruction has a different target (only the image tells them apart)."""
    targets: dict[tuple, set[str]] = {}
    for r in rows:
        targets.setdefault((r["task"], r["goal"], r["previous"]), set()).add(r["target"])
    return [len(targets[(r["task"], r["goal"], r["previous"])]) > 1 for r in rows]


def _rate(rows: list[dict[str, Any]], name: str) -> float | None:
    return float(np.mean([r[f"{name}_hit"] for r in rows])) if rows else None


def planner_eval_block(rows: list[dict[str, Any]], tasks: list[str], finetuned: bool) -> dict[str, Any]:
    """Exact-match rates of the base (and finetuned) planner, overall, per task and image-dependent."""
    names = ["base", "finetuned"] if finetuned else ["base"]
    for r, dep in zip(rows, image_dependent(rows), strict=True):
        r["image_dependent"] = dep
    dep_rows = [r for r in rows if r["image_dependent"]]
    per_task = {}
    for task in tasks:
        rs = [r for r in rows if r["task"] == task]
        ds = [r for r in rs if r["image_dependent"]]
        per_task[task] = {"boundaries": len(rs), **{n: _rate(rs, n) for n in names},
                          "image_dependent": {"boundaries": len(ds), **{n: _rate(ds, n) for n in names},
                                              "which": sorted({(r["previous"], r["target"]) for r in ds})}}
    block: dict[str, Any] = {
        "per_task": per_task,
        "boundaries": len(rows),
        **{f"{n}_exact_match": _rate(rows, n) for n in names},
        "image_dependent_boundaries": len(dep_rows),
        **{f"{n}_image_dependent": _rate(dep_rows, n) for n in names},
        "misses": [r for r in rows if not r.get("finetuned_hit", r["base_hit"])],
    }
    if rows and all("scene" in r for r in rows):  # describe_scene: how often the stated scene was true
        block["scene_exact_match"] = float(np.mean([r["scene"] == r["scene_true"] for r in rows]))
        if dep_rows:
            block["scene_image_dependent"] = float(np.mean([r["scene"] == r["scene_true"] for r in dep_rows]))
    return block
