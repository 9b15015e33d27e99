"""``python -m rdd``: build a sub-task database, decompose demonstrations, evaluate, plot.

Subcommands: ``build-db``, ``calibrate``, ``decompose``, ``evaluate``, ``plot``, ``demo``. Every expected failure
is reported as one line naming the file or option at fault, with exit status 2 (``-v`` also prints
the traceback); Ctrl-C stops with status 130 and leaves no partial output. Outputs are written
atomically and never replace an existing file or folder without ``--force``.
"""

from __future__ import annotations

import argparse
import inspect
import json
import logging
import pickle
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rdd.atomic import write_json_atomic as _write_json
from rdd.data.episode import Episode
from rdd.data.load import FORMATS
from rdd.encoders.embed import DEFAULT_VIEWS
from rdd.progress import track_episodes
from rdd.registry import available, component

log = logging.getLogger("rdd")
# The registry's decomposers (rdd.registry: one module each in rdd/decomposers/), the same the
# harness's conf/decomposer/*.yaml name as _target_.
DECOMPOSERS = tuple(available("decomposer"))
OUTPUT_VERSION = 1


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


# ----------------------------------------------------------------------------- helpers
def parse_options(items: Sequence[str] | None, flag: str) -> dict[str, Any]:
    """``KEY=VALUE`` pairs; VALUE is read as JSON when it parses, else kept as a string."""
    out: dict[str, Any] = {}
    for item in items or ():
        if "=" not in item:
            raise CLIError(f"{flag} {item!r}: expected KEY=VALUE")
        key, value = item.split("=", 1)
        key = key.strip().replace("-", "_")
        if not key.isidentifier():
            raise CLIError(f"{flag} {item!r}: {key!r} is not a valid option name")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def dumps_compact(data: Any) -> str:
    """JSON with the top level indented and each list item of ``episodes`` on one line."""
    if isinstance(data, dict) and isinstance(data.get("episodes"), list):
        head = {k: v for k, v in data.items() if k != "episodes"}
        lines = ",\n  ".join(json.dumps(r) for r in data["episodes"])
        inner = json.dumps(head, indent=1)[:-1].rstrip()
        sep = ",\n" if head else "\n"
        return f'{inner}{sep} "episodes": [\n  {lines}\n ]\n}}\n'
    return json.dumps(data, indent=1) + "\n"


def check_output(path: str | Path | None, flag: str, force: bool, kind: str = "file") -> Path | None:
    """Refuse an output path that is a folder (for files), a file (for folders), or exists without --force."""
    if path is None:
        return None
    path = Path(path)
    if kind == "file" and path.is_dir():
        raise CLIError(f"{flag} {path}: is an existing folder; give a file name")
    if kind == "dir" and path.exists() and not path.is_dir():
        raise CLIError(f"{flag} {path}: is an existing file; give a folder name")
    if path.exists() and not force:
        raise CLIError(f"{flag} {path}: already exists; pass --force to replace it")
    return path


def progress(items, desc: str):
    """A tqdm bar over ``items`` on stderr (a terminal only); frames-aware bars: ``track_episodes``."""
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a dependency
        return items
    return tqdm(items, desc=desc, file=sys.stderr, disable=None, dynamic_ncols=True)


def write_json_atomic(path: str | Path, data: Any, overwrite: bool = True) -> Path:
    """Write ``data`` as compact JSON to ``path`` atomically (``rdd.atomic``)."""
    return _write_json(path, data, overwrite=overwrite, dumps=dumps_compact)


def load_data(args: argparse.Namespace) -> list[Episode]:
    """Episodes at ``--data`` in ``--format``, filtered by ``--include`` / ``--exclude``."""
    from rdd.data.load import load_episodes

    if not Path(args.data).exists():
        raise CLIError(f"--data {args.data}: no such file or folder")
    options = parse_options(args.reader_option, "--reader-option")
    try:
        episodes = load_episodes(args.format, args.data, **options)
    except TypeError as exc:
        raise CLIError(f"--reader-option for --format {args.format}: {exc}".replace("load_episodes() ", "")) from exc
    except ValueError as exc:
        if "reader option" in str(exc):
            raise CLIError(f"--reader-option: {exc}") from exc
        raise
    if args.format == "lerobot" and episodes:
        from rdd.data.lerobot import describe_layout

        print(f"lerobot: {describe_layout(episodes[0])}", file=sys.stderr)
    names = [e.name for e in episodes]
    for flag, wanted in (("--include", args.include), ("--exclude", args.exclude)):
        unknown = sorted(set(wanted or ()) - set(names))
        if unknown:
            raise CLIError(f"{flag}: no episode named {unknown} in {args.data}; have {names}")
    if args.include:
        episodes = [e for e in episodes if e.name in set(args.include)]
    if args.exclude:
        episodes = [e for e in episodes if e.name not in set(args.exclude)]
    if not episodes:
        raise CLIError(f"--data {args.data}: no episodes left after --include/--exclude")
    return episodes


