"""What every subcommand shares: the one-line error, safe outputs, episodes in, encoders and the cache."""

from __future__ import annotations

import argparse
import json
import logging
import os
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

from rdd.atomic import check_writable
from rdd.atomic import write_json_atomic as _write_json
from rdd.data.episode import Episode
from rdd.encoders.embed import DEFAULT_VIEWS, STATE_VIEW, has_view
from rdd.errors import UsageError

log = logging.getLogger("rdd")



def parse_options(items: Sequence[str] | None, flag: str) -> dict[str, Any]:
    """``KEY=VALUE`` pairs; VALUE is read as JSON when it parses, else kept as a string."""
    out: dict[str, Any] = {}
    for item in items or ():
        if "=" not in item:
            raise UsageError(f"{flag} {item!r}: expected KEY=VALUE")
        key, value = item.split("=", 1)
        key = key.strip().replace("-", "_")
        if not key.isidentifier():
            raise UsageError(f"{flag} {item!r}: {key!r} is not a valid option name")
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


# What the check calls an input in its message, when a flag alone says too little.
INPUT_NAMES = {"--data": "the source dataset --data", "--cache-dir": "the embedding cache"}
Inputs = Sequence[tuple[str, str | Path | None]]


def check_output(path: str | Path | None, flag: str, force: bool, kind: str = "file",
                 inputs: Inputs = ()) -> Path | None:
    """Refuse an output path, before any work, that is a folder (for files) or a file (for folders),
    is or holds or lies inside an input (``(flag, path)`` pairs; ``--force`` or not), exists without
    ``--force``, or cannot be written (an unwritable folder, a name too long)."""
    if path is None:
        return None
    path = Path(path)
    try:  # first: a name too long for its filesystem makes even is_dir() fail
        check_writable(path)
    except OSError as exc:
        raise UsageError(f"{flag} {path}: cannot be written: {exc.strerror}") from exc
    if kind == "file" and path.is_dir():
        raise UsageError(f"{flag} {path}: is an existing folder; give a file name")
    if kind == "dir" and path.exists() and not path.is_dir():
        raise UsageError(f"{flag} {path}: is an existing file; give a folder name")
    check_not_input(path, flag, kind, inputs)
    if path.exists() and not force:
        raise UsageError(f"{flag} {path}: already exists; pass --force to replace it")
    return path


def check_not_input(path: Path, flag: str, kind: str, inputs: Inputs) -> None:
    """Refuse an output that is an input, holds one (replacing it would delete the input), or lies
    inside an input folder as a folder or in place of one of its files (a new file beside them is fine)."""
    target = _resolved(path)
    for in_flag, in_path in inputs:
        if in_path is None:
            continue
        source = _resolved(in_path)
        if target == source:
            relation = "is"
        elif target in source.parents:
            relation = "holds"
        elif source in target.parents and (kind == "dir" or path.exists() or path.is_symlink()):
            relation = "is inside"
        else:
            continue
        raise UsageError(f"{flag} {path}: {relation} {INPUT_NAMES.get(in_flag, 'the input ' + in_flag)} {in_path}; "
                       "an output never replaces or goes inside an input of the same command, --force or not")


def _resolved(path: str | Path) -> Path:
    """``path`` absolute, with ``~``, ``.``, ``..`` and symbolic links resolved (as far as it exists)."""
    return Path(path).expanduser().resolve()


def cache_input(args: argparse.Namespace) -> tuple[str, Path | None]:
    """The embedding cache folder as an input of ``check_output`` (None with ``--no-cache``)."""
    if args.no_cache:
        return "--cache-dir", None
    from rdd.encoders.cache import default_cache_dir

    return "--cache-dir", Path(args.cache_dir) if args.cache_dir else default_cache_dir()


def write_json_atomic(path: str | Path, data: Any, overwrite: bool = True) -> Path:
    """Write ``data`` as compact JSON to ``path`` atomically (``rdd.atomic``)."""
    return _write_json(path, data, overwrite=overwrite, dumps=dumps_compact)


