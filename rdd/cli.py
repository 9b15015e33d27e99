"""``python -m rdd``: build a sub-task database, decompose demonstrations, evaluate, plot.

Subcommands: ``build-db``, ``decompose``, ``evaluate``, ``plot``, ``demo``. Every failure is
reported as one line naming the file or option at fault, with exit status 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rdd.data.episode import Episode
from rdd.data.load import FORMATS
from rdd.encoders.embed import DEFAULT_VIEWS

log = logging.getLogger("rdd")
DECOMPOSERS = ("rdd", "uvd", "uniform", "expert", "vlm")
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


def write_json_atomic(path: str | Path, data: Any) -> Path:
    """Write ``data`` as JSON to ``path`` through a temporary file and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(dumps_compact(data))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def progress(items, desc: str):
    """A tqdm progress bar on stderr (silent when tqdm is missing)."""
    try:
        from tqdm import tqdm
    except ImportError:
        return items
    return tqdm(items, desc=desc, unit="ep", file=sys.stderr, disable=None)


def load_data(args: argparse.Namespace) -> list[Episode]:
    """Episodes at ``--data`` in ``--format``, filtered by ``--include`` / ``--exclude``."""
    from rdd.data.load import load_episodes

    if not Path(args.data).exists():
        raise CLIError(f"--data {args.data}: no such file or folder")
    options = parse_options(args.reader_option, "--reader-option")
    try:
        episodes = load_episodes(args.format, args.data, **options)
    except TypeError as exc:
        raise CLIError(f"--reader-option: {exc}") from exc
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


def expert_decomposer(args: argparse.Namespace):
    from rdd.decomposers.expert import ExpertDecomposer

    return ExpertDecomposer(stopping_delta=args.stopping_delta, velocity_source=args.velocity_source)


# ----------------------------------------------------------------------------- build-db
def cmd_build_db(args: argparse.Namespace) -> int:
    """Segment episodes with the expert rule and build the sub-task database."""
    from rdd.database import SubtaskDatabase

    episodes = load_data(args)
    views = resolve_views(args.views, episodes[0])
    encoder = make_encoder(args.encoder, parse_options(args.encoder_option, "--encoder-option"))
    expert = expert_decomposer(args)
    segmentations = []
    for ep in progress(episodes, "expert segments"):
        try:
            segmentations.append(expert.decompose(ep).segments)
        except ValueError as exc:
            raise CLIError(f"--data {args.data}: {exc}") from exc
    cache = make_cache(args)
    if cache is not None:
        from rdd.encoders.embed import episode_frame_vectors

        # Fill the cache episode by episode so the progress bar shows the slow part (encoding).
        for ep in progress(episodes, f"embedding ({encoder.name})"):
            episode_frame_vectors(ep, encoder, views=views, cache=cache)
    db = SubtaskDatabase.build(episodes, segmentations, encoder, views=views, cache=cache)
    db.meta["source"] = {"format": args.format, "data": str(args.data),
                         "episodes": [e.name for e in episodes], "segmenter": "expert"}
    out = db.save(args.out)
    print(f"built database {out}: {len(db)} sub-tasks from {len(episodes)} episodes "
          f"(encoder {encoder.name}, views {list(views)})")
    return 0


# ----------------------------------------------------------------------------- decompose
def make_decomposer(args: argparse.Namespace, first: Episode):
    """The decomposer named by ``--decomposer`` with its options; also the config to record."""
    options = parse_options(args.option, "--option")
    config: dict[str, Any] = {"decomposer": args.decomposer, "options": options}
    name = args.decomposer
    try:
        if name == "expert":
            config.update(stopping_delta=args.stopping_delta, velocity_source=args.velocity_source)
            return expert_decomposer(args), config
        if name == "uniform":
            from rdd.decomposers.uniform import UniformDecomposer

            return UniformDecomposer(**options), config
        if name == "vlm":
            from rdd.decomposers.vlm import VLMDecomposer

            return VLMDecomposer(views=args.views or None, **options), config
        cache = make_cache(args)
        if name == "uvd":
            from rdd.decomposers.uvd import UVDDecomposer

            views = resolve_views(args.views, first)
            encoder = make_encoder(args.encoder or "effnet_lite0",
                                   parse_options(args.encoder_option, "--encoder-option"))
            config.update(encoder=encoder.name, weights_id=encoder.weights_id, views=list(views))
            return UVDDecomposer(encoder=encoder, views=views, cache=cache, **options), config
        if name == "rdd":
            from rdd.database import SubtaskDatabase
            from rdd.decomposers.rdd import RDDDecomposer

            if not args.db:
                raise CLIError("--decomposer rdd needs --db DIR (build one with `python -m rdd build-db`)")
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
            dec = RDDDecomposer(db, encoder=encoder, views=views, cache=cache, **kwargs)
            config.update(encoder=encoder.name, weights_id=encoder.weights_id, views=list(views),
                          db=str(args.db), db_fingerprint=db.fingerprint(), db_size=len(db),
                          alpha=dec.alpha, max_len=dec.max_len, mode=dec.mode, backend=dec.index.name)
            return dec, config
    except TypeError as exc:
        raise CLIError(f"--option for --decomposer {name}: {exc}") from exc
    raise CLIError(f"--decomposer {name!r}: choose one of {', '.join(DECOMPOSERS)}")


