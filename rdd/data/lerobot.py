"""LeRobot datasets (format v2.1 and v3.0) from a local folder: parquet via pyarrow, video via PyAV.

v2.1: ``meta/info.json``, ``meta/episodes.jsonl``, ``meta/tasks.jsonl``, one parquet and one mp4
per episode at the ``data_path`` / ``video_path`` templates.
v3.0: ``meta/episodes/chunk-*/file-*.parquet`` rows locate each episode inside multi-episode
parquet and mp4 files (``data/chunk_index``, ``videos/<key>/from_timestamp`` ...).

Camera keys and the gripper signal are options (:data:`READER_OPTIONS`). When ``info.json`` names
the state dims, the arm joints and the gripper/hand dims (names with gripper, hand or finger; one
group per side) are inferred from the names; datasets without a gripper flag (e.g. dexterous
hands) derive one per hand by thresholding the mean of its dims. Sub-tasks written by LeRobot's
annotation tools (or ``rdd.data.lerobot_write``) are read from the ``language_persistent`` column.
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


LANGUAGE_PERSISTENT = "language_persistent"
LANGUAGE_EVENTS = "language_events"
GRIPPER_WORDS = ("gripper", "hand", "finger")
SIDES = ("left", "right")

# Every reader option with its meaning; ``python -m rdd ... --help`` prints this table and
# :func:`check_reader_options` validates against it, so the two cannot drift apart.
READER_OPTIONS: dict[str, str] = {
    "episodes": "episode indices to read, e.g. [1,2] (default: every listed episode)",
    "skip_missing": "true: skip listed episodes whose files are missing (default false: error)",
    "camera_keys": "video features to read, e.g. [\"observation.images.cam_high\"] (default: all)",
    "max_side": "downsize decoded frames so their longer side is at most this many pixels",
    "state_key": "column with the joint state (default observation.state)",
    "joint_indices": "arm joint dims of state_key for the velocities (default: inferred from the "
                     "feature names in info.json: every dim not named gripper/hand/finger)",
    "gripper_key": "column with the gripper/hand state (default: state_key when its names show "
                   "gripper/hand/finger dims)",
    "gripper_indices": "dims of gripper_key: [i,...] for one gripper, [[left...],[right...]] per hand "
                       "(default: inferred from the names, one group per side)",
    "gripper_threshold": "a hand is open when the mean of its dims is above this (default 0.5)",
    "gripper_hysteresis": "the mean must pass threshold +- this to switch state (default 0.05)",
    "gripper_open_above": "false when lower values mean open (default true)",
}


def _is_index_list(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(i, int) and not isinstance(i, bool) for i in value)


def check_reader_options(options: dict[str, Any]) -> None:
    """Raise ValueError naming the option when a key is unknown or a value has the wrong type."""
    unknown = sorted(set(options) - set(READER_OPTIONS))
    if unknown:
        raise ValueError(f"unknown LeRobot reader option(s) {unknown}; accepted: {', '.join(READER_OPTIONS)}")

    def bad(key: str, what: str) -> ValueError:
        return ValueError(f"reader option {key}={options[key]!r}: expected {what}")

    for key, value in options.items():
        if key in ("episodes", "joint_indices") and value is not None and not _is_index_list(value):
            raise bad(key, "a list of integers")
        if key == "gripper_indices" and value is not None and not (
            _is_index_list(value) and value
            or isinstance(value, list) and value and all(_is_index_list(g) and g for g in value)
        ):
            raise bad(key, "a non-empty list of integers or a list of non-empty integer lists")
        if key in ("state_key", "gripper_key") and value is not None and not isinstance(value, str):
            raise bad(key, "a column name")
        if key == "camera_keys" and value is not None and not (
            isinstance(value, list) and all(isinstance(k, str) for k in value)
        ):
            raise bad(key, "a list of video feature names")
        if key in ("skip_missing", "gripper_open_above") and not isinstance(value, bool):
            raise bad(key, "true or false")
        if key in ("gripper_threshold", "gripper_hysteresis") and (
            not isinstance(value, (int, float)) or isinstance(value, bool) or not np.isfinite(value)
        ):
            raise bad(key, "a number")
        if key == "gripper_hysteresis" and value < 0:
            raise bad(key, "a number >= 0")
        if key == "max_side" and value is not None and (
            not isinstance(value, int) or isinstance(value, bool) or value < 1
        ):
            raise bad(key, "an integer >= 1")


def feature_names(info: dict[str, Any], key: str) -> list[str] | None:
    """The per-dimension names info.json gives feature ``key`` (flattened), or None."""
    names = (info.get("features", {}).get(key) or {}).get("names")
    if isinstance(names, dict):  # {"motors": [...]} in some datasets
        names = [n for group in names.values() for n in (group if isinstance(group, list) else [group])]
    if isinstance(names, list) and len(names) == 1 and isinstance(names[0], list):
        names = names[0]
    if isinstance(names, list) and names and all(isinstance(n, str) for n in names):
        return names
    return None


def infer_layout(names: Sequence[str]) -> tuple[list[int], dict[str, list[int]]]:
    """Arm dims and gripper/hand dims per side ("left", "right" or "") from per-dim names."""
    arm: list[int] = []
    hands: dict[str, list[int]] = {}
    for i, name in enumerate(names):
        low = name.lower()
        if any(w in low for w in GRIPPER_WORDS):
            side = next((s for s in SIDES if s in low), "")
            hands.setdefault(side, []).append(i)
        else:
            arm.append(i)
    return arm, hands


def hand_flags(
    values: np.ndarray, groups: Sequence[Sequence[int]], threshold: float, hysteresis: float, open_above: bool,
    where: str,
) -> np.ndarray:
    """(T, H) open flags, one per hand: the mean of its dims against ``threshold`` with hysteresis.

    A hand switches state only when its mean passes ``threshold +- hysteresis``, so a resting hand
    whose level hovers near the threshold does not flicker between open and closed.
    """
    v = values if values.ndim == 2 else values[:, None]
    flags = np.zeros((v.shape[0], len(groups)))
    for h, group in enumerate(groups):
        bad = [i for i in group if not -v.shape[1] <= i < v.shape[1]]
        if bad:
            raise ValueError(f"reader option gripper_indices {bad} out of range for {where} with {v.shape[1]} dims")
        level = v[:, list(group)].mean(axis=1)
        if not open_above:
            level = -level
        thr = threshold if open_above else -threshold
        state = bool(level[0] > thr) if len(level) else True
        for t, x in enumerate(level):
            if state and x < thr - hysteresis:
                state = False
            elif not state and x > thr + hysteresis:
                state = True
            flags[t, h] = float(state)
    return flags


def read_subtasks(
    table, timestamps: np.ndarray, where: str
) -> tuple[list[tuple[int, int]], list[str]] | None:
    """Segments and instructions from the ``language_persistent`` subtask rows of one episode.

    Each row starts a segment at the frame whose timestamp equals the row's (float32) timestamp;
    it lasts until the next row's frame. None when the column is absent or holds no subtask rows.
    The first segment always starts at frame 0 (frames before the first row belong to it).
    """
    if LANGUAGE_PERSISTENT not in table.column_names or table.num_rows == 0:
        return None
    column = table.column(LANGUAGE_PERSISTENT)
    first = column[0].as_py() or []
    for i in (table.num_rows // 2, table.num_rows - 1):
        if (column[i].as_py() or []) != first:
            raise ValueError(f"{where}: column {LANGUAGE_PERSISTENT} differs between frames 0 and {i} "
                             "(LeRobot broadcasts the same rows to every frame of an episode)")
    rows = [r for r in first if isinstance(r, dict) and r.get("style") == "subtask"]
    if not rows:
        return None
    ts32 = timestamps.astype(np.float32)
    starts: dict[int, str] = {}
    for r in sorted(rows, key=lambda r: float(r.get("timestamp") or 0.0)):
        if r.get("timestamp") is None:
            raise ValueError(f"{where}: a {LANGUAGE_PERSISTENT} subtask row has no timestamp")
        hit = np.flatnonzero(ts32 == np.float32(r["timestamp"]))
        if hit.size == 0:
            raise ValueError(f"{where}: {LANGUAGE_PERSISTENT} subtask timestamp {r['timestamp']} "
                             "is not one of the episode's frame timestamps")
        frame = int(hit[0])
        if frame in starts:
            raise ValueError(f"{where}: two {LANGUAGE_PERSISTENT} subtask rows start at timestamp {r['timestamp']}")
        starts[frame] = "" if r.get("content") is None else str(r["content"])
    frames = sorted(starts)
    bounds = [0, *frames[1:], len(timestamps)]
    segments = [(bounds[j], bounds[j + 1]) for j in range(len(frames))]
    return segments, [starts[f] for f in frames]


def load_episode(
    dataset: LeRobotDataset | str | Path,
    episode_index: int,
    camera_keys: Sequence[str] | None = None,
    state_key: str = "observation.state",
    joint_indices: Sequence[int] | None = None,
    gripper_key: str | None = None,
    gripper_indices: Sequence[int] | Sequence[Sequence[int]] | None = None,
    gripper_threshold: float = 0.5,
    gripper_hysteresis: float = 0.05,
    gripper_open_above: bool = True,
    max_side: int | None = None,
) -> Episode:
    """One episode: frames per camera (view name = key without ``observation.images.``), arm joint
    positions and velocities (finite differences x fps), a gripper flag, and the sub-tasks of its
    ``language_persistent`` column as ``segments``/``instructions``. Options: :data:`READER_OPTIONS`."""
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
    layout: dict[str, Any] = {}
    state_names = feature_names(ds.info, state_key)
    joint_positions = joint_velocities = None
    if state_key in table.column_names:
        state = _column(table, state_key, data_path).astype(np.float64)
        state = state if state.ndim == 2 else state[:, None]
        if joint_indices is None and state_names is not None and len(state_names) == state.shape[1]:
            arm, _ = infer_layout(state_names)
            if arm and len(arm) < state.shape[1]:
                joint_indices = arm
                layout["joint_indices"] = ("inferred", arm)
        if joint_indices is not None:
            bad = [i for i in joint_indices if not -state.shape[1] <= i < state.shape[1]]
            if bad:
                raise ValueError(f"reader option joint_indices {bad} out of range for {data_path}:{state_key} "
                                 f"with {state.shape[1]} dims")
        joint_positions = state if joint_indices is None else state[:, list(joint_indices)]
        if n > 1:
            joint_velocities = np.gradient(joint_positions, axis=0) * ds.fps
        else:
            joint_velocities = np.zeros_like(joint_positions)
    elif joint_indices is not None:
        raise KeyError(f"{data_path}: state column {state_key!r} is missing")
    gripper = None
    groups: list[list[int]] | None = None
    sides: list[str] = []
    if gripper_indices is not None:
        groups = [list(g) for g in gripper_indices] if isinstance(gripper_indices[0], list) else [list(gripper_indices)]
    source_key = gripper_key
    if groups is None:
        key = gripper_key or state_key
        names = feature_names(ds.info, key)
        _, hands = infer_layout(names) if names else ([], {})
        if hands:
            source_key, sides = key, sorted(hands)
            groups = [hands[s] for s in sides]
            layout["gripper_indices"] = ("inferred", {s or "gripper": hands[s] for s in sides})
        elif gripper_key is not None:
            if key not in table.column_names:
                raise KeyError(f"{data_path}: no column {key!r} (reader option gripper_key)")
            width = _column(table, key, data_path).reshape(n, -1).shape[1]
            if width > 1:
                raise ValueError(
                    f"reader option gripper_key={key!r}: the column has {width} dims and info.json names "
                    "no gripper/hand/finger dims among them; pass gripper_indices=[...]"
                )
            groups = [[0]]
    if groups is not None and source_key is None:
        source_key = state_key
    if groups is not None:
        if source_key not in table.column_names:
            raise KeyError(f"{data_path}: no column {source_key!r} (reader option gripper_key)")
        flags = hand_flags(_column(table, source_key, data_path).astype(np.float64), groups,
                           float(gripper_threshold), float(gripper_hysteresis), bool(gripper_open_above),
                           f"{data_path}:{source_key}")
        # With several hands the flag is the fraction of hands open, so any hand's change shows.
        gripper = flags.mean(axis=1)
        if n and np.all(gripper == gripper[0]):
            log.warning(
                "%s episode %d: the gripper flag derived from %s dims %s never changes (always %s); "
                "set the reader options gripper_indices / gripper_threshold / gripper_open_above",
                ds.root, ep, source_key, groups, "open" if gripper[0] >= 0.5 else "closed",
            )
    subtasks = read_subtasks(table, timestamps, f"{data_path} (episode {ep})")
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
        segments=None if subtasks is None else subtasks[0],
        instructions=None if subtasks is None else subtasks[1],
        meta={
            "format": f"lerobot-{ds.version}",
            "source": str(ds.root),
            "episode_index": ep,
            "fps": ds.fps,
            "robot_type": ds.info.get("robot_type"),
            "joint_velocities_derived": joint_velocities is not None,
            "joint_indices": None if joint_indices is None else list(joint_indices),
            "layout_inferred": layout,
            "gripper": None if groups is None else {
                "key": source_key, "indices": groups, "sides": sides, "threshold": gripper_threshold,
                "hysteresis": gripper_hysteresis, "open_above": gripper_open_above,
            },
        },
    )


def describe_layout(episode: Episode) -> str:
    """One line saying which state dims the reader used as arm joints and as grippers/hands."""
    m = episode.meta
    g = m.get("gripper")
    joints = m.get("joint_indices")
    how = {k: v[0] for k, v in (m.get("layout_inferred") or {}).items()}
    jtxt = "all state dims" if joints is None else f"dims {joints}"
    gtxt = "none (no gripper flag)" if g is None else (
        f"{g['key']} dims " + ", ".join(f"{s or 'gripper'} {ix}" for s, ix in
                                        zip(g["sides"] or [""] * len(g["indices"]), g["indices"], strict=True)))
    return (f"arm joints: {jtxt} ({how.get('joint_indices', 'given')}); grippers/hands: {gtxt} "
            f"({how.get('gripper_indices', 'given' if g else '-')}); "
            "override with --reader-option joint_indices=[...] gripper_indices=[[...],[...]]")


def load_episodes(
    root: str | Path,
    episodes: Sequence[int] | None = None,
    skip_missing: bool = False,
    **options: Any,
) -> list[Episode]:
    """Episodes of the dataset at ``root`` (all listed ones when ``episodes`` is None).

    A listed episode whose files are missing is an error unless ``skip_missing`` (then it is
    skipped with a warning). ``options`` go to :func:`load_episode` (see :data:`READER_OPTIONS`).
    """
    check_reader_options({"episodes": episodes, "skip_missing": skip_missing, **options})
    ds = LeRobotDataset(root)
    wanted = sorted(ds.episodes) if episodes is None else [int(e) for e in episodes]
    unknown = [e for e in wanted if e not in ds.episodes]
    if unknown:
        raise ValueError(f"reader option episodes: {unknown} are not listed in {ds.root}/meta")
    if skip_missing:
        present = set(ds.present_episodes())
        missing = [e for e in wanted if e not in present]
        if missing:
            log.warning("%s: skipping %d listed episodes whose files are missing", ds.root, len(missing))
        wanted = [e for e in wanted if e in present]
        if not wanted:
            raise FileNotFoundError(f"{ds.root}: none of the requested episodes is present")
    return [load_episode(ds, e, **options) for e in wanted]
