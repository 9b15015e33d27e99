"""``python -m rdd build-db``: segment episodes, build the sub-task database and calibrate it."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from rdd.atomic import atomic_file
from rdd.batch.staging import (
    Staging,
    claim,
    parts_folder,
    run_staged,
    settings_hash,
)
from rdd.cli.common import (
    cache_input,
    check_output,
    load_data,
    log,
    make_cache,
    make_encoder,
    parse_options,
    resolve_views,
)
from rdd.cli.components import expert_decomposer
from rdd.cli.options import (
    add_workers_arg,
    check_workers,
    data_args,
    embed_args,
    expert_args,
    force_arg,
    with_reader_help,
)
from rdd.data.episode import Episode
from rdd.database.build import Entries, segment_entries
from rdd.errors import InputError, UsageError
from rdd.progress import progress


def _embedder(args: argparse.Namespace, views: tuple[str, ...]):
    """A worker's encoder, views, cache and view normalisation, built from the command's arguments."""
    return (make_encoder(args.encoder, parse_options(args.encoder_option, "--encoder-option")), views,
            make_cache(args), not args.raw_views)


def _embed_one(state, path: Path, episode: Episode, payload: Any) -> None:
    """One episode's database entries (its segments' boundary frame vectors; every frame's when
    calibration keeps it), staged at ``path``."""
    encoder, views, cache, normalize = state
    segments, instructions, kept = payload
    begin, end, durations, labels, meta, frames = segment_entries(
        [episode], [segments], encoder, views, cache, None if instructions is None else [instructions],
        normalize, [episode.name] if kept else [])
    info = {"episode": episode.name, "durations": durations, "labels": labels, "meta": meta}
    with atomic_file(path) as fh:
        np.savez(fh, begin=np.stack(begin), end=np.stack(end), info=np.array(json.dumps(info)),
                 **({"frames": frames[episode.name]} if kept else {}))


def _staged_entries(path: Path, episode: Episode) -> Entries:
    with np.load(path, allow_pickle=False) as part:
        info = json.loads(str(part["info"]))
        if info["episode"] != episode.name:
            raise UsageError(f"{path}: a staged part of another episode ({info['episode']!r}, not "
                           f"{episode.name!r}); delete {path.parent} and run again")
        frames = {episode.name: part["frames"]} if "frames" in part.files else {}
        return list(part["begin"]), list(part["end"]), info["durations"], info["labels"], info["meta"], frames


def cmd_build_db(args: argparse.Namespace) -> int:
    """Segment episodes (their sub-task annotations or the expert rule), build and calibrate the database."""
    workers = check_workers(args.workers, args)
    given = [] if args.segments in ("auto", "subtasks", "expert") else [("--segments", args.segments)]
    out = check_output(args.out, "--out", args.force, kind="dir",
                       inputs=[("--data", args.data), cache_input(args), *given])
    with claim(out, "--out"):
        return _build(args, out, workers)


def _given_segments(path: str, episodes) -> tuple[list, list]:
    """``--segments FILE``: each episode's segments and labels as a decompose output (or a file reviewed
    with ``python -m rdd review``) records them."""
    from rdd.decomposers.given import GivenDecomposer
    from rdd.review.session import read_predictions

    read_predictions(path, flag="--segments")  # a missing or malformed file: named as this option's
    try:
        given = GivenDecomposer(file=path)
        found = [given.decompose(ep) for ep in episodes]
    except InputError as exc:
        raise UsageError(f"--segments {path}: {exc}") from exc
    return [f.segments for f in found], [f.instructions or [""] * len(f.segments) for f in found]


def _build(args: argparse.Namespace, out: Path, workers: int) -> int:
    """The work of :func:`cmd_build_db`, with ``out`` held by this run."""
    from rdd.core.calibrate import CalibrationError, calibrate, sample_episodes, summary
    from rdd.database.build import merge_entries
    from rdd.database.model import SubtaskDatabase

    episodes = load_data(args)
    views = resolve_views(args.views, episodes[0])
    encoder = make_encoder(args.encoder, parse_options(args.encoder_option, "--encoder-option"))
    annotated = [e for e in episodes if e.segments is not None]
    source = args.segments
    if source == "auto":
        source = "subtasks" if annotated and len(annotated) == len(episodes) else "expert"
        if annotated and len(annotated) != len(episodes):
            log.warning("only %d of %d episodes carry sub-task annotations; using the expert rule for all "
                        "(pass --segments subtasks to require them)", len(annotated), len(episodes))
    if source == "subtasks":
        missing = [e.name for e in episodes if e.segments is None]
        if missing:
            raise UsageError(f"--segments subtasks: episodes {missing} of --data {args.data} carry no sub-task "
                           "annotations (LeRobot: language_persistent subtask rows)")
        segmentations = [e.segments for e in episodes]
        instructions = [e.instructions or [""] * len(e.segments) for e in episodes]
    elif source not in ("expert", "auto"):
        segmentations, instructions = _given_segments(source, episodes)
    else:
        expert = expert_decomposer(args)
        segmentations = []
        for ep in episodes:
            try:
                segmentations.append(expert.decompose(ep).segments)
            except ValueError as exc:
                raise UsageError(f"--data {args.data}: {exc}") from exc
        instructions = None
    print(f"segments: {source} ({sum(len(s) for s in segmentations)} sub-tasks in {len(episodes)} episodes)",
          file=sys.stderr)
    names = [e.name for e in episodes]
    keep: list[str] = []
    if args.no_calibrate:
        pass
    elif len(set(names)) < 2:
        # the database's episode count, not the dataset's: --include/--exclude or the reader's options
        # may have chosen one episode of many
        print(f"warning: calibration skipped: the database holds one episode ({names[0]}), nothing to leave out",
              file=sys.stderr)
    else:
        try:
            keep = sample_episodes(names, args.calibration_sample, args.calibration_seed)
        except CalibrationError as exc:
            raise UsageError(f"--calibration-sample: {exc}") from exc
    # Each episode's entries are staged beside --out as they are embedded (rdd.batch.staging): a run
    # that stops resumes there. Only each segment's first and last frame are encoded, except for
    # the calibration sample.
    staging = Staging(parts_folder(out), settings_hash(args, encoder=[encoder.name, encoder.weights_id],
                                                       views=views, segments=source), suffix=".npz")
    items = []
    for i, ep in enumerate(episodes):
        payload = ([tuple(int(v) for v in seg) for seg in segmentations[i]],
                   None if instructions is None else list(instructions[i]), ep.name in keep)
        items.append((staging.path(i, ep, payload), ep, payload))
    parts = run_staged(items, _embed_one, f"embedding ({encoder.name})", workers=workers,
                       state=(encoder, views, make_cache(args), not args.raw_views),
                       factory=_embedder, factory_args=(args, views),
                       executor=args.executor, address=args.ray_address, read=_staged_entries)
    db = SubtaskDatabase.from_entries(merge_entries(parts), encoder, views, normalize_views=not args.raw_views)
    db.meta["source"] = {"format": args.format, "data": str(args.data),
                         "episodes": names, "segmenter": source}
    if keep:
        try:
            db.meta["calibration"] = calibrate(db, sample=args.calibration_sample,
                                               seed=args.calibration_seed,
                                               progress=lambda xs: progress(xs, "calibration", leave=True))
        except CalibrationError as exc:
            raise UsageError(str(exc)) from exc
    out = db.save(out, overwrite=args.force)
    print(f"built database {out}: {len(db)} sub-tasks from {len(episodes)} episodes "
          f"(encoder {encoder.name}, views {list(views)}, segments {source})")
    staging.remove()
    if db.meta.get("calibration"):
        print(summary(db.meta["calibration"]))
    return 0


def add_parser(sub) -> None:
    """The ``build-db`` subcommand and its options."""
    p = sub.add_parser("build-db", help="segment episodes and build the sub-task database", **with_reader_help())
    data_args(p)
    p.add_argument("--encoder", required=True, help="encoder name (rdd.encoders), e.g. effnet_lite0")
    embed_args(p)
    expert_args(p)
    p.add_argument("--segments", default="auto", metavar="auto|subtasks|expert|FILE",
                   help="sub-tasks from the episodes' annotations (LeRobot language_persistent subtask rows), "
                        "the expert rule, or FILE (a decompose output, e.g. one reviewed with python -m rdd review); "
                        "auto: annotations when every episode has them")
    p.add_argument("--out", required=True, help="database directory")
    force_arg(p)
    add_workers_arg(p)
    p.add_argument("--no-calibrate", action="store_true",
                   help="skip leave-one-episode-out calibration (embeds only segment boundary frames)")
    p.add_argument("--calibration-sample", type=int, default=10, metavar="N",
                   help="episodes held out in turn by calibration (default 10)")
    p.add_argument("--calibration-seed", type=int, default=0)
    p.add_argument("--raw-views", action="store_true",
                   help="concatenate raw per-view embeddings (the official code) instead of L2-normalised ones")
    p.set_defaults(func=cmd_build_db)
