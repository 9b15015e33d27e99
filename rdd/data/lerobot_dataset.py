"""A local LeRobot dataset folder (format v2.1 or v3.0): its metadata and where each episode's files are.

v2.1: ``meta/info.json``, ``meta/episodes.jsonl``, ``meta/tasks.jsonl``, one parquet and one mp4
per episode at the ``data_path`` / ``video_path`` templates.
v3.0: ``meta/episodes/chunk-*/file-*.parquet`` rows locate each episode inside multi-episode
parquet and mp4 files (``data/chunk_index``, ``videos/<key>/from_timestamp`` ...).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np


def _need(module: str, extra: str = "data"):
    try:
        return __import__(module)
    except ImportError as exc:
        raise ImportError(
            f"reading LeRobot datasets needs {module}: pip install 'rdd-harness[{extra}]'"
        ) from exc


def _column(table, name: str, source: Path) -> np.ndarray:
    """A parquet column as a numpy array ((N,) or (N, D) for list columns)."""
    pa = _need("pyarrow")
    if name not in table.column_names:
        raise KeyError(f"{source}: no column {name!r}; columns: {table.column_names}")
    col = table.column(name).combine_chunks()
    if pa.types.is_fixed_size_list(col.type) or pa.types.is_list(col.type):
        flat = col.flatten().to_numpy(zero_copy_only=False)
        return flat.reshape(len(col), -1)
    return col.to_numpy(zero_copy_only=False)


class LeRobotDataset:
    """A local LeRobot dataset folder (v2.1 or v3.0)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        info_path = self.root / "meta" / "info.json"
        if not info_path.is_file():
            raise FileNotFoundError(f"{self.root} is not a LeRobot dataset: meta/info.json is missing")
        try:
            self.info: dict[str, Any] = json.loads(info_path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{info_path}: invalid JSON ({exc})") from exc
        self.version = str(self.info.get("codebase_version", ""))
        if self.version not in ("v2.1", "v3.0"):
            raise ValueError(
                f"{info_path}: codebase_version {self.version!r} is not supported (v2.1 or v3.0)"
            )
        for key in ("fps", "features", "data_path"):
            if key not in self.info:
                raise ValueError(f"{info_path}: field {key!r} is missing")
        self.fps = float(self.info["fps"])
        self.features: dict[str, Any] = self.info["features"]
        self.video_keys = [k for k, f in self.features.items() if f.get("dtype") == "video"]
        self.episodes = self._read_episode_meta()
        self.tasks = self._read_tasks()

    # -- metadata ---------------------------------------------------------------------------
    def _read_episode_meta(self) -> dict[int, dict[str, Any]]:
        if self.version == "v2.1":
            path = self.root / "meta" / "episodes.jsonl"
            if not path.is_file():
                raise FileNotFoundError(f"{path} is missing")
            out = {}
            for n, line in enumerate(path.read_text().splitlines(), 1):
                if line.strip():
                    try:
                        row = json.loads(line)
                        out[int(row["episode_index"])] = row
                    except (json.JSONDecodeError, KeyError, TypeError) as exc:
                        raise ValueError(f"{path}:{n}: bad episode record ({exc})") from exc
            return out
        _need("pyarrow")
        import pyarrow.parquet as pq

        files = sorted((self.root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
        if not files:
            raise FileNotFoundError(f"{self.root / 'meta' / 'episodes'}: no chunk-*/file-*.parquet")
        out = {}
        for f in files:
            for row in pq.read_table(f).to_pylist():
                if "episode_index" not in row:
                    raise ValueError(f"{f}: rows lack 'episode_index'")
                out[int(row["episode_index"])] = row
        return out

    def _read_tasks(self) -> dict[int, str]:
        if self.version == "v2.1":
            path = self.root / "meta" / "tasks.jsonl"
            if not path.is_file():
                return {}
            rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
            return {int(r["task_index"]): str(r["task"]) for r in rows}
        import pyarrow.parquet as pq

        path = self.root / "meta" / "tasks.parquet"
        if not path.is_file():
            return {}
        table = pq.read_table(path)
        names = table.column_names
        task_col = "task" if "task" in names else next((c for c in names if c.startswith("__index")), None)
        if task_col is None or "task_index" not in names:
            raise ValueError(f"{path}: expected columns 'task' (or the pandas index) and 'task_index'")
        return {
            int(i): str(t)
            for i, t in zip(table.column("task_index").to_pylist(), table.column(task_col).to_pylist(), strict=True)
        }

    # -- file locations ----------------------------------------------------------------------
    def _chunk(self, ep: int) -> int:
        return ep // int(self.info.get("chunks_size", 1000))

    def data_file(self, ep: int) -> Path:
        """The parquet file holding episode ``ep``'s rows."""
        meta = self.episodes[ep]
        if self.version == "v2.1":
            rel = self.info["data_path"].format(episode_chunk=self._chunk(ep), episode_index=ep)
        else:
            rel = self.info["data_path"].format(
                chunk_index=int(meta["data/chunk_index"]), file_index=int(meta["data/file_index"])
            )
        return self.root / rel

    def video_file(self, ep: int, key: str) -> tuple[Path, float]:
        """The mp4 holding ``key`` for episode ``ep`` and the episode's start time in it."""
        meta = self.episodes[ep]
        template = self.info.get("video_path")
        if not template:
            raise ValueError(f"{self.root / 'meta/info.json'}: field 'video_path' is missing")
        if self.version == "v2.1":
            rel = template.format(episode_chunk=self._chunk(ep), video_key=key, episode_index=ep)
            return self.root / rel, 0.0
        rel = template.format(
            video_key=key,
            chunk_index=int(meta[f"videos/{key}/chunk_index"]),
            file_index=int(meta[f"videos/{key}/file_index"]),
        )
        return self.root / rel, float(meta.get(f"videos/{key}/from_timestamp", 0.0))

    def present_episodes(self) -> list[int]:
        """Episodes listed in the metadata whose parquet file exists."""
        return [ep for ep in sorted(self.episodes) if self.data_file(ep).is_file()]
