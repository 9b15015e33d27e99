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


def auroc(scores: Sequence[float], positive: Sequence[bool]) -> float:
    """Area under the ROC curve: the chance that a positive scores above a negative (ties half);
    NaN without both kinds."""
    s = [float(x) for x in scores]
    pos = [x for x, p in zip(s, positive, strict=True) if p]
    neg = [x for x, p in zip(s, positive, strict=True) if not p]
    if not pos or not neg:
        return float("nan")
    wins = sum((a > b) + 0.5 * (a == b) for a in pos for b in neg)
    return wins / (len(pos) * len(neg))


def confidence_auroc(episodes: Sequence[tuple[Sequence[Segment], Sequence[float], Sequence[Segment]]],
                     doubtful_below: float = 0.5) -> dict[str, float]:
    """How well per-segment confidences separate the segments that match a ground-truth segment
    (best IoU >= ``doubtful_below``) from those that match none: AUROC over every segment of
    ``episodes`` (pred segments, their confidences, ground truth) with a confidence (a person's
    segment, after review, has None), and the counts."""
    conf, good = [], []
    for pred, confidence, gt in episodes:
        p, g = _check(pred, "predicted"), _check(gt, "ground-truth")
        if len(confidence) != len(p):
            raise ValueError(f"{len(confidence)} confidences for {len(p)} segments")
        for a, c in zip(p, confidence, strict=True):
            if c is not None:
                conf.append(float(c))
                good.append(max(segment_iou(a, b) for b in g) >= doubtful_below)
    return {"auroc": auroc(conf, good), "segments": float(len(good)), "doubtful": float(len(good) - sum(good))}
