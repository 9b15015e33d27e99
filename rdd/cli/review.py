"""``python -m rdd review``: check and fix decompositions in a local web page (``rdd.review``).

The page lists the episodes of ``--pred`` lowest confidence first; an episode shows its frames, its
segments coloured by confidence, the robot's signals, and the matched database entry's frames
(``--db``). Edits are saved to ``--out`` (never the input, never over a file without ``--force``).
"""

from __future__ import annotations

import argparse
import sys
import webbrowser
from pathlib import Path

from rdd.cli.common import check_output, parse_options
from rdd.cli.options import force_arg
from rdd.core.confidence import REVIEW_BELOW
from rdd.data.load import formats
from rdd.errors import UsageError


def default_out(pred: str) -> Path:
    """``rdd.json`` -> ``rdd.reviewed.json`` beside it."""
    path = Path(pred)
    return path.with_name(f"{path.stem}.reviewed{path.suffix or '.json'}")


def make_session(args: argparse.Namespace):
    """The review session of the command's arguments (errors: one line naming the file or option)."""
    from rdd.review.session import ReviewSession

    if not 0.0 <= args.review_below <= 1.0:
        raise UsageError(f"--review-below {args.review_below:g}: a confidence is in [0, 1]")
    out = args.out or str(default_out(args.pred))
    inputs = [("--pred", args.pred), ("--data", args.data), ("--db", args.db)]
    checked = check_output(out, "--out", args.force, inputs=inputs)
    if not Path(args.data).exists():
        raise UsageError(f"--data {args.data}: no such file or folder")
    return ReviewSession(args.format, args.data, args.pred, checked, db=args.db,
                         reader_options=parse_options(args.reader_option, "--reader-option"),
                         review_below=args.review_below, force=args.force)


def cmd_review(args: argparse.Namespace) -> int:
    """Load the session (errors before any port opens), then serve the page until Ctrl-C."""
    if not 0 < args.port < 65536:
        raise UsageError(f"--port {args.port}: must be in 1..65535")
    try:
        import uvicorn
    except ImportError as exc:
        raise ImportError(f"review needs FastAPI and uvicorn: pip install 'rdd[serve]' ({exc})") from exc
    from rdd.review.app import create_app

    session = make_session(args)
    app = create_app(session)
    url = f"http://{args.host}:{args.port}/"
    page = session.page()
    print(f"reviewing {page['episodes']} episodes of {args.pred} ({page['flagged']} below {args.review_below:g}) "
          f"at {url}; edits are saved to {session.out}; Ctrl-C stops", file=sys.stderr, flush=True)
    if not args.no_browser:
        webbrowser.open(url)
    uvicorn.run(app, host=args.host, port=args.port, log_level="info" if args.verbose else "warning")
    return 0


def add_parser(sub) -> None:
    """The ``review`` subcommand and its options."""
    p = sub.add_parser("review", help="check and fix decompositions in a local web page",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("--format", choices=formats(), required=True, help="episode format of --data")
    p.add_argument("--data", required=True, help="the episodes --pred decomposed (one or a folder)")
    p.add_argument("--reader-option", action="append", metavar="KEY=VALUE", help="reader keyword, as for decompose")
    p.add_argument("--pred", required=True, help="a decompose output (or a reviewed file) of --data")
    p.add_argument("--db", help="the database rdd matched against: shows each segment's matched entry's frames")
    p.add_argument("--out", help="where saving writes (default PRED.reviewed.json beside --pred)")
    p.add_argument("--review-below", type=float, default=REVIEW_BELOW, metavar="C",
                   help=f"flag episodes with a segment of confidence below C (default {REVIEW_BELOW:g})")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8002, help="port (default 8002)")
    p.add_argument("--no-browser", action="store_true", help="do not open the page in a browser")
    force_arg(p)
    p.set_defaults(func=cmd_review)
