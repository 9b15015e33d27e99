"""``python -m rdd``: build a sub-task database, decompose demonstrations, evaluate, plot.

Subcommands: ``build-db``, ``calibrate``, ``decompose``, ``evaluate``, ``plot``, ``demo``, ``serve``, ``review``. Every expected failure
is reported as one line naming the file or option at fault, with exit status 2 (``-v`` also prints
the traceback); Ctrl-C stops with status 130 and SIGTERM with 143, both leaving no partial output and
no temporary copy (``decompose`` and ``build-db`` keep the episodes they finished beside it, so the same
command resumes: ``rdd.batch.staging``). A full disk is one line naming the file and its role (output,
database, staging, cache).
Outputs are written atomically, never replace an existing file or folder without ``--force``, and never
replace or go inside an input of the same command, ``--force`` or not.
"""

from __future__ import annotations

import argparse
import logging
import pickle
import sys
import traceback
from collections.abc import Sequence

from rdd.atomic import FULL_ERRNOS
from rdd.cli import build_db, calibrate, decompose, demo, evaluate, plot, review, serve
from rdd.cli.common import full_disk
from rdd.errors import Terminated, UsageError, interrupt_on_sigterm, restore_sigterm

# One module per subcommand, each adding its own parser; the order is the order of ``--help``.
SUBCOMMANDS = (build_db, calibrate, decompose, evaluate, plot, demo, serve, review)


def build_parser(prog: str = "rdd") -> argparse.ArgumentParser:
    """The argument parser of the ``rdd`` script, its usage lines naming the program as ``prog``."""
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log each step, and print the traceback of an error")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in SUBCOMMANDS:
        module.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None, prog: str = "rdd") -> int:
    """Entry point of the ``rdd`` script and, with ``prog="python -m rdd"``, of ``python -m rdd``."""
    try:
        parser = build_parser(prog)
    except ImportError as exc:  # a module of RDD_PLUGINS that cannot be imported: the registry names it
        print(f"error: {exc}", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    previous = interrupt_on_sigterm()  # restored on return: main() may run inside another program
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt as exc:
        resumes = " (the episodes it finished are kept: the same command resumes)" \
            if args.command in ("decompose", "build-db") else ""
        how = "terminated" if isinstance(exc, Terminated) else "interrupted"
        by = " by SIGTERM" if isinstance(exc, Terminated) else ""
        print(f"\n{how} ({args.command}): stopped{by}; no partial output was written{resumes}", file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    except UsageError as exc:
        return _report(args, str(exc), "error")
    except (FileNotFoundError, KeyError, ValueError, ImportError, RuntimeError, OSError,
            pickle.UnpicklingError) as exc:
        # Library errors already name the file/field at fault; show them without a traceback.
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        if isinstance(exc, OSError) and exc.errno in FULL_ERRNOS:
            msg = full_disk(args, exc)
        return _report(args, str(msg), f"error ({args.command})")
    finally:
        restore_sigterm(previous)


def _report(args: argparse.Namespace, message: str, prefix: str) -> int:
    """Print an expected error as one line (after its traceback with -v); exit status 2."""
    if args.verbose:
        traceback.print_exc()
    print(f"{prefix}: {message}", file=sys.stderr)
    return 2


# The name this error had before it moved to rdd.errors; kept for callers of rdd.cli.
CLIError = UsageError

__all__ = ["CLIError", "UsageError", "build_parser", "main"]
