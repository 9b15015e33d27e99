"""Segmentation metrics: the RDD paper's mIoU, its symmetric form, boundary precision/recall/F1."""

from __future__ import annotations

from collections.abc import Sequence

from rdd.segments import Segment, boundaries, validate_segments


def segment_iou(a: Segment, b: Segment) -> float:
    """Intersection over union of two half-open frame intervals."""
    inter = max(0, min(a[1], b[1]) - max(a[0], b[0]))
    union = (a[1] - a[0]) + (b[1] - b[0]) - inter
    return inter / union if union > 0 else 0.0


def _check(segments: Sequence[Segment], what: str) -> list[Segment]:
    out = [(int(s), int(e)) for s, e in segments]
    if not out:
        raise ValueError(f"{what} segmentation is empty")
    for s, e in out:
        if e <= s:
            raise ValueError(f"{what} segment {(s, e)} is empty")
    return out


def miou(pred: Sequence[Segment], gt: Sequence[Segment]) -> float:
    """Mean over predicted segments of their best IoU with any ground-truth segment (RDD paper)."""
    p, g = _check(pred, "predicted"), _check(gt, "ground-truth")
    return sum(max(segment_iou(a, b) for b in g) for a in p) / len(p)


def symmetric_miou(pred: Sequence[Segment], gt: Sequence[Segment]) -> float:
    """Mean of ``miou(pred, gt)`` and ``miou(gt, pred)``: also penalises missed GT segments."""
    return 0.5 * (miou(pred, gt) + miou(gt, pred))


def boundary_scores(
    pred: Sequence[Segment], gt: Sequence[Segment], tolerance: int = 0
) -> dict[str, float]:
    """Precision, recall and F1 of predicted cut points within ``tolerance`` frames of GT cuts.

    Cuts are matched one-to-one (a maximum matching), so duplicates do not count twice.
    Two segmentations with no cut at all agree perfectly.
    """
    if tolerance < 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance}")
    pb = boundaries(_check(pred, "predicted"))
    gb = boundaries(_check(gt, "ground-truth"))
    # 1-D sweep: each predicted cut (ascending) takes the earliest unmatched GT cut within the
    # tolerance; for points on a line this gives a maximum one-to-one matching.
    gs = sorted(gb)
    j = 0
    hits = 0
    for a in sorted(pb):
        while j < len(gs) and gs[j] < a - tolerance:
            j += 1
        if j < len(gs) and gs[j] <= a + tolerance:
            hits += 1
            j += 1
    precision = hits / len(pb) if pb else (1.0 if not gb else 0.0)
    recall = hits / len(gb) if gb else (1.0 if not pb else 0.0)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {"precision": precision, "recall": recall, "f1": f1, "matched": float(hits)}


def evaluate_segmentation(
    pred: Sequence[Segment], gt: Sequence[Segment], tolerance: int = 0, num_frames: int | None = None
) -> dict[str, float]:
    """All metrics for one episode; with ``num_frames`` both must partition ``[0, num_frames)``."""
    if num_frames is not None:
        pred = validate_segments(pred, num_frames)
        gt = validate_segments(gt, num_frames)
    b = boundary_scores(pred, gt, tolerance)
    return {
        "miou": miou(pred, gt),
        "symmetric_miou": symmetric_miou(pred, gt),
        "boundary_precision": b["precision"],
        "boundary_recall": b["recall"],
        "boundary_f1": b["f1"],
        "num_pred": float(len(pred)),
        "num_gt": float(len(gt)),
    }
