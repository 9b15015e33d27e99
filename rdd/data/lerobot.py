"""LeRobot datasets (format v2.1 and v3.0) from a local folder: parquet via pyarrow, video via PyAV.

v2.1: ``meta/info.json``, ``meta/episodes.jsonl``, ``meta/tasks.jsonl``, one parquet and one mp4
per episode at the ``data_path`` / ``video_path`` templates.
v3.0: ``meta/episodes/chunk-*/file-*.parquet`` rows locate each episode inside multi-episode
parquet and mp4 files (``data/chunk_index``, ``videos/<key>/from_timestamp`` ...).

Camera keys and the gripper signal are options: datasets without a gripper flag (e.g. dexterous
hands) derive it by thresholding the mean of chosen state dimensions.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.data.episode import Episode
from rdd.data.frames import update_with_file

log = logging.getLogger(__name__)
IMAGE_PREFIX = "observation.images."


def _need(module: str, extra: str = "data"):
    try:
        return __import__(module)
    except ImportError as exc:
        raise ImportError(
            f"reading LeRobot datasets needs {module}: pip install 'rdd-harness[{extra}]'"
        ) from exc


class VideoFrames:
    """Frames of one episode inside an mp4, decoded with PyAV on demand.

    Frame i is the decoded frame nearest to ``timestamps[i]`` (seconds in the file); a gap larger
    than ``tolerance_s`` is an error. ``max_side`` downsizes frames as they are decoded so long
    640x480 episodes do not fill memory.
    """

    def __init__(
        self,
        path: str | Path,
        timestamps: np.ndarray,
        tolerance_s: float,
        max_side: int | None = None,
    ):
        self.path = Path(path)
        self.timestamps = np.asarray(timestamps, dtype=np.float64)
        self.tolerance_s = float(tolerance_s)
        self.max_side = None if max_side is None else int(max_side)
        self._fingerprint: str | None = None

    def __len__(self) -> int:
        return int(self.timestamps.shape[0])

    def _to_array(self, frame) -> np.ndarray:
        if self.max_side is not None and max(frame.width, frame.height) > self.max_side:
            scale = self.max_side / max(frame.width, frame.height)
            frame = frame.reformat(
                width=max(1, round(frame.width * scale)), height=max(1, round(frame.height * scale))
            )
        return frame.to_ndarray(format="rgb24")

    def load(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """Decode the frames at ``indices`` (all when None) in one sequential pass."""
        av = _need("av")
        idx = np.arange(len(self)) if indices is None else np.asarray(indices, dtype=np.int64)
        if idx.size == 0:
            return np.zeros((0, 0, 0, 3), dtype=np.uint8)
        if idx.min() < 0 or idx.max() >= len(self):
            raise IndexError(f"{self.path}: frame index out of range [0, {len(self)})")
        wanted = np.unique(self.timestamps[idx])
        best_gap = np.full(wanted.shape, np.inf)
        best: list[np.ndarray | None] = [None] * len(wanted)
        lo, hi = wanted[0] - self.tolerance_s, wanted[-1] + self.tolerance_s
        try:
            container = av.open(str(self.path))
        except (OSError, av.error.FFmpegError) as exc:
            raise ValueError(f"cannot open video {self.path}: {exc}") from exc
        with container:
            stream = container.streams.video[0]
            if lo > 1.0:
                # Seek to a keyframe before the first wanted frame (v3.0 files hold many episodes).
                container.seek(int(max(0.0, lo - 1.0) / stream.time_base), stream=stream)
            for frame in container.decode(stream):
                t = frame.time
                if t is None or t < lo:
                    continue
                if t > hi:
                    break
                j = int(np.searchsorted(wanted, t))
                for k in (j - 1, j):
                    if 0 <= k < len(wanted) and abs(wanted[k] - t) < best_gap[k]:
                        best_gap[k] = abs(wanted[k] - t)
                        best[k] = self._to_array(frame)
        bad = np.nonzero(best_gap > self.tolerance_s)[0]
        if bad.size:
            raise ValueError(
                f"{self.path}: no video frame within {self.tolerance_s:.4f}s of timestamp "
                f"{wanted[bad[0]]:.4f}s ({bad.size} of {len(wanted)} frames missing)"
            )
        lookup = {float(t): k for k, t in enumerate(wanted)}
        return np.stack([best[lookup[float(self.timestamps[i])]] for i in idx]).astype(np.uint8)

    def fingerprint(self) -> str:
        """SHA-256 of the video bytes, the episode's timestamps and the resize option."""
        if self._fingerprint is None:
            h = update_with_file(hashlib.sha256(), self.path)
            h.update(self.timestamps.tobytes())
            h.update(str(self.max_side).encode())
            self._fingerprint = h.hexdigest()
        return self._fingerprint


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


def _gripper_signal(
    values: np.ndarray, indices: Sequence[int] | None, threshold: float, open_above: bool, where: str
) -> np.ndarray:
    """1 = open, 0 = closed, from the mean of ``values[:, indices]`` against ``threshold``."""
    v = values if values.ndim == 2 else values[:, None]
    if indices is not None:
        bad = [i for i in indices if not -v.shape[1] <= i < v.shape[1]]
        if bad:
            raise ValueError(f"gripper_indices {bad} out of range for {where} with {v.shape[1]} dims")
        v = v[:, list(indices)]
    level = v.mean(axis=1)
    return ((level > threshold) if open_above else (level < threshold)).astype(np.float64)


