"""Several segmentation methods against one ground truth: validated, per episode and averaged."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rdd.metrics import evaluate_segmentation

Records = Mapping[str, Mapping[str, Any]]  # episode name -> decompose-output record


def compare_methods(methods: Mapping[str, Records], gt: Records, tolerance: int = 2,
                    allow_partial: bool = False) -> dict[str, Any]:
    """Metrics of every method on every episode it shares with ``gt``, and their means.

    Each segmentation must partition ``[0, num_frames)`` of its record. The episode sets of every
    method and of ``gt`` must be equal unless ``allow_partial`` (then only shared ones count,
    and the result lists what was left out).
    """
    if not methods:
        raise ValueError("no predictions to evaluate")
    out: dict[str, Any] = {"tolerance": tolerance, "methods": {}}
    for label, pred in methods.items():
        only_pred, only_gt = sorted(set(pred) - set(gt)), sorted(set(gt) - set(pred))
        if (only_pred or only_gt) and not allow_partial:
            raise ValueError(
                f"--pred {label} and --gt cover different episodes (only in --pred: {only_pred or 'none'}; "
                f"only in --gt: {only_gt or 'none'}); pass --allow-partial to score the shared ones"
            )
        shared = [name for name in gt if name in pred]
        if not shared:
            raise ValueError(f"--pred {label} shares no episode with --gt")
        per_episode = {}
        for name in shared:
            p, g = pred[name], gt[name]
            n_pred, n_gt = p.get("num_frames"), g.get("num_frames")
            if n_pred != n_gt:
                raise ValueError(f"episode {name!r}: --pred {label} has {n_pred} frames, --gt {n_gt}")
            if not isinstance(n_gt, int) or n_gt < 1:
                raise ValueError(f"episode {name!r}: --gt record has no valid 'num_frames' ({n_gt!r})")
            for what, rec in ((f"--pred {label}", p), ("--gt", g)):
                try:
                    evaluate_segmentation(rec["segments"], rec["segments"], 0, num_frames=n_gt)
                except (ValueError, TypeError) as exc:
                    raise ValueError(f"episode {name!r} in {what}: segments are not a partition of "
                                     f"[0, {n_gt}): {exc}") from exc
            per_episode[name] = evaluate_segmentation(p["segments"], g["segments"], tolerance, num_frames=n_gt)
        keys = list(next(iter(per_episode.values())))
        mean = {k: sum(m[k] for m in per_episode.values()) / len(per_episode) for k in keys}
        out["methods"][label] = {"num_episodes": len(per_episode), "mean": mean, "episodes": per_episode,
                                 "left_out": {"pred_only": only_pred, "gt_only": only_gt}}
    return out


def format_table(result: Mapping[str, Any], per_episode: bool = True) -> str:
    """A plain-text table: one row per method (mean), optionally one per method and episode."""
    rows = []
    for label, m in result["methods"].items():
        if per_episode:  # also for one episode: the row names it, as `evaluate --help` promises
            rows += [(label, name, e) for name, e in m["episodes"].items()]
        rows.append((label, f"MEAN ({m['num_episodes']} ep)", m["mean"]))
    lw = max(6, *(len(r[0]) for r in rows))
    ew = max(7, *(len(r[1]) for r in rows))
    lines = [f"{'method':<{lw}}  {'episode':<{ew}}  mIoU   sym-mIoU  bP     bR     bF1    #seg"]
    for label, name, m in rows:
        lines.append(f"{label:<{lw}}  {name:<{ew}}  {m['miou']:.3f}  {m['symmetric_miou']:.3f}     "
                     f"{m['boundary_precision']:.3f}  {m['boundary_recall']:.3f}  {m['boundary_f1']:.3f}  "
                     f"{m['num_pred']:.1f}")
    return "\n".join(lines)
