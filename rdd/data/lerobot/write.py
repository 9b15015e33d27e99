"""Write sub-tasks back into a copy of a LeRobot dataset (v2.1 or v3.0) as LeRobot's language columns.

The copy keeps every source file byte for byte except the data parquet files, which gain two
columns, and ``meta/info.json``, which declares them (``{"dtype": "language", "shape": [1], "names": null}``, as
``lerobot.datasets.language.language_feature_info`` does):

- ``language_persistent``: on every frame of an episode the same list of rows ``{role: "assistant",
  content: <instruction>, style: "subtask", timestamp: <float32, the segment's first frame
  timestamp>, camera: null, tool_calls: null}``, one row per segment (LeRobot's persistent slice);
- ``language_events``: per-frame event rows, empty lists here.

Episodes without new sub-tasks keep the rows they had (empty lists when they had none), and rows
of other styles (plan, memory, ...) of a decomposed episode are kept. Every source column is
unchanged; each episode is one parquet row group, as LeRobot writes them. The copy appears under
its final name only when complete (:func:`rdd.atomic.atomic_dir`), never replaces an existing
folder, and is refused inside the source dataset.

The copy never shares storage with its source for a file that a user or a tool may edit in place
(``meta/`` files, json/jsonl, parquet, READMEs, anything not listed below): those are copied. Only
encoded media, which tools replace rather than edit (:data:`IMMUTABLE_SUFFIXES`: the videos and
image frames), are hard-linked when ``link`` is true and the filesystem allows it, else copied.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.atomic import (
    TargetExistsError,
    atomic_dir,
    atomic_path,
    remove_temporaries,
    write_text_atomic,
)
from rdd.data.lerobot.convert import convert_to_v30, link_or_copy
from rdd.data.lerobot.dataset import LeRobotDataset, column, need
from rdd.data.lerobot.language import LANGUAGE_EVENTS, LANGUAGE_PERSISTENT
from rdd.segments import Segment, validate_segments

log = logging.getLogger(__name__)

LANGUAGE_FEATURE = {"dtype": "language", "shape": [1], "names": None}
SUBTASK_STYLE = "subtask"
# Files the copy may share with the source (hard links): encoded media, rewritten whole or not at
# all. Everything else is copied, so editing the copy can never edit the source.


def _message_list_type(with_timestamp: bool):
    """A list of LeRobot message rows; the two language columns differ only in the timestamp field."""
    pa = need("pyarrow")
    fields = [
        pa.field("role", pa.string(), nullable=False),
        pa.field("content", pa.string()),
        pa.field("style", pa.string()),
        *([pa.field("timestamp", pa.float32(), nullable=False)] if with_timestamp else []),
        pa.field("camera", pa.string()),
        pa.field("tool_calls", pa.list_(pa.string())),
    ]
    return pa.list_(pa.struct(fields))


def persistent_type():
    """Arrow type of ``language_persistent`` (LeRobot's canonical type with JSON stored as string)."""
    return _message_list_type(with_timestamp=True)


def events_type():
    """Arrow type of ``language_events`` (rows carry no timestamp: they sit on their frame)."""
    return _message_list_type(with_timestamp=False)


def subtask_rows(segments: Sequence[Segment], instructions: Sequence[str], timestamps: np.ndarray,
                 where: str) -> list[dict[str, Any]]:
    """One persistent row per segment, stamped with the segment's first frame timestamp (float32)."""
    segs = validate_segments(segments, len(timestamps))
    if len(instructions) != len(segs):
        raise ValueError(f"{where}: {len(instructions)} instructions for {len(segs)} segments")
    rows = []
    for (start, _end), text in zip(segs, instructions, strict=True):
        if not isinstance(text, str) or not text.strip():
            raise ValueError(f"{where}: segment starting at frame {start} has no instruction")
        rows.append({"role": "assistant", "content": text, "style": SUBTASK_STYLE,
                     "timestamp": float(np.float32(timestamps[start])), "camera": None, "tool_calls": None})
    return rows


def _hf_metadata(metadata: dict[bytes, bytes] | None) -> dict[bytes, bytes] | None:
    """The schema metadata with the language columns added to the ``huggingface`` features, if any."""
    if not metadata or b"huggingface" not in metadata:
        return metadata
    try:
        hf = json.loads(metadata[b"huggingface"])
        features = hf["info"]["features"]
    except (ValueError, KeyError, TypeError):
        return metadata
    legacy = '"_type": "List"' not in metadata[b"huggingface"].decode("utf-8", "replace")

    def value(dtype: str) -> dict:
        return {"dtype": dtype, "_type": "Value"}

    def listed(feature: Any) -> Any:
        if legacy:  # datasets < 4 writes a list of structs as [struct], a list of values as Sequence
            return [feature] if isinstance(feature, dict) and "_type" not in feature else \
                {"feature": feature, "_type": "Sequence"}
        return {"feature": feature, "_type": "List"}

    row = {"role": value("string"), "content": value("string"), "style": value("string"),
           "timestamp": value("float32"), "camera": value("string"), "tool_calls": listed(value("string"))}
    event = {k: v for k, v in row.items() if k != "timestamp"}
    features[LANGUAGE_PERSISTENT] = listed(row)
    features[LANGUAGE_EVENTS] = listed(event)
    out = dict(metadata)
    out[b"huggingface"] = json.dumps(hf).encode()
    return out


def _rewrite_data_file(src: Path, dst: Path, new_rows: Mapping[int, list[dict[str, Any]]],
                       file_episode: int | None) -> list[int]:
    """Copy parquet ``src`` to ``dst`` with the two language columns; returns the episodes it holds."""
    pa = need("pyarrow")
    import pyarrow.parquet as pq

    table = pq.read_table(src)
    n = table.num_rows
    if "episode_index" in table.column_names:
        episodes = column(table, "episode_index", src).astype(np.int64)
    elif file_episode is not None:
        episodes = np.full(n, file_episode, dtype=np.int64)
    else:
        raise ValueError(f"{src}: no column 'episode_index' (needed to place sub-tasks in a multi-episode file)")
    if n and "timestamp" not in table.column_names:
        raise ValueError(f"{src}: no column 'timestamp' (sub-task rows are stamped with frame timestamps)")
    old_persistent = table.column(LANGUAGE_PERSISTENT).to_pylist() if LANGUAGE_PERSISTENT in table.column_names else None
    old_events = table.column(LANGUAGE_EVENTS).to_pylist() if LANGUAGE_EVENTS in table.column_names else None
    base = table.drop_columns([c for c in (LANGUAGE_PERSISTENT, LANGUAGE_EVENTS) if c in table.column_names])
    # Episodes in the order they appear; each becomes one row group.
    change = np.flatnonzero(np.diff(episodes)) + 1
    bounds = [0, *change.tolist(), n]
    order = [int(episodes[a]) for a in bounds[:-1]]
    if len(set(order)) != len(order):
        raise ValueError(f"{src}: the rows of an episode are not contiguous")
    persistent: list[list[dict]] = []
    events: list[list[dict]] = []
    for a, b, ep in zip(bounds[:-1], bounds[1:], order, strict=True):
        if ep in new_rows:
            kept = [r for r in (old_persistent[a] or []) if r.get("style") != SUBTASK_STYLE] if old_persistent else []
            rows = sorted([*kept, *new_rows[ep]], key=lambda r: (float(r["timestamp"]), r.get("style") or ""))
            persistent.extend([rows] * (b - a))
        else:
            persistent.extend(old_persistent[a:b] if old_persistent else [[] for _ in range(b - a)])
        events.extend(old_events[a:b] if old_events else [[] for _ in range(b - a)])
    table = base.append_column(pa.field(LANGUAGE_PERSISTENT, persistent_type()),
                               pa.array(persistent, type=persistent_type()))
    table = table.append_column(pa.field(LANGUAGE_EVENTS, events_type()), pa.array(events, type=events_type()))
    table = table.replace_schema_metadata(_hf_metadata(base.schema.metadata))
    with atomic_path(dst) as tmp, pq.ParquetWriter(tmp, table.schema) as writer:
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            writer.write_table(table.slice(a, b - a), row_group_size=max(1, b - a))
    return order


def _episodes_in(path: Path, file_episode: int | None) -> list[int]:
    """The episodes a data parquet file holds (its ``episode_index`` column, else ``file_episode``)."""
    import pyarrow.parquet as pq

    if "episode_index" not in pq.read_schema(path).names:
        return [] if file_episode is None else [file_episode]
    table = pq.read_table(path, columns=["episode_index"])
    return sorted(set(column(table, "episode_index", path).astype(np.int64).tolist()))


def _staged_episodes(dst: Path, file_episode: int | None) -> list[int] | None:
    """The episodes of a data file an earlier run wrote into the staging folder; None when there is
    none, or it cannot be read back (damaged: a warning, and it is written again)."""
    if not dst.is_file():
        return None
    try:
        return _episodes_in(dst, file_episode)
    except Exception as exc:  # noqa: BLE001 - any damage: the file is rewritten, never published
        log.warning("staged file %s of the LeRobot copy cannot be read back (%s); writing it again", dst,
                    str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        return None


@contextlib.contextmanager
def _resumable_dir(staging: Path, out: Path) -> Iterator[Path]:
    """Yield ``staging`` (kept across runs, its files each written whole); on success rename it to ``out``."""
    if out.exists():
        raise TargetExistsError(f"{out} already exists (refusing to replace it)")
    staging.mkdir(parents=True, exist_ok=True)
    remove_temporaries(staging)  # a killed run's half-written files: never published with the copy
    yield staging
    if out.exists():
        raise TargetExistsError(f"{out} already exists (refusing to replace it)")
    os.rename(staging, out)


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
        return True
    except ValueError:
        return False


V21_EPISODE_LISTS = (Path("meta/episodes.jsonl"), Path("meta/episodes_stats.jsonl"))


def _v21_totals(ds: LeRobotDataset, present: set[int]) -> dict[str, Any]:
    """The info.json counts of a v2.1 copy holding only the ``present`` episodes (none when it holds all)."""
    if ds.version != "v2.1" or len(present) == len(ds.episodes):
        return {}
    out: dict[str, Any] = {"total_episodes": len(present),
                           "total_frames": sum(int(ds.episodes[e].get("length", 0)) for e in present),
                           "total_videos": len(present) * len(ds.video_keys)}
    if present and max(present) - min(present) + 1 == len(present):  # a contiguous range: LeRobot's split form
        out["splits"] = {**dict(ds.info.get("splits") or {}), "train": f"{min(present)}:{max(present) + 1}"}
    return out


def _present_lines(path: Path, present: set[int]) -> str:
    """The JSON lines of ``path`` (episodes.jsonl, episodes_stats.jsonl) whose episode is in ``present``."""
    keep = [line for line in path.read_text().splitlines()
            if line.strip() and int(json.loads(line)["episode_index"]) in present]
    return "".join(line + "\n" for line in keep)


def write_subtasks(
    source: str | Path,
    out: str | Path,
    subtasks: Mapping[int, tuple[Sequence[Segment], Sequence[str]]],
    link: bool = True,
    staging: str | Path | None = None,
    version: str | None = None,
) -> Path:
    """Write OUT, a copy of the dataset at ``source`` whose ``language_persistent`` column carries
    ``subtasks`` (episode index -> (segments, instructions)); returns OUT. ``link``: hard-link the
    videos and image frames instead of copying them (every other file is always copied).

    ``staging``: a folder to build the copy in, kept when the writing stops, so that a rerun with the
    same source and sub-tasks (the caller keys the folder by them) writes only the files still missing
    (each data parquet file is rewritten once); renamed to OUT when complete. Without it the copy is
    built in a temporary folder and a stopped run leaves nothing.

    ``version``: the copy's layout, "v2.1" or "v3.0" (None: the source's). A v2.1 source is first
    laid out as v3.0 (:func:`rdd.data.lerobot.convert.convert_to_v30`) in a temporary folder beside
    OUT; a v3.0 source cannot be written as v2.1."""
    need("pyarrow")
    ds = LeRobotDataset(source)
    src_root, out = ds.root.resolve(), Path(out)
    target = out.resolve()
    if target == src_root or _inside(target, src_root) or _inside(src_root, target):
        raise ValueError(f"--write-lerobot {out}: refusing to write into (or over) the source dataset {ds.root}")
    if version not in (None, "v2.1", "v3.0"):
        raise ValueError(f"LeRobot version {version!r}: choose v2.1 or v3.0")
    if version is not None and version != ds.version:
        if ds.version == "v3.0":
            raise ValueError(f"{ds.root} is a v3.0 dataset; its copy cannot be written as {version}")
        if out.exists():
            raise TargetExistsError(f"{out} already exists (refusing to replace it)")
        out.parent.mkdir(parents=True, exist_ok=True)
        # In the staging folder when there is one: what a killed run leaves goes with it.
        beside = Path(staging).parent if staging is not None else out.parent
        beside.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=beside, prefix=f".{out.name}.v30-") as tmp:
            converted = convert_to_v30(ds, Path(tmp) / "dataset", link=link)
            return write_subtasks(converted, out, subtasks, link=link, staging=staging)
    unknown = sorted(set(subtasks) - set(ds.episodes))
    if unknown:
        raise ValueError(f"{ds.root}: episodes {unknown} are not listed in its metadata")
    data_files: dict[Path, int | None] = {}
    for ep in sorted(ds.episodes):
        path = ds.data_file(ep)
        if path.is_file():
            # v2.1 holds one episode per file (its index is known even without the column)
            data_files.setdefault(path.resolve(), ep if ds.version == "v2.1" else None)
    missing = [ep for ep in subtasks if not ds.data_file(ep).is_file()]
    if missing:
        raise FileNotFoundError(f"{ds.root}: data files of episodes {missing} are missing")
    rows: dict[int, list[dict[str, Any]]] = {}
    for ep, (segments, instructions) in subtasks.items():
        import pyarrow.parquet as pq

        path = ds.data_file(ep)
        table = pq.read_table(path, columns=[c for c in ("episode_index", "frame_index", "timestamp")
                                              if c in pq.read_schema(path).names])
        if "episode_index" in table.column_names:
            table = table.filter(column(table, "episode_index", path) == ep)
        if "frame_index" in table.column_names:
            table = table.take(np.argsort(column(table, "frame_index", path), kind="stable"))
        if "timestamp" not in table.column_names:
            raise ValueError(f"{path}: no column 'timestamp' (sub-task rows are stamped with frame timestamps)")
        ts = column(table, "timestamp", path).astype(np.float32)
        rows[int(ep)] = subtask_rows(segments, instructions, ts, f"{path} (episode {ep})")
    # The copy of a partial v2.1 source lists the episodes it holds (as convert_to_v30 does for v3.0).
    present = set(ds.present_episodes()) if ds.version == "v2.1" else set(ds.episodes)
    written: set[int] = set()
    building = atomic_dir(out) if staging is None else _resumable_dir(Path(staging), out)
    with building as tmp:
        for dirpath, _dirs, files in os.walk(src_root):
            for name in files:
                src = Path(dirpath) / name
                rel = src.relative_to(src_root)
                dst = tmp / rel
                if src.resolve() in data_files:
                    held = _staged_episodes(dst, data_files[src.resolve()])
                    if held is None:
                        held = _rewrite_data_file(src, dst, rows, data_files[src.resolve()])
                    written.update(held)
                elif dst.is_file():
                    continue
                elif rel == Path("meta/info.json"):
                    info = {**dict(ds.info), **_v21_totals(ds, present)}
                    info["features"] = {**ds.info["features"], LANGUAGE_PERSISTENT: dict(LANGUAGE_FEATURE),
                                        LANGUAGE_EVENTS: dict(LANGUAGE_FEATURE)}
                    write_text_atomic(dst, json.dumps(info, indent=4, ensure_ascii=False) + "\n")
                elif ds.version == "v2.1" and rel in V21_EPISODE_LISTS and len(present) < len(ds.episodes):
                    write_text_atomic(dst, _present_lines(src, present))
                else:
                    link_or_copy(src, dst, link)
        lost = sorted(set(rows) - written)
        if lost:
            raise ValueError(f"{ds.root}: the data files hold no rows of episodes {lost}")
    return out