def resolve_views(args_views: Sequence[str] | None, episode: Episode) -> tuple[str, ...]:
    """``--views``, else front+wrist when the episode has them, else all its views."""
    if args_views:
        views = tuple(args_views)
    elif all(v in episode.views for v in DEFAULT_VIEWS):
        views = DEFAULT_VIEWS
    else:
        views = tuple(sorted(episode.views))
    missing = [v for v in views if v not in episode.views]
    if missing:
        raise CLIError(f"--views: episode {episode.name!r} has no view {missing}; has {sorted(episode.views)}")
    if not views:
        raise CLIError(f"episode {episode.name!r} has no camera views to embed")
    return views


def make_encoder(name: str, options: dict[str, Any]):
    """``rdd.encoders.load_encoder`` with errors turned into CLI errors."""
    try:
        from rdd.encoders import load_encoder
    except ImportError as exc:  # pragma: no cover - encoders are part of the package
        raise CLIError(f"--encoder {name}: encoders unavailable ({exc})") from exc
    try:
        return load_encoder(name, **options)
    except (ValueError, TypeError, FileNotFoundError, ImportError) as exc:
        raise CLIError(f"--encoder {name}: {exc}") from exc


def make_cache(args: argparse.Namespace):
    """The embedding cache (``--cache-dir``, default location) or None with ``--no-cache``."""
    if args.no_cache:
        return None
    from rdd.encoders.cache import EmbeddingCache

    return EmbeddingCache(args.cache_dir)


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


def embed_all(episodes: Sequence[Episode], encoder, views: Sequence[str], cache) -> None:
    """Fill the embedding cache episode by episode so the progress bar shows the slow part."""
    if cache is None:
        return
    from rdd.encoders.embed import episode_frame_vectors

    for ep in track_episodes(episodes, f"embedding ({encoder.name})"):
        episode_frame_vectors(ep, encoder, views=views, cache=cache)