def episode_record(episode: Episode, result) -> dict[str, Any]:
    """One episode's entry in the ``decompose`` output."""
    from rdd.segments import validate_segments

    segments = validate_segments(result.segments, episode.num_frames)
    instructions = None
    if result.neighbours is not None:
        instructions = [str(n.get("instruction", "")) for n in result.neighbours]
    return {
        "episode": episode.name,
        "num_frames": episode.num_frames,
        "segments": [[s, e] for s, e in segments],
        "keyframes": [e - 1 for _, e in segments],
        "scores": None if result.scores is None else [float(x) for x in result.scores],
        "instructions": instructions,
        "novelty": None if result.novelty is None else float(result.novelty),
    }


def cmd_decompose(args: argparse.Namespace) -> int:
    """Decompose every episode at ``--data`` and write the segments as JSON."""
    episodes = load_data(args)
    decomposer, config = make_decomposer(args, episodes[0])
    config.update(format=args.format, data=str(args.data), version=OUTPUT_VERSION)
    records = []
    for ep in progress(episodes, f"decompose ({args.decomposer})"):
        try:
            records.append(episode_record(ep, decomposer.decompose(ep)))
        except ValueError as exc:
            raise CLIError(f"episode {ep.name!r} ({args.data}): {exc}") from exc
    out = write_json_atomic(args.out, {"config": config, "episodes": records})
    print(f"wrote {out}: {len(records)} episodes decomposed with {args.decomposer}")
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


def cmd_evaluate(args: argparse.Namespace) -> int:
    """mIoU (paper and symmetric) and boundary P/R/F1 of ``--pred`` against ``--gt``."""
    from rdd.metrics import evaluate_segmentation

    pred: dict[str, dict[str, Any]] = {}
    for path in args.pred:
        for name, rec in read_segments_file(path).items():
            if name in pred:
                raise CLIError(f"--pred {path}: episode {name!r} already came from an earlier --pred file")
            pred[name] = rec
    gt = read_segments_file(args.gt)
    common = [name for name in pred if name in gt]
    if not common:
        raise CLIError(f"--pred {' '.join(args.pred)} and --gt {args.gt} share no episode names")
    missing = sorted(set(pred) - set(gt))
    if missing:
        log.warning("episodes without ground truth are skipped: %s", missing)
    per_episode = {}
    for name in common:
        p, g = pred[name], gt[name]
        if p.get("num_frames") != g.get("num_frames"):
            raise CLIError(f"episode {name!r}: --pred has {p.get('num_frames')} frames, --gt {g.get('num_frames')}")
        try:
            per_episode[name] = evaluate_segmentation(p["segments"], g["segments"], args.tolerance)
        except ValueError as exc:
            raise CLIError(f"episode {name!r}: {exc}") from exc
    keys = list(next(iter(per_episode.values())))
    mean = {k: sum(m[k] for m in per_episode.values()) / len(per_episode) for k in keys}
    result = {"pred": [str(p) for p in args.pred], "gt": str(args.gt), "tolerance": args.tolerance,
              "num_episodes": len(per_episode), "mean": mean, "episodes": per_episode}
    width = max(len(n) for n in per_episode)
    print(f"{'episode':<{width}}  mIoU   sym-mIoU  bP     bR     bF1")
    for name, m in [*per_episode.items(), ("MEAN", mean)]:
        print(f"{name:<{width}}  {m['miou']:.3f}  {m['symmetric_miou']:.3f}     "
              f"{m['boundary_precision']:.3f}  {m['boundary_recall']:.3f}  {m['boundary_f1']:.3f}")
    if args.out:
        write_json_atomic(args.out, result)
    return 0


