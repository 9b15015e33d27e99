"""``python -m rdd evaluate``: score decompose outputs against ground truth; reading those outputs."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rdd.cli.common import check_output, log, write_json_atomic
from rdd.cli.options import force_arg
from rdd.errors import UsageError
from rdd.records import read_segments_file

# What each printed column is (rdd.metrics), for ``evaluate --help``.
COLUMNS = """columns (one row per method and episode, then the method's MEAN over its episodes):
  mIoU      the RDD paper's (official) mIoU: the mean over the PREDICTED segments of each one's best
            IoU with any ground-truth segment (a missed ground-truth segment costs nothing)
  sym-mIoU  symmetric mIoU: the mean of mIoU(pred, gt) and mIoU(gt, pred), which also penalises
            missed ground-truth segments
  bP bR bF1 boundary precision, recall and F1: cuts (segment starts after frame 0) matched one to
            one, a predicted cut with a ground-truth cut at most --tolerance frames away
  #seg      predicted segments"""


def pred_item(item: str) -> tuple[str, str]:
    """``LABEL=FILE`` -> (LABEL, FILE); a bare ``FILE`` (also one whose name holds ``=``) -> ("", FILE)."""
    label, sep, path = item.partition("=")
    if not sep or not label or Path(item).exists():
        return "", item
    return label, path


def pred_inputs(items: Sequence[str], flag: str = "--pred") -> list[tuple[str, str]]:
    """The files of ``--pred`` items as inputs of ``check_output``."""
    return [(flag, pred_item(item)[1]) for item in items]


def pred_methods(items: Sequence[str], flag: str = "--pred") -> dict[str, dict[str, dict[str, Any]]]:
    """``LABEL=FILE`` (or bare ``FILE``, labelled by its decomposer) -> {label: {episode: record}}.

    Files given the same explicit label (e.g. leave-one-out folds) are merged as episodes of one
    method; two unlabelled files whose decomposer is the same are an error (name them).
    """
    methods: dict[str, dict[str, dict[str, Any]]] = {}
    explicit: dict[str, bool] = {}
    for item in items:
        label, path = pred_item(item)
        named = bool(label)
        records = read_segments_file(path)
        if not named:
            config = json.loads(Path(path).read_text()).get("config") or {}
            label = str(config.get("decomposer") or Path(path).stem)
        if label in methods and not (named and explicit[label]):
            raise UsageError(f"{flag} {item}: a method is already labelled {label!r}; "
                           f"name them, e.g. {flag} a={path} b=other.json (same name = one method's folds)")
        explicit[label] = named
        merged = methods.setdefault(label, {})
        for name, rec in records.items():
            if name in merged:
                raise UsageError(f"{flag} {item}: episode {name!r} of method {label!r} came from an earlier file")
            merged[name] = rec
    return methods


def confidence_line(label: str, pred: dict[str, dict[str, Any]], gt: dict[str, dict[str, Any]]
                    ) -> tuple[str, dict[str, float]] | None:
    """For a method whose every shared episode has per-segment ``confidence``: one line with the
    AUROC of confidence against segments that match no ground-truth segment (best IoU < 0.5)."""
    from rdd.metrics import confidence_auroc

    shared = [name for name in gt if name in pred]
    if not shared or any(not isinstance(pred[n].get("confidence"), list) for n in shared):
        return None
    try:
        found = confidence_auroc([(pred[n]["segments"], pred[n]["confidence"], gt[n]["segments"]) for n in shared])
    except ValueError as exc:
        raise UsageError(f"--pred {label}: field 'confidence': {exc}") from exc
    return (f"{label}: confidence AUROC {found['auroc']:.3f} over {found['segments']:.0f} segments, "
            f"{found['doubtful']:.0f} of them with best IoU < 0.5 against --gt"), found


def cmd_evaluate(args: argparse.Namespace) -> int:
    """mIoU (paper and symmetric) and boundary P/R/F1 of each ``--pred`` method against ``--gt``."""
    from rdd.compare import compare_methods, format_table

    out = check_output(args.out, "--out", args.force, inputs=[*pred_inputs(args.pred), ("--gt", args.gt)])
    methods = pred_methods(args.pred)
    gt = read_segments_file(args.gt)
    try:
        result = compare_methods(methods, gt, args.tolerance, allow_partial=args.allow_partial)
    except ValueError as exc:
        raise UsageError(str(exc)) from exc
    for label, m in result["methods"].items():
        if m["left_out"]["pred_only"] or m["left_out"]["gt_only"]:
            log.warning("--pred %s: scored %d shared episodes; left out %s", label, m["num_episodes"],
                        m["left_out"])
    result.update(pred=list(args.pred), gt=str(args.gt))
    print(format_table(result))
    for label, pred in methods.items():
        line = confidence_line(label, pred, gt)
        if line:
            result["methods"][label]["confidence"] = line[1]
            print(line[0])
    if out is not None:
        write_json_atomic(out, result, overwrite=args.force)
    return 0


def add_parser(sub) -> None:
    """The ``evaluate`` subcommand and its options."""
    p = sub.add_parser("evaluate", help="compare decompose outputs (one or more methods) with ground truth",
                       description="Score each --pred method against --gt, episode by episode and on average.",
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=COLUMNS)
    p.add_argument("--pred", nargs="+", required=True, metavar="[LABEL=]FILE",
                   help="one decompose output per method, e.g. rdd=rdd.json uvd=uvd.json (same LABEL twice: "
                        "one method's folds)")
    p.add_argument("--gt", required=True, metavar="FILE",
                   help="the ground truth, a decompose output (or any JSON of the same episodes/segments form)")
    p.add_argument("--tolerance", type=int, default=2, metavar="FRAMES",
                   help="a predicted cut within this many frames of a ground-truth cut matches it (default 2)")
    p.add_argument("--allow-partial", action="store_true",
                   help="score only the episodes a method shares with --gt (default: differing sets are an error)")
    p.add_argument("--out", help="write the metrics JSON here (keys miou, symmetric_miou, boundary_precision, "
                                 "boundary_recall, boundary_f1, num_pred, num_gt per episode and mean)")
    force_arg(p)
    p.set_defaults(func=cmd_evaluate)