# ----------------------------------------------------------------------------- build-db
def cmd_build_db(args: argparse.Namespace) -> int:
    """Segment episodes (their sub-task annotations or the expert rule), build and calibrate the database."""
    from rdd.calibrate import CalibrationError, calibrate, sample_episodes, summary
    from rdd.database import SubtaskDatabase

    out = check_output(args.out, "--out", args.force, kind="dir")
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
            raise CLIError(f"--segments subtasks: episodes {missing} of --data {args.data} carry no sub-task "
                           "annotations (LeRobot: language_persistent subtask rows)")
        segmentations = [e.segments for e in episodes]
        instructions = [e.instructions or [""] * len(e.segments) for e in episodes]
    else:
        expert = expert_decomposer(args)
        segmentations = []
        for ep in episodes:
            try:
                segmentations.append(expert.decompose(ep).segments)
            except ValueError as exc:
                raise CLIError(f"--data {args.data}: {exc}") from exc
        instructions = None
    print(f"segments: {source} ({sum(len(s) for s in segmentations)} sub-tasks in {len(episodes)} episodes)",
          file=sys.stderr)
    names = [e.name for e in episodes]
    keep: list[str] = []
    if args.no_calibrate:
        pass
    elif len(set(names)) < 2:
        print(f"warning: calibration skipped: --data {args.data} has one episode, nothing to leave out",
              file=sys.stderr)
    else:
        try:
            keep = sample_episodes(names, args.calibration_sample, args.calibration_seed)
        except CalibrationError as exc:
            raise CLIError(f"--calibration-sample: {exc}") from exc
    cache = make_cache(args)
    # Only each segment's first and last frame are encoded, except for the calibration sample.
    embed_all([e for e in episodes if e.name in keep], encoder, views, cache)
    db = SubtaskDatabase.build(episodes, segmentations, encoder, views=views, cache=cache,
                               instructions=instructions, normalize_views=not args.raw_views,
                               keep_frames=keep)
    db.meta["source"] = {"format": args.format, "data": str(args.data),
                         "episodes": names, "segmenter": source}
    if keep:
        try:
            db.meta["calibration"] = calibrate(db, sample=args.calibration_sample,
                                               seed=args.calibration_seed,
                                               progress=lambda xs: progress(xs, "calibration"))
        except CalibrationError as exc:
            raise CLIError(str(exc)) from exc
    out = db.save(out, overwrite=args.force)
    print(f"built database {out}: {len(db)} sub-tasks from {len(episodes)} episodes "
          f"(encoder {encoder.name}, views {list(views)}, segments {source})")
    if db.meta.get("calibration"):
        print(summary(db.meta["calibration"]))
    return 0


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
            raise CLIError(f"{flag} {text!r}: {item!r} is not a valid value") from exc
    if not values:
        raise CLIError(f"{flag} {text!r}: the grid is empty (give comma-separated values)")
    return values


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Rerun leave-one-episode-out calibration on a saved database; record it in its manifest."""
    from rdd.calibrate import CalibrationError, calibrate, default_grid, summary
    from rdd.database import SubtaskDatabase

    db = SubtaskDatabase.load(args.db)
    grid = default_grid(db)
    for key, flag, cast in (("alpha", "--alpha", float), ("min_len", "--min-len", int),
                            ("max_len", "--max-len", int)):
        values = _grid_values(getattr(args, key), flag, cast)
        if values is not None:
            grid[key] = values
    try:
        cal = calibrate(db, grid=grid, sample=args.sample, seed=args.seed, backend=args.backend,
                        progress=lambda xs: progress(xs, "calibration"))
    except CalibrationError as exc:
        raise CLIError(f"--db {args.db}: {exc}") from exc
    if cal is None:
        print(f"warning: calibration skipped: --db {args.db} holds one episode, nothing to leave out",
              file=sys.stderr)
        return 0
    db.save_calibration(cal)
    print(summary(cal))
    print(f"recorded in {Path(args.db) / 'manifest.json'}")
    return 0


# ----------------------------------------------------------------------------- decompose
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


FALLBACK_FIELDS = ("task", "episode", "index", "count", "start", "end")


def fallback_instruction(template: str, episode: Episode, index: int, count: int, segment) -> str:
    """``--fallback-instruction`` filled in for one segment (fields: FALLBACK_FIELDS)."""
    try:
        return template.format(task=episode.goal or episode.task, episode=episode.name, index=index + 1,
                               count=count, start=int(segment[0]), end=int(segment[1]))
    except (KeyError, IndexError, ValueError) as exc:
        raise CLIError(f"--fallback-instruction {template!r}: {exc!r}; fields: "
                       + ", ".join("{" + f + "}" for f in FALLBACK_FIELDS)) from exc


def episode_record(episode: Episode, result) -> dict[str, Any]:
    """One episode's entry in the ``decompose`` output."""
    from rdd.segments import validate_segments

    segments = validate_segments(result.segments, episode.num_frames)
    instructions = getattr(result, "instructions", None)
    if instructions is None and result.neighbours is not None:
        instructions = [n.get("instruction") for n in result.neighbours]
    return {
        "episode": episode.name,
        "num_frames": episode.num_frames,
        "segments": [[s, e] for s, e in segments],
        "keyframes": [e - 1 for _, e in segments],
        "scores": None if result.scores is None else [float(x) for x in result.scores],
        "instructions": None if instructions is None else ["" if t is None else str(t) for t in instructions],
        "instruction_sources": None,
        "novelty": None if result.novelty is None else float(result.novelty),
    }


def fill_instructions(record: dict[str, Any], episode: Episode, labeler=None, fallback: str | None = None) -> None:
    """Give every segment without an instruction the labeler's, else the fallback's (recording which)."""
    if labeler is None and fallback is None:
        return
    segments = [tuple(s) for s in record["segments"]]
    given = record["instructions"] or [""] * len(segments)
    sources = ["decomposer" if t and t.strip() else None for t in given]
    texts = list(given)
    missing = [j for j, src in enumerate(sources) if src is None]
    if labeler is not None and missing:
        for j, text in zip(missing, labeler.label_all(episode, [segments[j] for j in missing]), strict=True):
            if text and text.strip():
                texts[j], sources[j] = text, "labeler"
    if fallback is not None:
        for j, src in enumerate(sources):
            if src is None:
                texts[j] = fallback_instruction(fallback, episode, j, len(segments), segments[j])
                sources[j] = "fallback"
    record["instructions"], record["instruction_sources"] = texts, sources


