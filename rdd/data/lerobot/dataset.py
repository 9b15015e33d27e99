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

from rdd.data.lerobot.checks import check_info
from rdd.errors import InputError


def need(module: str, extra: str = "data"):
    try:
        return __import__(module)
    except ImportError as exc:
        raise ImportError(
            f"reading LeRobot datasets needs {module}: pip install 'rdd[{extra}]'"
        ) from exc


def column(table, name: str, source: Path) -> np.ndarray:
    """A parquet column as a numpy array ((N,) or (N, D) for list columns)."""
    pa = need("pyarrow")
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
        self.info_path = info_path
        try:
            self.info: dict[str, Any] = json.loads(info_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{info_path}: invalid JSON ({exc})") from exc
        if not isinstance(self.info, dict):
            raise InputError(f"{info_path}: expected a JSON object, got {type(self.info).__name__}")
        self.version = str(self.info.get("codebase_version", ""))
        if self.version not in ("v2.1", "v3.0"):
            raise InputError(
                f"{info_path}: codebase_version {self.version!r} is not supported (v2.1 or v3.0)"
            )
        for key in ("fps", "features", "data_path"):
            if key not in self.info:
                raise InputError(f"{info_path}: field {key!r} is missing")
        self.fps = check_info(self.info, info_path)
        self.features: dict[str, Any] = self.info["features"]
        self.video_keys = [k for k, f in self.features.items() if f.get("dtype") == "video"]
        self.episode_meta_file: dict[int, Path] = {}  # where each episode's metadata row was read
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
                    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
                        raise InputError(f"{path}:{n}: bad episode record ({exc})") from exc
                    self.episode_meta_file[int(row["episode_index"])] = path
            return out
        need("pyarrow")
        import pyarrow.parquet as pq

        files = sorted((self.root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
        if not files:
            raise FileNotFoundError(f"{self.root / 'meta' / 'episodes'}: no chunk-*/file-*.parquet")
        out = {}
        for f in files:
            for row in pq.read_table(f).to_pylist():
                if "episode_index" not in row:
                    raise InputError(f"{f}: rows lack 'episode_index'")
                out[int(row["episode_index"])] = row
                self.episode_meta_file[int(row["episode_index"])] = f
        return out

    def _read_tasks(self) -> dict[int, str]:
        if self.version == "v2.1":
            path = self.root / "meta" / "tasks.jsonl"
            if not path.is_file():
                return {}
            out = {}
            for n, line in enumerate(path.read_text().splitlines(), 1):
                if line.strip():
                    try:
                        row = json.loads(line)
                        out[int(row["task_index"])] = str(row["task"])
                    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
                        raise InputError(f"{path}:{n}: bad task record ({type(exc).__name__}: {exc})") from exc
            return out
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

    def _meta_number(self, ep: int, field: str, default: float | None = None, integer: bool = True) -> Any:
        """Numeric field ``field`` of episode ``ep``'s metadata row (InputError naming it otherwise)."""
        value = self.episodes[ep].get(field, default)
        ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
            and np.isfinite(value) and (not integer or float(value).is_integer())
        if not ok:
            raise InputError(f"{self.episode_meta_file.get(ep, self.root / 'meta')} (episode {ep}): "
                             f"field {field!r} is {value!r}; expected {'an integer' if integer else 'a number'}")
        return int(value) if integer else float(value)

    def _fill(self, field: str, **values: Any) -> Path:
        """The path template ``info[field]`` filled with ``values``, under the dataset root."""
        try:
            return self.root / self.info[field].format(**values)
        except (KeyError, IndexError, ValueError) as exc:
            raise InputError(f"{self.info_path}: field {field!r} ({self.info[field]!r}) is not a valid path "
                             f"template ({type(exc).__name__}: {exc}); it may use {sorted(values)}") from exc

    def data_file(self, ep: int) -> Path:
        """The parquet file holding episode ``ep``'s rows."""
        if self.version == "v2.1":
            return self._fill("data_path", episode_chunk=self._chunk(ep), episode_index=ep)
        return self._fill("data_path", chunk_index=self._meta_number(ep, "data/chunk_index"),
                          file_index=self._meta_number(ep, "data/file_index"))

    def video_file(self, ep: int, key: str) -> tuple[Path, float]:
        """The mp4 holding ``key`` for episode ``ep`` and the episode's start time in it."""
        if not self.info.get("video_path"):
            raise InputError(f"{self.info_path}: field 'video_path' is missing")
        if self.version == "v2.1":
            return self._fill("video_path", episode_chunk=self._chunk(ep), video_key=key, episode_index=ep), 0.0
        path = self._fill("video_path", video_key=key, chunk_index=self._meta_number(ep, f"videos/{key}/chunk_index"),
                          file_index=self._meta_number(ep, f"videos/{key}/file_index"))
        return path, self._meta_number(ep, f"videos/{key}/from_timestamp", 0.0, integer=False)

    def present_episodes(self) -> list[int]:
        """Episodes listed in the metadata whose parquet file exists."""
        return [ep for ep in sorted(self.episodes) if self.data_file(ep).is_file()]
