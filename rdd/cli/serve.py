"""``python -m rdd serve``: decomposition over HTTP, in the official RDD server's request and answer shapes.

``POST /decompose`` takes ``{"paths": [[view paths of frame 0], ...], "method": "rdd" | "uvd",
"preprocessor": ...}`` and answers ``{"segments": [[frame indices], ...], "nn_list": [...]}`` (rdd)
or ``{"segments": ...}`` (uvd); ``GET /config`` and ``GET /health`` (``docs/cli.md``, Serving).
The rdd decomposer is built exactly as ``decompose --decomposer rdd --db DB`` builds it (the same
flags), uvd with the database's encoder and views. Each of ``--workers N`` uvicorn workers loads the
database and the encoder once, at its start.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

import numpy as np

from rdd.batch.staging import cores, set_torch_threads
from rdd.cli.common import parse_options
from rdd.cli.components import SET_BY_CLI, make_decomposer
from rdd.errors import UsageError
from rdd.serve.body_limit import DEFAULT_MAX_BODY_BYTES
from rdd.serve.service import DEFAULT_MAX_FRAMES, DecomposeService

# The worker processes of --workers N > 1 read the command's arguments here (JSON, set by the parent).
ARGS_ENV = "RDD_SERVE_ARGS"


def make_service(args: argparse.Namespace) -> DecomposeService:
    """The database, encoder and decomposers ``args`` names, loaded once (per worker)."""
    from rdd.registry import check_option_names, component, construct

    ns = argparse.Namespace(**vars(args))
    ns.decomposer, ns.no_cache, ns.cache_dir = "rdd", True, None  # no embedding cache: requests are one-off
    rdd_decomposer, config = make_decomposer(ns, None)
    uvd_options = parse_options(args.uvd_option, "--uvd-option")
    uvd_cls = component("decomposer", "uvd")
    try:
        check_option_names("decomposer", uvd_cls, uvd_options, reserved=SET_BY_CLI)
        uvd = construct(uvd_cls, {"encoder": rdd_decomposer.encoder, "cache": None}, "decomposer uvd",
                        views=rdd_decomposer.views, **uvd_options)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"--uvd-option: {exc}") from exc
    encoder = rdd_decomposer.encoder
    if getattr(encoder, "num_threads", 0) is None:
        # The workers share the cores: ONNX Runtime fixes its threads when its session is made (the
        # warm-up below), so an encoder left to the default gets its share before it.
        encoder.num_threads = max(1, cores() // args.workers)
    # The encoder's first call readies its runtime (the ONNX session; torch's import where torch
    # runs it, 1-2 s): done here, at load, so no request pays for it.
    encoder.encode(np.zeros((1, 64, 64, 3), dtype=np.uint8))
    config.update(preprocessor=config.get("encoder"), uvd_options=uvd_options, workers=args.workers,
                  encoder_threads=getattr(encoder, "num_threads", None))
    config.pop("decomposer", None)
    try:
        return DecomposeService({"rdd": rdd_decomposer, "uvd": uvd}, rdd_decomposer.views, config,
                                root=args.root, max_frames=args.max_frames)
    except ValueError as exc:
        raise UsageError(f"--root / --max-frames: {exc}") from exc


def _settings(args: argparse.Namespace) -> dict[str, Any]:
    """The command's arguments as JSON for the workers (the subcommand's function left out)."""
    return {k: v for k, v in vars(args).items() if k != "func"}


def worker_app():
    """A uvicorn worker's app (``--workers N > 1``): its own service, loaded once from the parent's arguments."""
    from rdd.progress import show_progress
    from rdd.serve.app import create_app

    args = argparse.Namespace(**json.loads(os.environ[ARGS_ENV]))
    show_progress(False)
    service = make_service(args)
    set_torch_threads(max(1, cores() // args.workers))  # after the load: torch is imported by then
    return create_app(service, args.max_body_bytes)


def cmd_serve(args: argparse.Namespace) -> int:
    """Load the service once (errors are one line, before any port is opened), then serve it."""
    if args.workers < 1:
        raise UsageError(f"--workers {args.workers}: must be at least 1")
    if not 0 < args.port < 65536:
        raise UsageError(f"--port {args.port}: must be in 1..65535")
    if args.max_body_bytes < 1:
        raise UsageError(f"--max-body-bytes {args.max_body_bytes}: must be at least 1")
    try:
        import uvicorn
    except ImportError as exc:
        raise ImportError(f"serve needs FastAPI and uvicorn: pip install 'rdd[serve]' ({exc})") from exc
    from rdd.progress import show_progress
    from rdd.serve.app import create_app

    show_progress(False)
    service = make_service(args)
    app = create_app(service, args.max_body_bytes)  # fails here, not in a worker, when FastAPI is missing
    level = "info" if args.verbose else "warning"
    print(f"serving {', '.join(service.decomposers)} on http://{args.host}:{args.port} ({args.workers} "
          f"worker(s); database {args.db}, encoder {service.encoder_name}, views {', '.join(service.views)})",
          file=sys.stderr, flush=True)
    if args.workers == 1:
        uvicorn.run(app, host=args.host, port=args.port, log_level=level, access_log=False)
    else:
        del app, service  # each worker loads its own
        os.environ[ARGS_ENV] = json.dumps(_settings(args))
        uvicorn.run("rdd.cli.serve:worker_app", factory=True, host=args.host, port=args.port,
                    workers=args.workers, log_level=level, access_log=False)
    _exit_now()


def _exit_now() -> None:
    """End the process once uvicorn has closed its socket and answered its last request: tearing the
    interpreter down with torch loaded takes 1.5-2 s more, and the server has nothing left to write."""
    print("server stopped", file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(0)


def add_parser(sub) -> None:
    """The ``serve`` subcommand and its options."""
    p = sub.add_parser("serve", help="serve decomposition over HTTP (the official RDD server's API)",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("--db", required=True, help="sub-task database directory")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8001, help="port (default 8001, the official server's)")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="uvicorn worker processes, each loading the database and encoder once (default 1)")
    p.add_argument("--root", metavar="DIR",
                   help="serve only image files inside DIR (relative request paths are taken from DIR)")
    p.add_argument("--max-frames", type=int, default=DEFAULT_MAX_FRAMES,
                   help=f"refuse requests of more frames (default {DEFAULT_MAX_FRAMES})")
    p.add_argument("--max-body-bytes", type=int, default=DEFAULT_MAX_BODY_BYTES, metavar="N",
                   help=f"refuse request bodies of more than N bytes with 413 (default {DEFAULT_MAX_BODY_BYTES}, "
                        "64 MiB)")
    p.add_argument("--encoder", help="encoder (default the database's)")
    p.add_argument("--encoder-option", action="append", metavar="KEY=VALUE")
    p.add_argument("--views", nargs="+", help="database views the request's paths of a frame stand for, in order "
                                              "(default the database's)")
    p.add_argument("--alpha", type=float, help="rdd: weight of the duration term")
    p.add_argument("--max-len", type=int, help="rdd: longest segment in frames")
    p.add_argument("--no-calibration", action="store_true",
                   help="rdd: ignore the database's calibrated options (use the paper's)")
    p.add_argument("--option", action="append", metavar="KEY=VALUE", help="rdd decomposer keyword, as decompose's")
    p.add_argument("--uvd-option", action="append", metavar="KEY=VALUE", help="uvd keyword, e.g. min_interval=10")
    p.set_defaults(func=cmd_serve)