def make_labeler(args: argparse.Namespace):
    """``--labeler retrieval``: the nearest entry of ``--label-db`` (default ``--db``) names a segment."""
    if args.labeler is None:
        return None
    from rdd.database import SubtaskDatabase
    from rdd.retrieval_labeler import RetrievalLabeler

    path = args.label_db or args.db
    if not path:
        raise CLIError("--labeler retrieval needs --label-db DIR (a database whose entries carry instructions)")
    db = SubtaskDatabase.load(path)
    enc_name = db.meta.get("encoder")
    if not enc_name:
        raise CLIError(f"--label-db {path} records no encoder")
    encoder = make_encoder(enc_name, parse_options(args.encoder_option, "--encoder-option"))
    try:
        return RetrievalLabeler(db, encoder, cache=make_cache(args))
    except ValueError as exc:
        raise CLIError(f"--label-db {path}: {exc}") from exc


def lerobot_subtasks(episodes: Sequence[Episode], records: Sequence[dict[str, Any]], decomposer: str,
                     ) -> dict[int, tuple[list, list[str]]]:
    """Episode index -> (segments, instructions) for the LeRobot writer; every segment needs an instruction."""
    out = {}
    for ep, rec in zip(episodes, records, strict=True):
        instr = rec["instructions"]
        empty = [j for j, t in enumerate(instr or [None] * len(rec["segments"])) if not t or not str(t).strip()]
        if empty:
            raise CLIError(
                f"--write-lerobot: decomposer {decomposer} gives no instruction for segments {empty} of episode "
                f"{ep.name!r} (rdd takes them from its database's entries: build it from annotated episodes); "
                "pass --labeler retrieval --label-db DB (a database with instructions) or "
                "--fallback-instruction TEMPLATE, e.g. '{task} (step {index} of {count})'"
            )
        out[int(ep.meta["episode_index"])] = ([tuple(s) for s in rec["segments"]], list(instr))
    return out


def cmd_decompose(args: argparse.Namespace) -> int:
    """Decompose every episode at ``--data``; write the segments as JSON and/or into a LeRobot copy."""
    if args.out is None and args.write_lerobot is None:
        raise CLIError("decompose needs --out FILE.json, --write-lerobot DIR, or both")
    if args.write_lerobot is not None and args.format != "lerobot":
        raise CLIError(f"--write-lerobot needs --format lerobot, not {args.format}")
    out = check_output(args.out, "--out", args.force)
    lerobot_out = check_output(args.write_lerobot, "--write-lerobot", False, kind="dir")
    if lerobot_out is not None and Path(args.data).resolve() in (lerobot_out.resolve(), *lerobot_out.resolve().parents):
        raise CLIError(f"--write-lerobot {lerobot_out}: refusing to write into the source dataset {args.data}")
    if args.fallback_instruction is not None:
        fallback_instruction(args.fallback_instruction, Episode(name="check", views={}), 0, 1, (0, 1))
    episodes = load_data(args)
    decomposer, config = make_decomposer(args, episodes[0])
    labeler = make_labeler(args)
    config.update(format=args.format, data=str(args.data), version=OUTPUT_VERSION,
                  fallback_instruction=args.fallback_instruction, labeler=args.labeler,
                  label_db=None if labeler is None else str(args.label_db or args.db))
    if args.decomposer in ("rdd", "uvd"):
        embed_all(episodes, decomposer.encoder, decomposer.views, getattr(decomposer, "cache", None))
    records = []
    for ep in track_episodes(episodes, f"decompose ({args.decomposer})"):
        try:
            record = episode_record(ep, decomposer.decompose(ep))
            fill_instructions(record, ep, labeler, args.fallback_instruction)
            records.append(record)
        except ValueError as exc:
            raise CLIError(f"episode {ep.name!r} ({args.data}): {exc}") from exc
    subtasks = lerobot_subtasks(episodes, records, args.decomposer) if lerobot_out is not None else None
    if out is not None:
        write_json_atomic(out, {"config": config, "episodes": records}, overwrite=args.force)
        print(f"wrote {out}: {len(records)} episodes decomposed with {args.decomposer}")
    if subtasks is not None:
        from rdd.data.lerobot_write import write_subtasks

        write_subtasks(args.data, lerobot_out, subtasks)
        print(f"wrote {lerobot_out}: LeRobot dataset with sub-tasks of {len(subtasks)} episodes "
              "(language_persistent)")
    return 0


