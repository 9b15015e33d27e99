"""``python -m rdd plot``: a timeline figure of decompose outputs with keyframe thumbnails."""

from __future__ import annotations

import argparse

from rdd.cli.common import check_output, load_data
from rdd.cli.evaluate import pred_inputs, pred_methods
from rdd.cli.options import data_args, force_arg, with_reader_help
from rdd.errors import UsageError
from rdd.records import read_segments_file


def cmd_plot(args: argparse.Namespace) -> int:
    """Timeline figure: one row per method (and ground truth), keyframe thumbnails."""
    from rdd.plots.timeline import figure_format, plot_timelines

    out = check_output(args.out, "--out", args.force,
                       inputs=[*pred_inputs(args.pred), ("--gt", args.gt), ("--data", args.data)])
    try:
        figure_format(out)
    except ValueError as exc:
        raise UsageError(f"--out {exc}") from exc
    labels = args.labels or []
    if labels and len(labels) != len(args.pred):
        raise UsageError(f"--labels: {len(labels)} labels for {len(args.pred)} --pred files")
    items = [f"{lab}={p}" for lab, p in zip(labels, args.pred, strict=True)] if labels else args.pred
    methods = pred_methods(items)
    rows = {label: dict(recs) for label, recs in methods.items()}  # records: segments and instructions
    # only the episodes drawn are read: another episode's files are never opened (nor its warnings printed)
    wanted = set(args.episode or ()) or {n for r in rows.values() for n in r}
    episodes = {e.name: e for e in load_data(args, only=wanted)}
    gt = dict(read_segments_file(args.gt)) if args.gt else {}
    names = args.episode or [n for n in episodes if any(n in r for r in rows.values())]
    if not names:
        raise UsageError(f"--pred files share no episode with --data {args.data}")
    panels = []
    for name in names:
        if name not in episodes:
            raise UsageError(f"--episode {name!r} is not in --data {args.data}")
        ep_rows = {label: r[name] for label, r in rows.items() if name in r}
        ep = episodes[name]
        truth = gt.get(name) or ({"segments": ep.segments, "instructions": ep.instructions}
                                 if ep.segments else None)
        panels.append((ep, ep_rows, truth))
    out = plot_timelines(panels, out, view=args.view, gt_label=args.gt_label, overwrite=args.force)
    print(f"wrote {out}")
    return 0


def add_parser(sub) -> None:
    """The ``plot`` subcommand and its options."""
    p = sub.add_parser("plot", help="timeline figure of one or more decompose outputs", **with_reader_help())
    p.add_argument("--pred", nargs="+", required=True, metavar="[LABEL=]FILE")
    data_args(p)
    p.add_argument("--gt", help="ground-truth decompose output (default: the episodes' own segments)")
    p.add_argument("--gt-label", default="ground truth")
    p.add_argument("--labels", nargs="+", help="row labels, one per --pred file")
    p.add_argument("--episode", nargs="+", help="episodes to draw (default: all in --pred)")
    p.add_argument("--view", help="camera view for thumbnails (default: the first)")
    p.add_argument("--out", required=True, help="figure file: .png, .pdf or .svg")
    force_arg(p)
    p.set_defaults(func=cmd_plot)
