"""Decomposers built from a subcommand's options, through the registry and constructor the harness uses.

``--decomposer NAME`` is ``rdd.registry.component("decomposer", NAME)``, the class a harness config's
``_target_`` names, and :func:`rdd.registry.construct` calls it as the harness does: ``--option``
pairs and the flags that name its parameters are its keyword arguments, and it gets the runtime
objects it takes (``database`` from ``--db``, ``encoder`` from ``--encoder``, ``cache`` from
``--cache-dir``). Which of these apply follows from the constructor's parameters, not its name.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping
from typing import Any

from rdd.cli.aliases import OPTION_ALIASES, OUTPUT_KEYS
from rdd.cli.common import (
    make_cache,
    make_encoder,
    parse_options,
    resolve_views,
    unique_views,
)
from rdd.data.episode import Episode
from rdd.decomposers.base import Decomposer
from rdd.encoders.embed import DEFAULT_VIEWS
from rdd.errors import InputError, UsageError
from rdd.registry import (
    RUNTIME_OBJECTS,
    available,
    check_option_names,
    component,
    construct,
    parameters,
    runtime_names,
)

# Parameters the CLI fills itself (from --db, --encoder, --views, --no-calibration), never --option.
SET_BY_CLI = (*RUNTIME_OBJECTS, "views")
# Flags that are decomposer parameters. These have defaults, so an --option of the same name wins...
FLAG_DEFAULTS = ("stopping_delta", "velocity_source")
# ...while these are unset unless typed, and when typed they win over --option.
FLAG_OVERRIDES = ("alpha", "max_len")
DEFAULT_ENCODER = "effnet_lite0"  # uvd's encoder without --encoder (rdd: the database's)


def keyword_names(options: Mapping[str, Any], params: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` under the parameter names of the decomposer (OPTION_ALIASES resolved)."""
    out = {}
    for key, value in options.items():
        new = OPTION_ALIASES.get(key)
        out[new if new in params and key not in params else key] = value
    return out


def build_decomposer(name: str, options: Mapping[str, Any], args: argparse.Namespace,
                     first: Episode | None = None) -> tuple[Decomposer, dict[str, Any]]:
    """The decomposer ``name`` with ``options`` and the flags of ``args``; also what to record of it.

    ``first``: an episode of the data, whose views an encoder embeds when no database fixes them.
    """
    cls = component("decomposer", name)
    params = parameters(cls)
    takes = runtime_names(cls)
    views = unique_views(args.views)
    defaults = {k: getattr(args, k) for k in FLAG_DEFAULTS if k in params}
    options = keyword_names(options, params)
    typed = {k: getattr(args, k) for k in FLAG_OVERRIDES if k in params and getattr(args, k, None) is not None}
    kwargs = {**defaults, **options, **typed}
    # How the user gave each keyword, to name it so when the decomposer refuses its value.
    given_as = {k: f"--{k.replace('_', '-')} {v}" for k, v in defaults.items()}
    given_as.update({k: f"--option {k}={json.dumps(v)}" for k, v in options.items()})
    given_as.update({k: f"--{k.replace('_', '-')} {v}" for k, v in typed.items()})
    if "database" in takes and not getattr(args, "db", None):
        raise UsageError(f"--decomposer {name} needs --db DIR (build one with `python -m rdd build-db`)")
    check_option_names("decomposer", cls, kwargs, reserved=SET_BY_CLI)
    runtime: dict[str, Any] = {}
    db = None
    make = cls  # or its `calibrated` factory: the database's calibrated options unless given here
    if "cache" in takes:
        runtime["cache"] = make_cache(args)
    if "database" in takes:
        from rdd.database.model import SubtaskDatabase

        db = runtime["database"] = SubtaskDatabase.load(args.db)
        if hasattr(cls, "calibrated") and db.meta.get("calibration") and not args.no_calibration:
            make = cls.calibrated
    if "views" in params:
        if db is not None:  # the views the database's entries were embedded with
            kwargs["views"] = views or tuple(db.meta.get("views") or DEFAULT_VIEWS)
        elif "encoder" in takes:  # what the encoder will embed: the episodes' views
            kwargs["views"] = resolve_views(args.views, first)
        else:
            kwargs["views"] = views
    if "encoder" in takes:
        enc_name = args.encoder or (db.meta.get("encoder") if db is not None else DEFAULT_ENCODER)
        if not enc_name:
            raise UsageError(f"--db {args.db} records no encoder; pass --encoder")
        runtime["encoder"] = make_encoder(enc_name, parse_options(args.encoder_option, "--encoder-option"))
    try:
        decomposer = construct(make, runtime, f"decomposer {name}", **kwargs)
    except InputError as exc:
        if exc.option in given_as:
            raise UsageError(f"{given_as[exc.option]}: {exc}") from exc
        if make is not cls:  # a value the database's calibration chose
            raise UsageError(f"--db {args.db} (its calibration; --no-calibration ignores it): {exc}") from exc
        raise
    config: dict[str, Any] = dict(defaults)
    if "encoder" in runtime:
        encoder = runtime["encoder"]
        config.update(encoder=encoder.name, weights_id=encoder.weights_id, views=list(kwargs["views"]))
    if db is not None:
        config.update(db=str(args.db), db_fingerprint=db.fingerprint(), db_size=len(db))
    config.update({OUTPUT_KEYS.get(k, k): v for k, v in decomposer.settings().items()})
    return decomposer, config


def expert_decomposer(args: argparse.Namespace) -> Decomposer:
    """The expert rule with ``--stopping-delta`` / ``--velocity-source`` (``build-db``'s segmenter)."""
    try:
        return build_decomposer("expert", {}, args)[0]
    except ValueError as exc:
        raise UsageError(f"expert rule: {exc}") from exc


def make_decomposer(args: argparse.Namespace, first: Episode) -> tuple[Decomposer, dict[str, Any]]:
    """The decomposer named by ``--decomposer`` with its options; also the config to record."""
    name = args.decomposer
    options = parse_options(args.option, "--option")
    try:
        decomposer, config = build_decomposer(name, options, args, first)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ValueError) and "option" not in str(exc) and "must be" not in str(exc):
            raise
        raise UsageError(f"--option for --decomposer {name}: {exc}") from exc
    return decomposer, {"decomposer": name, "options": options, **config}


def decomposer_names() -> tuple[str, ...]:
    """The registry's decomposers (one module each in rdd/decomposers/, and RDD_PLUGINS'), the same
    the harness's conf/decomposer/*.yaml name as _target_. Looked up when a parser is built, inside
    the CLI's error handling: a plugin that cannot be imported is a one-line error."""
    return tuple(available("decomposer"))


def decomposer_help() -> str:
    """Each decomposer's ``--option`` keys and defaults, read from its constructor."""
    lines = ["decomposer options (--option KEY=VALUE):"]
    for name in decomposer_names():
        params = [p for p in parameters(component("decomposer", name)).values() if p.name not in SET_BY_CLI]
        lines.append(f"  {name}: " + ", ".join(f"{p.name}={p.default!r}" for p in params))
    return "\n".join(lines)