# ----------------------------------------------------------------------------- evaluate
def read_segments_file(path: str | Path) -> dict[str, dict[str, Any]]:
    """Episodes of a ``decompose`` output file by name."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise CLIError(f"{path}: no such file") from exc
    except json.JSONDecodeError as exc:
        raise CLIError(f"{path}: invalid JSON ({exc})") from exc
    if not isinstance(data, dict) or not isinstance(data.get("episodes"), list):
        raise CLIError(f"{path}: expected an object with an 'episodes' list (a decompose output)")
    out = {}
    for i, rec in enumerate(data["episodes"]):
        if not isinstance(rec, dict) or "episode" not in rec or "segments" not in rec:
            raise CLIError(f"{path}: episodes[{i}] lacks 'episode' or 'segments'")
        out[str(rec["episode"])] = rec
    return out


def pred_methods(items: Sequence[str], flag: str = "--pred") -> dict[str, dict[str, dict[str, Any]]]:
    """``LABEL=FILE`` (or bare ``FILE``, labelled by its decomposer) -> {label: {episode: record}}.

    Files given the same explicit label (e.g. leave-one-out folds) are merged as episodes of one
    method; two unlabelled files whose decomposer is the same are an error (name them).
    """
    methods: dict[str, dict[str, dict[str, Any]]] = {}
    explicit: dict[str, bool] = {}
    for item in items:
        label, sep, path = item.partition("=")
        if not sep or not label or Path(item).exists():
            label, path, named = "", item, False
        else:
            named = True
        records = read_segments_file(path)
        if not named:
            config = json.loads(Path(path).read_text()).get("config") or {}
            label = str(config.get("decomposer") or Path(path).stem)
        if label in methods and not (named and explicit[label]):
            raise CLIError(f"{flag} {item}: a method is already labelled {label!r}; "
                           f"name them, e.g. {flag} a={path} b=other.json (same name = one method's folds)")
        explicit[label] = named
        merged = methods.setdefault(label, {})
        for name, rec in records.items():
            if name in merged:
                raise CLIError(f"{flag} {item}: episode {name!r} of method {label!r} came from an earlier file")
            merged[name] = rec
    return methods


def cmd_evaluate(args: argparse.Namespace) -> int:
    """mIoU (paper and symmetric) and boundary P/R/F1 of each ``--pred`` method against ``--gt``."""
    from rdd.compare import compare_methods, format_table

    out = check_output(args.out, "--out", args.force)
    methods = pred_methods(args.pred)
    gt = read_segments_file(args.gt)
    try:
        result = compare_methods(methods, gt, args.tolerance, allow_partial=args.allow_partial)
    except ValueError as exc:
        raise CLIError(str(exc)) from exc
    for label, m in result["methods"].items():
        if m["left_out"]["pred_only"] or m["left_out"]["gt_only"]:
            log.warning("--pred %s: scored %d shared episodes; left out %s", label, m["num_episodes"],
                        m["left_out"])
    result.update(pred=list(args.pred), gt=str(args.gt))
    print(format_table(result))
    if out is not None:
        write_json_atomic(out, result, overwrite=args.force)
    return 0


# ----------------------------------------------------------------------------- plot
def cmd_plot(args: argparse.Namespace) -> int:
    """Timeline figure: one row per method (and ground truth), keyframe thumbnails."""
    from rdd.plots import figure_format, plot_timelines

    out = check_output(args.out, "--out", args.force)
    try:
        figure_format(out)
    except ValueError as exc:
        raise CLIError(f"--out {exc}") from exc
    labels = args.labels or []
    if labels and len(labels) != len(args.pred):
        raise CLIError(f"--labels: {len(labels)} labels for {len(args.pred)} --pred files")
    items = [f"{lab}={p}" for lab, p in zip(labels, args.pred, strict=True)] if labels else args.pred
    methods = pred_methods(items)
    rows = {label: {n: r["segments"] for n, r in recs.items()} for label, recs in methods.items()}
    episodes = {e.name: e for e in load_data(args)}
    gt = {n: r["segments"] for n, r in read_segments_file(args.gt).items()} if args.gt else {}
    names = args.episode or [n for n in episodes if any(n in r for r in rows.values())]
    if not names:
        raise CLIError(f"--pred files share no episode with --data {args.data}")
    panels = []
    for name in names:
        if name not in episodes:
            raise CLIError(f"--episode {name!r} is not in --data {args.data}")
        ep_rows = {label: r[name] for label, r in rows.items() if name in r}
        truth = gt.get(name) or episodes[name].segments
        panels.append((episodes[name], ep_rows, truth))
    out = plot_timelines(panels, out, view=args.view, gt_label=args.gt_label, overwrite=args.force)
    print(f"wrote {out}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the end-to-end demo (``rdd.demo.run_demo``)."""
    try:
        from rdd.demo import run_demo
    except ImportError as exc:
        raise CLIError(f"demo: rdd.demo is not available ({exc})") from exc
    check_output(args.json, "--json", args.force)
    result = run_demo(seed=args.seed, backend=args.backend)  # prints its own summary
    if args.json:
        write_json_atomic(args.json, json.loads(json.dumps(result, default=str)), overwrite=args.force)
        print(f"wrote {args.json}")
    return 0