def full_disk(args: argparse.Namespace, exc: OSError) -> str:
    """The one line for a full disk or quota: the file that could not be written and its role."""
    from rdd.batch.staging import parts_folder
    from rdd.encoders.cache import default_cache_dir

    path = Path(os.path.abspath(exc.filename)) if exc.filename else None
    roles: list[tuple[Path | None, str, str]] = []
    for flag in ("out", "write_lerobot"):
        target = getattr(args, flag, None)
        if target is None:
            continue
        shown = "--" + flag.replace("_", "-")
        roles.append((parts_folder(Path(target)), f"staging: the resumable parts of {shown} {target}",
                      f"free space beside {shown}"))
        kind = "the database" if args.command == "build-db" else "the output"
        roles.append((Path(target), f"{kind} {shown}", f"free space there or give another {shown}"))
    if getattr(args, "db", None):
        roles.append((Path(args.db), f"the database --db {args.db}", "free space there"))
    cache = getattr(args, "cache_dir", None)
    roles.append(((Path(cache) if cache else default_cache_dir()).parent, "the cache",
                  "free space there, or give another --cache-dir or --no-cache"))
    for root, role, fix in roles:
        root = Path(os.path.abspath(root))
        if path is not None and (path == root or root in path.parents):
            return f"no space left on device: cannot write {path} ({role}); {fix}"
    where = f"cannot write {path}" if path is not None else "a write failed"
    return f"no space left on device: {where}; free space there and run again"


def load_data(args: argparse.Namespace, only: Collection[str] | None = None) -> list[Episode]:
    """Episodes at ``--data`` in ``--format``, filtered by ``--include`` / ``--exclude`` (and, when given,
    to the names in ``only``) before any episode is read, so an excluded episode's files are never opened."""
    from rdd.data.load import episode_names, load_episodes

    if not Path(args.data).exists():
        raise UsageError(f"--data {args.data}: no such file or folder")
    options = parse_options(args.reader_option, "--reader-option")
    try:
        names = episode_names(args.format, args.data, **options)
        for flag, wanted in (("--include", args.include), ("--exclude", args.exclude)):
            unknown = sorted(set(wanted or ()) - set(names))
            if unknown:
                raise UsageError(f"{flag}: no episode named {unknown} in {args.data}; have {names}")
        chosen = [n for n in names if (not args.include or n in set(args.include))
                  and n not in set(args.exclude or ()) and (only is None or n in only)]
        if not chosen and only is not None:
            return []  # the caller says which of its episodes are missing
        if not chosen:
            raise UsageError(f"--data {args.data}: no episodes left after --include/--exclude")
        episodes = load_episodes(args.format, args.data, names=set(chosen), **options)
    except TypeError as exc:
        raise UsageError(f"--reader-option for --format {args.format}: {exc}".replace("load_episodes() ", "")
                       .replace("episode_names() ", "")) from exc
    except ValueError as exc:
        if "reader option" in str(exc):
            raise UsageError(f"--reader-option: {exc}") from exc
        raise
    if args.format == "lerobot" and episodes:
        from rdd.data.lerobot.reader import describe_layout

        # a detail of the reading, once per command: shown with -v, not on every plain run
        log.info("lerobot: %s", describe_layout(episodes[0]))
    return episodes


def unique_views(args_views: Sequence[str] | None) -> tuple[str, ...] | None:
    """``--views`` as a tuple (None when not given), refusing a view named twice (it would be embedded twice)."""
    if not args_views:
        return None
    twice = sorted({v for v in args_views if list(args_views).count(v) > 1})
    if twice:
        raise UsageError(f"--views {' '.join(args_views)}: view(s) {twice} named more than once; name each view once")
    return tuple(args_views)


def resolve_views(args_views: Sequence[str] | None, episode: Episode) -> tuple[str, ...]:
    """``--views``, else front+wrist when the episode has them, else all its views."""
    if args_views:
        views = unique_views(args_views)
    elif all(v in episode.views for v in DEFAULT_VIEWS):
        views = DEFAULT_VIEWS
    else:
        views = tuple(sorted(episode.views))
    missing = [v for v in views if not has_view(episode, v)]
    if missing:
        state = f" (view {STATE_VIEW!r}: it has no joint state)" if STATE_VIEW in missing else ""
        raise UsageError(f"--views: episode {episode.name!r} has no view {missing}{state}; "
                       f"has {sorted(episode.views)}")
    if not views:
        raise UsageError(f"episode {episode.name!r} has no camera views to embed")
    return views


def make_encoder(name: str, options: dict[str, Any]):
    """``rdd.encoders.load_encoder`` with errors turned into CLI errors."""
    try:
        from rdd.encoders import load_encoder
    except ImportError as exc:  # pragma: no cover - encoders are part of the package
        raise UsageError(f"--encoder {name}: encoders unavailable ({exc})") from exc
    try:
        return load_encoder(name, **options)
    except (ValueError, TypeError, FileNotFoundError, ImportError) as exc:
        raise UsageError(f"--encoder {name}: {exc}") from exc


def make_cache(args: argparse.Namespace):
    """The embedding cache (``--cache-dir``, default location) or None with ``--no-cache``."""
    if args.no_cache:
        return None
    from rdd.encoders.cache import EmbeddingCache

    return EmbeddingCache(args.cache_dir)
