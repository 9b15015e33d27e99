"""``python -m rdd demo``: the end-to-end demo on a synthetic world (``rdd.demo``)."""

from __future__ import annotations

import argparse
import json

from rdd.cli.aliases import add_index_arg
from rdd.cli.common import check_output, write_json_atomic
from rdd.cli.options import force_arg
from rdd.errors import UsageError


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the end-to-end demo (``rdd.demo.run_demo``)."""
    try:
        from rdd.demo import run_demo
    except ImportError as exc:
        raise UsageError(f"demo: rdd.demo is not available ({exc})") from exc
    check_output(args.json, "--json", args.force)
    result = run_demo(seed=args.seed, index=args.index)  # prints its own summary
    if args.json:
        write_json_atomic(args.json, json.loads(json.dumps(result, default=str)), overwrite=args.force)
        print(f"wrote {args.json}")
    return 0


def add_parser(sub) -> None:
    """The ``demo`` subcommand and its options."""
    p = sub.add_parser("demo", help="run the end-to-end demo")
    p.add_argument("--seed", type=int, default=0)
    add_index_arg(p, "retrieval index: exact, annoy or faiss")
    p.add_argument("--json", help="also write the demo's summary here")
    force_arg(p)
    p.set_defaults(func=cmd_demo)
