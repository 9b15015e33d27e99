"""``python -m rdd decompose``: cut episodes into sub-task segments; JSON and/or a LeRobot copy."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rdd.atomic import write_text_atomic
from rdd.batch.staging import (
    Staging,
    claim,
    digest,
    parts_folder,
    run_staged,
    settings_hash,
)
from rdd.cli.common import (
    cache_input,
    check_output,
    load_data,
    make_cache,
    make_encoder,
    parse_options,
    write_json_atomic,
)
from rdd.cli.components import decomposer_help, decomposer_names, make_decomposer
from rdd.cli.options import (
    add_workers_arg,
    check_workers,
    data_args,
    embed_args,
    expert_args,
    force_arg,
    reader_help,
)
from rdd.core.confidence import REVIEW_BELOW
from rdd.data.episode import Episode
from rdd.errors import InputError, UsageError
from rdd.records import (
    FALLBACK_FIELDS,
    OUTPUT_VERSION,
    episode_record,
    fallback_instruction,
    fill_instructions,
    lerobot_subtasks,
)
from rdd.registry import available


def make_labeler(args: argparse.Namespace):
    """``--labeler retrieval``: the nearest entry of ``--label-db`` (default ``--db``) names a segment;
    ``--labeler signals`` (the default with ``--write-lerobot`` and no ``--fallback-instruction``): what
    the robot's hand and joint signals show; ``--labeler vlm``: a vision-language model's instruction for
    a few frames of the segment. ``--labeler-option KEY=VALUE`` pairs are the signals and vlm labelers'
    keyword arguments."""
    name = args.labeler
    if name is None and args.write_lerobot is not None and args.fallback_instruction is None:
        name = "signals"
    options = parse_options(getattr(args, "labeler_option", None), "--labeler-option")
    if name is None:
        if options:
            raise UsageError("--labeler-option needs --labeler signals or --labeler vlm")
        return None
    if name != "retrieval":  # signals, vlm and any registered labeler: built from its options alone
        return _option_labeler(name, options)
    if options:
        raise UsageError("--labeler retrieval takes no --labeler-option (its index is the database's)")
    from rdd.database.model import SubtaskDatabase
    from rdd.labelers.retrieval import RetrievalLabeler

    path = args.label_db or args.db
    if not path:
        raise UsageError("--labeler retrieval needs --label-db DIR (a database whose entries carry instructions)")
    db = SubtaskDatabase.load(path)
    enc_name = db.meta.get("encoder")
    if not enc_name:
        raise UsageError(f"--label-db {path} records no encoder")
    encoder = make_encoder(enc_name, parse_options(args.encoder_option, "--encoder-option"))
    try:
        return RetrievalLabeler(db, encoder, cache=make_cache(args))
    except ValueError as exc:
        raise UsageError(f"--label-db {path}: {exc}") from exc


def _option_labeler(name: str, options: dict[str, Any]):
    """A labeler (signals, vlm, a plugin's) built from ``--labeler-option`` pairs; a bad one is a one-line error."""
    from rdd.registry import check_option_names, component

    cls = component("labeler", name)
    try:
        check_option_names("labeler", cls, options)
        return cls(**options)
    except InputError as exc:
        shown = f"--labeler-option {exc.option}={json.dumps(options[exc.option])}" if exc.option in options \
            else f"--labeler {name}"
        raise UsageError(f"{shown}: {exc}") from exc
    except ValueError as exc:
        hint = " (e.g. --labeler-option base_url=http://127.0.0.1:8000/v1 --labeler-option model=NAME)" \
            if name == "vlm" else ""
        raise UsageError(f"--labeler {name}: {exc}{hint}") from exc


def _components(args: argparse.Namespace, first: Episode):
    """A worker's decomposer and labeler, built from the command's arguments as the parent's were."""
    return make_decomposer(args, first)[0], make_labeler(args), args


def _decompose_one(state, path: Path, episode: Episode, _payload: Any) -> None:
    """Decompose and label one episode; stage its record at ``path``."""
    decomposer, labeler, args = state
    try:
        record = episode_record(episode, decomposer.decompose(episode))
        fill_instructions(record, episode, labeler, args.fallback_instruction)
    except ValueError as exc:
        raise UsageError(f"episode {episode.name!r} ({args.data}): {exc}") from exc
    write_text_atomic(path, json.dumps({"episode": episode.name, "record": record}))


def _staged_record(path: Path, episode: Episode) -> dict[str, Any]:
    part = json.loads(path.read_text())
    if part.get("episode") != episode.name:
        raise UsageError(f"{path}: a staged part of another episode ({part.get('episode')!r}, not "
                       f"{episode.name!r}); delete {path.parent} and run again")
    return part["record"]


def cmd_decompose(args: argparse.Namespace) -> int:
    """Decompose every episode at ``--data``; write the segments as JSON and/or into a LeRobot copy.

    Each episode's record is staged beside the output as it is done (``rdd.batch.staging``), so a run
    that stops resumes where it stopped; ``--workers N`` decomposes N episodes at once.
    """
    if args.out is None and args.write_lerobot is None:
        raise UsageError("decompose needs --out FILE.json, --write-lerobot DIR, or both")
    if args.write_lerobot is not None and args.format != "lerobot":
        raise UsageError(f"--write-lerobot needs --format lerobot, not {args.format}")
    workers = check_workers(args.workers, args)
    if not 0.0 <= args.review_below <= 1.0:
        raise UsageError(f"--review-below {args.review_below:g}: a confidence is in [0, 1]")
    inputs = [("--data", args.data), ("--db", args.db), ("--label-db", args.label_db), cache_input(args)]
    out = check_output(args.out, "--out", args.force, inputs=inputs)
    lerobot_out = check_output(args.write_lerobot, "--write-lerobot", False, kind="dir",
                               inputs=[*inputs, ("--out", args.out)])
    if args.fallback_instruction is not None:
        fallback_instruction(args.fallback_instruction, Episode(name="check", views={}), 0, 1, (0, 1))
    if lerobot_out is not None and args.lerobot_version == "2.1":
        from rdd.data.lerobot.dataset import LeRobotDataset

        if LeRobotDataset(args.data).version == "v3.0":
            raise UsageError(f"--lerobot-version 2.1: --data {args.data} is a v3.0 dataset; its copy is written as "
                           "v3.0 (drop the option)")
    with claim(out, "--out"), claim(lerobot_out, "--write-lerobot"):
        return _decompose(args, out, lerobot_out, workers)


def _decompose(args: argparse.Namespace, out: Path | None, lerobot_out: Path | None, workers: int) -> int:
    """The work of :func:`cmd_decompose`, with its outputs held by this run."""
    episodes = load_data(args)
    decomposer, config = make_decomposer(args, episodes[0])
    labeler = make_labeler(args)
    label_db = getattr(labeler, "database", None)
    config.update(format=args.format, data=str(args.data), version=OUTPUT_VERSION,
                  fallback_instruction=args.fallback_instruction, labeler=getattr(labeler, "name", None),
                  label_db=None if label_db is None else str(args.label_db or args.db))
    staging = Staging(parts_folder(out if out is not None else lerobot_out),
                      settings_hash(args, config=config, label_db=label_db and label_db.fingerprint()))
    items = [(staging.path(i, ep), ep, None) for i, ep in enumerate(episodes)]
    records = run_staged(items, _decompose_one, f"decompose ({args.decomposer})", workers=workers,
                         state=(decomposer, labeler, args), factory=_components, factory_args=(args, episodes[0]),
                         executor=args.executor, address=args.ray_address, read=_staged_record)
    if lerobot_out is not None:
        from rdd.data.lerobot.write import write_subtasks

        subtasks = lerobot_subtasks(episodes, records, args.decomposer)
        version = f"v{args.lerobot_version}"
        key = digest([str(args.data), sorted(subtasks.items()), version])[:24]
        write_subtasks(args.data, lerobot_out, subtasks, staging=parts_folder(lerobot_out) / f"copy-{key}",
                       version=version)
        print(f"wrote {lerobot_out}: LeRobot {version} dataset with sub-tasks of {len(subtasks)} episodes "
              "(language_persistent)")
    if out is not None:
        write_json_atomic(out, {"config": config, "episodes": records}, overwrite=args.force)
        print(f"wrote {out}: {len(records)} episodes decomposed with {args.decomposer}")
    flagged = review_count(records, args.review_below)
    if flagged is not None:
        print(f"{flagged} of {len(records)} episodes have a segment of confidence below {args.review_below:g} "
              "(--review-below; python -m rdd review shows them)")
    staging.remove()
    if lerobot_out is not None:
        Staging(parts_folder(lerobot_out), "").remove()
    return 0


def review_count(records: Sequence[dict[str, Any]], below: float) -> int | None:
    """How many episodes have a segment whose confidence is below ``below`` (None: no confidences)."""
    if not records or any(not isinstance(r.get("confidence"), list) for r in records):
        return None
    return sum(1 for r in records if r["confidence"] and min(r["confidence"]) < below)


def add_parser(sub) -> None:
    """The ``decompose`` subcommand and its options."""
    p = sub.add_parser("decompose", help="decompose episodes into sub-task segments",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=decomposer_help() + "\n\n" + reader_help())
    data_args(p)
    p.add_argument("--decomposer", choices=decomposer_names(), required=True)
    p.add_argument("--encoder", help="encoder for rdd/uvd (rdd: default the database's)")
    p.add_argument("--db", help="sub-task database directory (rdd)")
    p.add_argument("--alpha", type=float, help="rdd: weight of the duration term")
    p.add_argument("--max-len", type=int, help="rdd: longest segment in frames")
    p.add_argument("--no-calibration", action="store_true",
                   help="rdd: ignore the database's calibrated options (use the paper's: alpha 1, "
                        "min_len 2, no max_len)")
    p.add_argument("--option", action="append", metavar="KEY=VALUE",
                   help="decomposer keyword, e.g. n_segments=5 (uniform), min_interval=10 (uvd), "
                        "stopping_fraction=0.1 (expert); unknown keys and bad values are errors")
    embed_args(p)
    expert_args(p)
    p.add_argument("--out", help="output JSON file")
    p.add_argument("--write-lerobot", metavar="DIR",
                   help="also write DIR, a copy of the LeRobot dataset --data whose language_persistent "
                        "column carries the sub-tasks (new folder; never the source)")
    p.add_argument("--lerobot-version", choices=("3.0", "2.1"), default="3.0",
                   help="layout of the --write-lerobot copy (default 3.0, also from a v2.1 source, as current "
                        "LeRobot reads it; 2.1 keeps a v2.1 source's layout)")
    p.add_argument("--labeler", choices=tuple(available("labeler")),
                   help="name segments the decomposer gives no instruction: retrieval = the instruction of "
                        "the nearest entry of --label-db; signals = what the robot's hand and joint signals "
                        "show (default with --write-lerobot unless --fallback-instruction is given); vlm = a "
                        "vision-language model's instruction for a few frames of each segment; any other "
                        "registered labeler (docs/extending.md) is built from its --labeler-option pairs")
    p.add_argument("--labeler-option", action="append", metavar="KEY=VALUE",
                   help="labeler keyword (signals, vlm), e.g. base_url=http://127.0.0.1:8000/v1, model=NAME, "
                        "view=top, frames=4 (vlm; conf/labeler/vlm.yaml lists them); unknown keys are errors")
    p.add_argument("--label-db", metavar="DIR", help="database for --labeler retrieval (default --db)")
    p.add_argument("--fallback-instruction", metavar="TEMPLATE",
                   help="instruction for segments the decomposer gives none, with fields "
                        + ", ".join("{" + f + "}" for f in FALLBACK_FIELDS))
    p.add_argument("--review-below", type=float, default=REVIEW_BELOW, metavar="C",
                   help=f"count the episodes with a segment of confidence below C (rdd; default {REVIEW_BELOW:g})")
    force_arg(p)
    add_workers_arg(p)
    p.set_defaults(func=cmd_decompose)
