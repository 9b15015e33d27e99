"""``python -m rdd calibrate``: rerun a saved database's leave-one-episode-out calibration."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rdd.cli.aliases import add_index_arg
from rdd.errors import UsageError
from rdd.progress import progress


def _grid_values(text: str | None, flag: str, cast) -> list | None:
    if text is None:
        return None
    values = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        try:
            values.append(None if item.lower() == "none" else cast(item))
        except ValueError as exc:
            raise UsageError(f"{flag} {text!r}: {item!r} is not a valid value") from exc
    if not values:
        raise UsageError(f"{flag} {text!r}: the grid is empty (give comma-separated values)")
    return values


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Rerun leave-one-episode-out calibration on a saved database; record it in its manifest."""
    from rdd.core.calibrate import CalibrationError, calibrate, default_grid, summary
    from rdd.database.model import SubtaskDatabase

    db = SubtaskDatabase.load(args.db)
    grid = default_grid(db)
    for key, flag, cast in (("alpha", "--alpha", float), ("min_len", "--min-len", int),
                            ("max_len", "--max-len", int)):
        values = _grid_values(getattr(args, key), flag, cast)
        if values is not None:
            grid[key] = values
    try:
        cal = calibrate(db, grid=grid, sample=args.sample, seed=args.seed, index=args.index,
                        progress=lambda xs: progress(xs, "calibration", leave=True))
    except CalibrationError as exc:
        typed = getattr(args, exc.option or "", None)  # a grid value given with --alpha etc.
        if typed is not None:
            raise UsageError(f"--{exc.option.replace('_', '-')} {typed}: {exc}") from exc
        raise UsageError(f"--db {args.db}: {exc}") from exc
    if cal is None:
        print(f"warning: calibration skipped: --db {args.db} holds one episode, nothing to leave out",
              file=sys.stderr)
        return 0
    db.save_calibration(cal)
    print(summary(cal))
    print(f"recorded in {Path(args.db) / 'manifest.json'}")
    return 0


def add_parser(sub) -> None:
    """The ``calibrate`` subcommand and its options."""
    p = sub.add_parser("calibrate", help="rerun leave-one-episode-out calibration of a database")
    p.add_argument("--db", required=True, help="database directory (built without --no-calibrate)")
    p.add_argument("--alpha", help="comma-separated alpha grid (default 0,0.1,0.25,0.5,1,2)")
    p.add_argument("--min-len", help="comma-separated min_len grid (default 2,4, half the shortest stored "
                   "sub-task, the shortest, a quarter and half the median)")
    p.add_argument("--max-len", help="comma-separated max_len grid, 'none' = unbounded "
                   "(default none and 1.25x, 2x the longest stored segment)")
    p.add_argument("--sample", type=int, default=10, help="episodes held out in turn (default 10)")
    p.add_argument("--seed", type=int, default=0)
    add_index_arg(p, "retrieval index for calibration: exact, annoy or faiss")
    p.set_defaults(func=cmd_calibrate)