# ----------------------------------------------------------------------------- plot
def cmd_plot(args: argparse.Namespace) -> int:
    """Timeline figure: one row per prediction file (and ground truth), keyframe thumbnails."""
    from rdd.plots import plot_timelines

    episodes = {e.name: e for e in load_data(args)}
    rows: dict[str, dict[str, list]] = {}
    labels = args.labels or []
    if labels and len(labels) != len(args.pred):
        raise CLIError(f"--labels: {len(labels)} labels for {len(args.pred)} --pred files")
    for i, path in enumerate(args.pred):
        data = json.loads(Path(path).read_text()) if Path(path).is_file() else None
        if data is None:
            raise CLIError(f"--pred {path}: no such file")
        label = labels[i] if labels else str((data.get("config") or {}).get("decomposer") or Path(path).stem)
        # Files with the same label (e.g. leave-one-out folds) merge into one row.
        rows.setdefault(label, {}).update(
            {n: r["segments"] for n, r in read_segments_file(path).items()}
        )
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
    out = plot_timelines(panels, args.out, view=args.view, gt_label=args.gt_label)
    print(f"wrote {out}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the end-to-end demo (``rdd.demo.run_demo``)."""
    try:
        from rdd.demo import run_demo
    except ImportError as exc:
        raise CLIError(f"demo: rdd.demo is not available ({exc})") from exc
    result = run_demo(seed=args.seed, backend=args.backend)  # prints its own summary
    if args.json:
        write_json_atomic(args.json, json.loads(json.dumps(result, default=str)))
        print(f"wrote {args.json}")
    return 0


# ----------------------------------------------------------------------------- parser
def _data_args(p: argparse.ArgumentParser, data_required: bool = True) -> None:
    p.add_argument("--format", choices=FORMATS, required=True, help="episode format of --data")
    p.add_argument("--data", required=data_required, help="one episode or a folder of episodes")
    p.add_argument("--reader-option", action="append", metavar="KEY=VALUE",
                   help="reader keyword (JSON value), e.g. episodes=[1,2] gripper_key=observation.state")
    p.add_argument("--include", nargs="+", metavar="NAME", help="only these episodes")
    p.add_argument("--exclude", nargs="+", metavar="NAME", help="skip these episodes")


def _embed_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--views", nargs="+", help="camera views (default front wrist, else all)")
    p.add_argument("--encoder-option", action="append", metavar="KEY=VALUE")
    p.add_argument("--cache-dir", help="embedding cache folder (default $RDD_CACHE_DIR or ~/.cache/rdd)")
    p.add_argument("--no-cache", action="store_true", help="do not cache embeddings")


def _expert_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--stopping-delta", type=float, default=0.1, help="expert rule: still-arm velocity")
    p.add_argument("--velocity-source", choices=("auto", "joint", "ee"), default="auto")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``python -m rdd``."""
    parser = argparse.ArgumentParser(prog="python -m rdd", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build-db", help="expert-segment episodes and build the sub-task database")
    _data_args(p)
    p.add_argument("--encoder", required=True, help="encoder name (rdd.encoders), e.g. effnet_lite0")
    _embed_args(p)
    _expert_args(p)
    p.add_argument("--out", required=True, help="database directory")
    p.set_defaults(func=cmd_build_db)

    p = sub.add_parser("decompose", help="decompose episodes into sub-task segments")
    _data_args(p)
    p.add_argument("--decomposer", choices=DECOMPOSERS, required=True)
    p.add_argument("--encoder", help="encoder for rdd/uvd (rdd: default the database's)")
    p.add_argument("--db", help="sub-task database directory (rdd)")
    p.add_argument("--alpha", type=float, help="rdd: weight of the duration term")
    p.add_argument("--max-len", type=int, help="rdd: longest segment in frames")
    p.add_argument("--option", action="append", metavar="KEY=VALUE",
                   help="decomposer keyword, e.g. n_segments=5 (uniform), min_interval=10 (uvd)")
    _embed_args(p)
    _expert_args(p)
    p.add_argument("--out", required=True, help="output JSON file")
    p.set_defaults(func=cmd_decompose)

    p = sub.add_parser("evaluate", help="compare decompose outputs with ground truth")
    p.add_argument("--pred", nargs="+", required=True, help="decompose outputs (episodes merged)")
    p.add_argument("--gt", required=True)
    p.add_argument("--tolerance", type=int, default=2, help="boundary tolerance in frames")
    p.add_argument("--out", help="write the metrics JSON here")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("plot", help="timeline figure of one or more decompose outputs")
    p.add_argument("--pred", nargs="+", required=True)
    _data_args(p)
    p.add_argument("--gt", help="ground-truth decompose output (default: the episodes' own segments)")
    p.add_argument("--gt-label", default="ground truth")
    p.add_argument("--labels", nargs="+", help="row labels, one per --pred file")
    p.add_argument("--episode", nargs="+", help="episodes to draw (default: all in --pred)")
    p.add_argument("--view", help="camera view for thumbnails (default: the first)")
    p.add_argument("--out", required=True, help="PNG file")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("demo", help="run the end-to-end demo")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--backend", default="exact", help="retrieval backend: exact, annoy or faiss")
    p.add_argument("--json", help="also write the demo's summary here")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m rdd`` and the ``rdd`` script."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except CLIError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (FileNotFoundError, KeyError, ValueError, ImportError, RuntimeError) as exc:
        # Library errors already name the file/field at fault; show them without a traceback.
        if args.verbose:
            raise
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"error ({args.command}): {msg}", file=sys.stderr)
        return 2
