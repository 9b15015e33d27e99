"""The components a subcommand builds from its options: decomposers by name, as the registry has them."""

from __future__ import annotations

import argparse
import inspect
from typing import Any

from rdd.cli.common import CLIError, make_cache, make_encoder, parse_options, resolve_views
from rdd.data.episode import Episode
from rdd.encoders.embed import DEFAULT_VIEWS
from rdd.registry import available, component

# The registry's decomposers (rdd.registry: one module each in rdd/decomposers/), the same the
# harness's conf/decomposer/*.yaml name as _target_.
DECOMPOSERS = tuple(available("decomposer"))


def expert_decomposer(args: argparse.Namespace, options: dict[str, Any] | None = None):
    """The expert rule with ``--stopping-delta``/``--velocity-source`` and any ``--option``."""
    from rdd.decomposers.base import check_option_names

    ExpertDecomposer = component("decomposer", "expert")
    options = dict(options or {})
    options.setdefault("stopping_delta", args.stopping_delta)
    options.setdefault("velocity_source", args.velocity_source)
    try:
        check_option_names(ExpertDecomposer, options)
        return ExpertDecomposer(**options)
    except ValueError as exc:
        raise CLIError(f"--option: {exc}") from exc


def make_decomposer(args: argparse.Namespace, first: Episode):
    """The decomposer named by ``--decomposer`` with its options; also the config to record."""
    from rdd.decomposers.base import check_option_names

    options = parse_options(args.option, "--option")
    config: dict[str, Any] = {"decomposer": args.decomposer, "options": options}
    name = args.decomposer
    try:
        if name == "expert":
            config.update(stopping_delta=args.stopping_delta, velocity_source=args.velocity_source)
            return expert_decomposer(args, options), config
        if name == "uniform":
            UniformDecomposer = component("decomposer", "uniform")
            check_option_names(UniformDecomposer, options)
            return UniformDecomposer(**options), config
        if name == "vlm":
            VLMDecomposer = component("decomposer", "vlm")
            check_option_names(VLMDecomposer, options, reserved=("views",))
            return VLMDecomposer(views=args.views or None, **options), config
        cache = make_cache(args)
        if name == "uvd":
            UVDDecomposer = component("decomposer", "uvd")
            check_option_names(UVDDecomposer, options, reserved=("encoder", "views", "cache"))
            views = resolve_views(args.views, first)
            encoder = make_encoder(args.encoder or "effnet_lite0",
                                   parse_options(args.encoder_option, "--encoder-option"))
            config.update(encoder=encoder.name, weights_id=encoder.weights_id, views=list(views))
            return UVDDecomposer(encoder=encoder, views=views, cache=cache, **options), config
        if name == "rdd":
            from rdd.database import SubtaskDatabase

            RDDDecomposer = component("decomposer", "rdd")
            if not args.db:
                raise CLIError("--decomposer rdd needs --db DIR (build one with `python -m rdd build-db`)")
            check_option_names(RDDDecomposer, options, reserved=("database", "encoder", "views", "cache"))
            db = SubtaskDatabase.load(args.db)
            enc_name = args.encoder or db.meta.get("encoder")
            if not enc_name:
                raise CLIError(f"--db {args.db} records no encoder; pass --encoder")
            encoder = make_encoder(enc_name, parse_options(args.encoder_option, "--encoder-option"))
            views = tuple(args.views) if args.views else tuple(db.meta.get("views") or DEFAULT_VIEWS)
            kwargs = dict(options)
            if args.alpha is not None:
                kwargs["alpha"] = args.alpha
            if args.max_len is not None:
                kwargs["max_len"] = args.max_len
            # The database's calibrated alpha/min_len/max_len unless given here (or --no-calibration).
            calibrated = bool(db.meta.get("calibration")) and not args.no_calibration
            dec = RDDDecomposer(db, encoder=encoder, views=views, cache=cache,
                                use_calibration=calibrated, **kwargs)
            config.update(encoder=encoder.name, weights_id=encoder.weights_id, views=list(views),
                          db=str(args.db), db_fingerprint=db.fingerprint(), db_size=len(db),
                          alpha=dec.alpha, min_len=dec.min_len, max_len=dec.max_len, mode=dec.mode,
                          beta=dec.beta, backend=dec.index.name, option_source=dec.option_source)
            return dec, config
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ValueError) and "option" not in str(exc) and "must be" not in str(exc):
            raise
        raise CLIError(f"--option for --decomposer {name}: {exc}") from exc
    raise CLIError(f"--decomposer {name!r}: choose one of {', '.join(DECOMPOSERS)}")


def decomposer_help() -> str:
    """Each decomposer's ``--option`` keys and defaults, read from its constructor."""
    lines = ["decomposer options (--option KEY=VALUE):"]
    reserved = {"self", "database", "encoder", "views", "cache"}
    for name in DECOMPOSERS:
        init = component("decomposer", name).__init__
        params = [p for p in inspect.signature(init).parameters.values()
                  if p.name not in reserved and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
        lines.append(f"  {name}: " + ", ".join(f"{p.name}={p.default!r}" for p in params))
    return "\n".join(lines)