# ----------------------------------------------------------------------------- parser
def _data_args(p: argparse.ArgumentParser, data_required: bool = True) -> None:
    p.add_argument("--format", choices=FORMATS, required=True, help="episode format of --data")
    p.add_argument("--data", required=data_required, help="one episode or a folder of episodes")
    p.add_argument("--reader-option", action="append", metavar="KEY=VALUE",
                   help="reader keyword (JSON value); the options of each format are listed below")
    p.add_argument("--include", nargs="+", metavar="NAME", help="only these episodes")
    p.add_argument("--exclude", nargs="+", metavar="NAME", help="skip these episodes")


def _embed_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--views", nargs="+", help="camera views (default front wrist, else all)")
    p.add_argument("--encoder-option", action="append", metavar="KEY=VALUE")
    p.add_argument("--cache-dir", help="embedding cache folder (default $RDD_CACHE_DIR or ~/.cache/rdd)")
    p.add_argument("--no-cache", action="store_true", help="do not cache embeddings")


def _expert_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--stopping-delta", type=float, default=0.1,
                   help="expert rule (stop_test=absolute, RLBench): still-arm joint velocity; recorded "
                        "data with an fps (LeRobot) uses the scale-aware test, see --option stopping_fraction")
    p.add_argument("--velocity-source", choices=("auto", "joint", "ee"), default="auto")


def _force_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--force", action="store_true", help="replace an existing output")


