"""The argument groups several subcommands share, and the reader options listed in ``--help``."""

from __future__ import annotations

import argparse
from typing import Any

from rdd.data.load import formats
from rdd.errors import UsageError


def data_args(p: argparse.ArgumentParser, data_required: bool = True) -> None:
    """``--format``, ``--data``, ``--reader-option``, ``--include``, ``--exclude``."""
    p.add_argument("--format", choices=formats(), required=True, help="episode format of --data")
    p.add_argument("--data", required=data_required, help="one episode or a folder of episodes")
    p.add_argument("--reader-option", action="append", metavar="KEY=VALUE",
                   help="reader keyword (JSON value); the options of each format are listed below")
    p.add_argument("--include", nargs="+", metavar="NAME", help="only these episodes")
    p.add_argument("--exclude", nargs="+", metavar="NAME", help="skip these episodes")


def embed_args(p: argparse.ArgumentParser) -> None:
    """``--views``, ``--encoder-option`` and the embedding cache."""
    p.add_argument("--views", nargs="+", help="camera views (default front wrist, else all); "
                   "`state` adds the joint state (standardised per episode) as a view")
    p.add_argument("--encoder-option", action="append", metavar="KEY=VALUE")
    p.add_argument("--cache-dir", help="embedding cache folder (default $RDD_CACHE_DIR or ~/.cache/rdd)")
    p.add_argument("--no-cache", action="store_true", help="do not cache embeddings")


def expert_args(p: argparse.ArgumentParser) -> None:
    """The expert rule's ``--stopping-delta`` and ``--velocity-source``."""
    p.add_argument("--stopping-delta", type=float, default=0.1,
                   help="expert rule (stop_test=absolute, RLBench): still-arm joint velocity; recorded "
                        "data with an fps (LeRobot) uses the scale-aware test, see --option stopping_fraction")
    p.add_argument("--velocity-source", choices=("auto", "joint", "ee"), default="auto")


def force_arg(p: argparse.ArgumentParser) -> None:
    """``--force``."""
    p.add_argument("--force", action="store_true", help="replace an existing output")


def reader_help() -> str:
    """The reader options of every format, for ``--help``."""
    from rdd.data.lerobot.reader import READER_OPTIONS

    lines = ["reader options (--reader-option KEY=VALUE, VALUE as JSON):",
             "  rlbench: views=[\"front\",\"wrist\"] (null: every <view>_rgb folder)",
             "  native: none", "  lerobot:"]
    lines += [f"    {k}: {v}" for k, v in READER_OPTIONS.items()]
    return "\n".join(lines)


def with_reader_help() -> dict[str, Any]:
    """``add_parser`` keywords that list the reader options below a subcommand's help."""
    return {"formatter_class": argparse.RawDescriptionHelpFormatter, "epilog": reader_help()}


def add_workers_arg(p: argparse.ArgumentParser) -> None:
    """``--workers N``, ``--executor``, ``--ray-address``."""
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="processes working on episodes at once (default 1; each gets cores/N torch threads; "
                        "with --executor ray, Ray actors of one CPU each)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="where episodes are worked on: local = processes on this machine; ray = tasks on a Ray "
                        "cluster, the components sent once, the same results (needs: make install-cluster; "
                        "--data readable at the same path on every node)")
    p.add_argument("--ray-address", metavar="ADDRESS",
                   help="--executor ray: the cluster to join (auto = the one this node belongs to, "
                        "ray://HEAD:10001); default a local cluster of --workers CPUs started for the job")


def check_workers(n: int, args: argparse.Namespace | None = None) -> int:
    """``--workers`` as given, refused below 1; with ``args``, ``--ray-address`` only with ``--executor ray``
    and Ray installed for it."""
    if n < 1:
        raise UsageError(f"--workers {n}: must be >= 1")
    if args is not None and getattr(args, "ray_address", None) is not None and args.executor != "ray":
        raise UsageError(f"--ray-address {args.ray_address}: needs --executor ray")
    if args is not None and getattr(args, "executor", "local") == "ray":
        from rdd.batch.ray_executor import import_ray

        import_ray()  # before any work: the missing extra is a one-line error naming the install line
    return n
