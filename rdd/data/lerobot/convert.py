"""A v3.0 copy of a LeRobot v2.1 dataset, laid out as LeRobot 0.6 reads it.

- ``data/chunk-XXX/file-YYY.parquet``: the episodes' rows, many episodes per file (one row group
  each), every source column unchanged; a new file starts when the source files gathered reach
  ``data_files_size_in_mb`` (LeRobot's default 100).
- ``videos/<key>/chunk-XXX/file-YYY.mp4``: one file per episode (the v2.1 mp4, hard-linked when
  allowed, else copied; never re-encoded), so each episode's ``from_timestamp`` is 0 and its
  ``to_timestamp`` its length / fps.
- ``meta/episodes/chunk-000/file-000.parquet``: one row per episode (index, tasks, length, where
  its rows and videos are, its ``episodes_stats.jsonl`` stats as ``stats/<feature>/<stat>``);
  ``meta/tasks.parquet`` (task strings as the index, LeRobot's layout); ``meta/info.json`` with
  ``codebase_version`` "v3.0" and the v3.0 path templates.

Episode indices are kept (the sub-tasks are keyed by them). Listed episodes whose data file is
missing are left out of the copy and counted in ``total_episodes`` no more. Every other file
(README, LICENSE, images) is copied as is.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import shutil
from pathlib import Path
from typing import Any

from rdd.atomic import atomic_path, write_text_atomic
from rdd.data.lerobot.dataset import LeRobotDataset, need

log = logging.getLogger(__name__)
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
V21_ONLY = ("total_chunks", "total_videos")
V21_META = ("episodes.jsonl", "tasks.jsonl", "episodes_stats.jsonl", "info.json")


def _episode_stats(ds: LeRobotDataset) -> dict[int, dict[str, Any]]:
    """``stats/<feature>/<stat>`` columns per episode from ``meta/episodes_stats.jsonl`` (if any)."""
    path = ds.root / "meta" / "episodes_stats.jsonl"
    out: dict[int, dict[str, Any]] = {}
    if not path.is_file():
        return out
    for line in path.read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            out[int(row["episode_index"])] = {f"stats/{feature}/{name}": value
                                              for feature, stats in (row.get("stats") or {}).items()
                                              for name, value in stats.items()}
    return out


# Encoded media, which tools replace rather than edit: safe to hard-link into a copy.
IMMUTABLE_SUFFIXES = frozenset({".mp4", ".mkv", ".webm", ".avi", ".mov", ".png", ".jpg", ".jpeg"})


def link_or_copy(src: Path, dst: Path, link: bool) -> None:
    """Hard-link ``src`` to ``dst`` when ``link`` and it is immutable media (else, or failing, copy)."""
    with atomic_path(dst) as tmp:  # a file of the copy is there whole or not at all (resuming trusts it)
        if link and src.suffix.lower() in IMMUTABLE_SUFFIXES:
            tmp.unlink()
            try:
                os.link(src, tmp)
                return
            except OSError as exc:
                if exc.errno not in (errno.EXDEV, errno.EPERM, errno.EMLINK, errno.ENOTSUP, errno.EACCES):
                    raise
        shutil.copyfile(src, tmp)
        shutil.copymode(src, tmp)


def convert_to_v30(source: str | Path | LeRobotDataset, out: str | Path, link: bool = True,
                   data_files_size_in_mb: float = 100.0) -> Path:
    """Write ``out`` (a new folder), the v3.0 layout of the v2.1 dataset at ``source``; returns ``out``."""
    pa = need("pyarrow")
    import pyarrow.parquet as pq

    ds = source if isinstance(source, LeRobotDataset) else LeRobotDataset(source)
    if ds.version != "v2.1":
        raise ValueError(f"{ds.root}: codebase_version {ds.version!r}; only v2.1 is converted to v3.0")
    out = Path(out)
    out.mkdir(parents=True)
    present = ds.present_episodes()
    if len(present) < len(ds.episodes):
        log.warning("%s: %d listed episodes have no data file; the v3.0 copy lists the %d present",
                    ds.root, len(ds.episodes) - len(present), len(present))
    chunks = int(ds.info.get("chunks_size", 1000))
    stats = _episode_stats(ds)
    # Episodes grouped into data files by their source files' size, in index order.
    groups: list[list[int]] = [[]]
    size = 0
    for ep in present:
        n = ds.data_file(ep).stat().st_size
        if groups[-1] and size + n > data_files_size_in_mb * 1e6:
            groups.append([])
            size = 0
        groups[-1].append(ep)
        size += n
    rows: list[dict[str, Any]] = []
    start = 0
    for file_index, group in enumerate(g for g in groups if g):
        dst = out / DATA_PATH.format(chunk_index=file_index // chunks, file_index=file_index)
        dst.parent.mkdir(parents=True, exist_ok=True)
        tables = [pq.read_table(ds.data_file(ep)) for ep in group]
        schema = tables[0].schema
        with pq.ParquetWriter(dst, schema) as writer:
            for ep, table in zip(group, tables, strict=True):
                if table.schema != schema:
                    table = table.cast(schema)
                writer.write_table(table, row_group_size=max(1, table.num_rows))
                meta = ds.episodes[ep]
                row: dict[str, Any] = {
                    "episode_index": ep, "tasks": list(meta.get("tasks") or []), "length": table.num_rows,
                    "data/chunk_index": file_index // chunks, "data/file_index": file_index,
                    "dataset_from_index": start, "dataset_to_index": start + table.num_rows,
                }
                start += table.num_rows
                rows.append(row)
    for key in ds.video_keys:
        for video_index, row in enumerate(rows):
            ep = row["episode_index"]
            src, _ = ds.video_file(ep, key)
            if not src.is_file():
                raise FileNotFoundError(f"{ds.root}: video for episode {ep}, camera {key!r} is missing: {src}")
            chunk = video_index // chunks
            link_or_copy(src, out / VIDEO_PATH.format(video_key=key, chunk_index=chunk, file_index=video_index),
                          link)
            row.update({f"videos/{key}/chunk_index": chunk, f"videos/{key}/file_index": video_index,
                        f"videos/{key}/from_timestamp": 0.0,
                        f"videos/{key}/to_timestamp": row["length"] / ds.fps})
    for row in rows:
        row.update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0,
                    **stats.get(row["episode_index"], {})})
    episodes_file = out / "meta" / "episodes" / "chunk-000" / "file-000.parquet"
    episodes_file.parent.mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(rows), episodes_file)
    _write_tasks(ds, out / "meta" / "tasks.parquet")
    info = {k: v for k, v in ds.info.items() if k not in V21_ONLY}
    info.update({"codebase_version": "v3.0", "data_path": DATA_PATH,
                 "total_episodes": len(rows), "total_frames": start, "total_tasks": len(ds.tasks),
                 "data_files_size_in_mb": info.get("data_files_size_in_mb", data_files_size_in_mb),
                 "video_files_size_in_mb": info.get("video_files_size_in_mb", 500)})
    if ds.video_keys:
        info["video_path"] = VIDEO_PATH
    write_text_atomic(out / "meta" / "info.json", json.dumps(info, indent=4, ensure_ascii=False) + "\n")
    _copy_the_rest(ds, out, {ds.data_file(ep).resolve() for ep in ds.episodes}
                   | {ds.video_file(ep, k)[0].resolve() for ep in ds.episodes for k in ds.video_keys})
    return out


def _write_tasks(ds: LeRobotDataset, path: Path) -> None:
    """``meta/tasks.parquet``: ``task_index`` with the task strings as the (pandas) index, as LeRobot writes it."""
    pa = need("pyarrow")
    import pyarrow.parquet as pq

    items = sorted(ds.tasks.items())
    table = pa.table({"task_index": pa.array([i for i, _ in items], pa.int64()),
                      "task": pa.array([t for _, t in items], pa.string())})
    pandas_meta = {"index_columns": ["task"], "column_indexes": [], "columns": [
        {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
         "metadata": None},
        {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": None},
    ], "creator": {"library": "pyarrow", "version": pa.__version__}, "pandas_version": "2.0.0"}
    pq.write_table(table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()}), path)


def _copy_the_rest(ds: LeRobotDataset, out: Path, done: set[Path]) -> None:
    """Every other file of the source (README, LICENSE, images ...) at the same place in ``out``."""
    meta = ds.root / "meta"
    for dirpath, _dirs, files in os.walk(ds.root):
        for name in files:
            src = Path(dirpath) / name
            if src.resolve() in done or (src.parent == meta and name in V21_META):
                continue
            dst = out / src.relative_to(ds.root)
            if not dst.exists():
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src, dst)