def reader_help() -> str:
    """The reader options of every format, for ``--help``."""
    from rdd.data.lerobot import READER_OPTIONS

    lines = ["reader options (--reader-option KEY=VALUE, VALUE as JSON):",
             "  rlbench: views=[\"front\",\"wrist\"] (null: every <view>_rgb folder)",
             "  native: none", "  lerobot:"]
    lines += [f"    {k}: {v}" for k, v in READER_OPTIONS.items()]
    return "\n".join(lines)


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


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``python -m rdd``."""
    parser = argparse.ArgumentParser(prog="python -m rdd", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log each step, and print the traceback of an error")
    sub = parser.add_subparsers(dest="command", required=True)
    fmt = {"formatter_class": argparse.RawDescriptionHelpFormatter, "epilog": reader_help()}

    p = sub.add_parser("build-db", help="segment episodes and build the sub-task database", **fmt)
    _data_args(p)
    p.add_argument("--encoder", required=True, help="encoder name (rdd.encoders), e.g. effnet_lite0")
    _embed_args(p)
    _expert_args(p)
    p.add_argument("--segments", choices=("auto", "subtasks", "expert"), default="auto",
                   help="sub-tasks from the episodes' annotations (LeRobot language_persistent subtask rows) "
                        "or the expert rule; auto: annotations when every episode has them")
    p.add_argument("--out", required=True, help="database directory")
    _force_arg(p)
    p.add_argument("--no-calibrate", action="store_true",
                   help="skip leave-one-episode-out calibration (embeds only segment boundary frames)")
    p.add_argument("--calibration-sample", type=int, default=10, metavar="N",
                   help="episodes held out in turn by calibration (default 10)")
    p.add_argument("--calibration-seed", type=int, default=0)
    p.add_argument("--raw-views", action="store_true",
                   help="concatenate raw per-view embeddings (the official code) instead of L2-normalised ones")
    p.set_defaults(func=cmd_build_db)

    p = sub.add_parser("calibrate", help="rerun leave-one-episode-out calibration of a database")
    p.add_argument("--db", required=True, help="database directory (built without --no-calibrate)")
    p.add_argument("--alpha", help="comma-separated alpha grid (default 0,0.1,0.25,0.5,1,2)")
    p.add_argument("--min-len", help="comma-separated min_len grid (default 2,4)")
    p.add_argument("--max-len", help="comma-separated max_len grid, 'none' = unbounded "
                   "(default none and 1.25x, 2x the longest stored segment)")
    p.add_argument("--sample", type=int, default=10, help="episodes held out in turn (default 10)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--backend", default="exact", help="retrieval backend for calibration")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("decompose", help="decompose episodes into sub-task segments",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=decomposer_help() + "\n\n" + reader_help())
    _data_args(p)
    p.add_argument("--decomposer", choices=DECOMPOSERS, required=True)
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
    _embed_args(p)
    _expert_args(p)
    p.add_argument("--out", help="output JSON file")
    p.add_argument("--write-lerobot", metavar="DIR",
                   help="also write DIR, a copy of the LeRobot dataset --data whose language_persistent "
                        "column carries the sub-tasks (new folder; never the source)")
    p.add_argument("--labeler", choices=("retrieval",),
                   help="name segments the decomposer gives no instruction: retrieval = the instruction of "
                        "the nearest entry of --label-db")
    p.add_argument("--label-db", metavar="DIR", help="database for --labeler retrieval (default --db)")
    p.add_argument("--fallback-instruction", metavar="TEMPLATE",
                   help="instruction for segments the decomposer gives none, with fields "
                        + ", ".join("{" + f + "}" for f in FALLBACK_FIELDS))
    _force_arg(p)
    p.set_defaults(func=cmd_decompose)

    p = sub.add_parser("evaluate", help="compare decompose outputs (one or more methods) with ground truth")
    p.add_argument("--pred", nargs="+", required=True, metavar="[LABEL=]FILE",
                   help="one decompose output per method, e.g. rdd=rdd.json uvd=uvd.json (same LABEL twice: "
                        "one method's folds)")
    p.add_argument("--gt", required=True)
    p.add_argument("--tolerance", type=int, default=2, help="boundary tolerance in frames")
    p.add_argument("--allow-partial", action="store_true",
                   help="score only the episodes a method shares with --gt (default: differing sets are an error)")
    p.add_argument("--out", help="write the metrics JSON here")
    _force_arg(p)
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("plot", help="timeline figure of one or more decompose outputs", **fmt)
    p.add_argument("--pred", nargs="+", required=True, metavar="[LABEL=]FILE")
    _data_args(p)
    p.add_argument("--gt", help="ground-truth decompose output (default: the episodes' own segments)")
    p.add_argument("--gt-label", default="ground truth")
    p.add_argument("--labels", nargs="+", help="row labels, one per --pred file")
    p.add_argument("--episode", nargs="+", help="episodes to draw (default: all in --pred)")
    p.add_argument("--view", help="camera view for thumbnails (default: the first)")
    p.add_argument("--out", required=True, help="figure file: .png, .pdf or .svg")
    _force_arg(p)
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("demo", help="run the end-to-end demo")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--backend", default="exact", help="retrieval backend: exact, annoy or faiss")
    p.add_argument("--json", help="also write the demo's summary here")
    _force_arg(p)
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m rdd`` and the ``rdd`` script."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"\ninterrupted ({args.command}): stopped; no partial output was written", file=sys.stderr)
        return 130
    except CLIError as exc:
        return _report(args, str(exc), "error")
    except (FileNotFoundError, KeyError, ValueError, ImportError, RuntimeError, OSError,
            pickle.UnpicklingError) as exc:
        # Library errors already name the file/field at fault; show them without a traceback.
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        return _report(args, str(msg), f"error ({args.command})")


def _report(args: argparse.Namespace, message: str, prefix: str) -> int:
    """Print an expected error as one line (after its traceback with -v); exit status 2."""
    if args.verbose:
        traceback.print_exc()
    print(f"{prefix}: {message}", file=sys.stderr)
    return 2