def load_episode(
    dataset: LeRobotDataset | str | Path,
    episode_index: int,
    camera_keys: Sequence[str] | None = None,
    state_key: str = "observation.state",
    joint_indices: Sequence[int] | None = None,
    gripper_key: str | None = None,
    gripper_indices: Sequence[int] | None = None,
    gripper_threshold: float = 0.5,
    gripper_open_above: bool = True,
    max_side: int | None = None,
) -> Episode:
    """One episode: frames per camera (view name = key without ``observation.images.``),
    joint positions from ``state_key`` (``joint_indices`` of it), joint velocities derived by
    finite differences x fps, and a gripper flag from ``gripper_key`` when given."""
    _need("pyarrow")
    import pyarrow.parquet as pq

    ds = dataset if isinstance(dataset, LeRobotDataset) else LeRobotDataset(dataset)
    ep = int(episode_index)
    if ep not in ds.episodes:
        raise KeyError(f"{ds.root}: episode {ep} is not listed in the dataset's episode metadata")
    data_path = ds.data_file(ep)
    if not data_path.is_file():
        raise FileNotFoundError(
            f"{ds.root}: episode {ep} is listed in the metadata but {data_path.relative_to(ds.root)} "
            f"is missing (present episodes: {ds.present_episodes()})"
        )
    table = pq.read_table(data_path)
    if "episode_index" in table.column_names:
        mask = _column(table, "episode_index", data_path) == ep
        if not mask.any():
            raise ValueError(f"{data_path}: holds no rows of episode {ep}")
        table = table.filter(mask)
    if "frame_index" in table.column_names:
        order = np.argsort(_column(table, "frame_index", data_path), kind="stable")
        table = table.take(order)
    n = table.num_rows
    if "timestamp" in table.column_names:
        timestamps = _column(table, "timestamp", data_path).astype(np.float64)
    else:
        timestamps = np.arange(n) / ds.fps
    keys = list(ds.video_keys if camera_keys is None else camera_keys)
    unknown = [k for k in keys if k not in ds.video_keys]
    if unknown:
        raise KeyError(f"{ds.root}: camera keys {unknown} are not video features; have {ds.video_keys}")
    views = {}
    for key in keys:
        path, offset = ds.video_file(ep, key)
        if not path.is_file():
            raise FileNotFoundError(f"{ds.root}: video for episode {ep}, camera {key!r} is missing: {path}")
        name = key[len(IMAGE_PREFIX):] if key.startswith(IMAGE_PREFIX) else key
        views[name] = VideoFrames(path, timestamps + offset, tolerance_s=0.5 / ds.fps + 1e-4,
                                  max_side=max_side)
    joint_positions = joint_velocities = None
    if state_key in table.column_names:
        state = _column(table, state_key, data_path).astype(np.float64)
        state = state if state.ndim == 2 else state[:, None]
        joint_positions = state if joint_indices is None else state[:, list(joint_indices)]
        if n > 1:
            joint_velocities = np.gradient(joint_positions, axis=0) * ds.fps
        else:
            joint_velocities = np.zeros_like(joint_positions)
    elif joint_indices is not None:
        raise KeyError(f"{data_path}: state column {state_key!r} is missing")
    gripper = None
    if gripper_key is not None:
        gripper = _gripper_signal(
            _column(table, gripper_key, data_path).astype(np.float64),
            gripper_indices, gripper_threshold, gripper_open_above, f"{data_path}:{gripper_key}",
        )
    meta = ds.episodes[ep]
    tasks = meta.get("tasks") or []
    if not tasks and "task_index" in table.column_names:
        tasks = [ds.tasks.get(int(_column(table, "task_index", data_path)[0]), "")]
    goal = str(tasks[0]) if tasks else ""
    return Episode(
        name=f"episode_{ep:06d}",
        views=views,
        gripper_open=gripper,
        joint_positions=joint_positions,
        joint_velocities=joint_velocities,
        goal=goal,
        task=goal,
        meta={
            "format": f"lerobot-{ds.version}",
            "source": str(ds.root),
            "episode_index": ep,
            "fps": ds.fps,
            "robot_type": ds.info.get("robot_type"),
            "joint_velocities_derived": joint_velocities is not None,
            "gripper": None if gripper_key is None else {
                "key": gripper_key, "indices": None if gripper_indices is None else list(gripper_indices),
                "threshold": gripper_threshold, "open_above": gripper_open_above,
            },
        },
    )


def load_episodes(
    root: str | Path,
    episodes: Sequence[int] | None = None,
    skip_missing: bool = False,
    **options: Any,
) -> list[Episode]:
    """Episodes of the dataset at ``root`` (all listed ones when ``episodes`` is None).

    A listed episode whose files are missing is an error unless ``skip_missing`` (then it is
    skipped with a warning). ``options`` go to :func:`load_episode`.
    """
    ds = LeRobotDataset(root)
    wanted = sorted(ds.episodes) if episodes is None else [int(e) for e in episodes]
    if skip_missing:
        present = set(ds.present_episodes())
        missing = [e for e in wanted if e not in present]
        if missing:
            log.warning("%s: skipping %d listed episodes whose files are missing", ds.root, len(missing))
        wanted = [e for e in wanted if e in present]
        if not wanted:
            raise FileNotFoundError(f"{ds.root}: none of the requested episodes is present")
    return [load_episode(ds, e, **options) for e in wanted]
