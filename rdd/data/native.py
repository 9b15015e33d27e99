"""The harness's own episode format: one directory per episode, written atomically.

Layout of ``<episode_dir>/``:
- ``episode.json``: format name + version, name, task, goal, num_frames, views, segments (or null),
  instructions (or null), meta (JSON).
- ``lowdim.npz``: gripper_open, joint_positions, joint_velocities, ee_poses (those present).
- ``privileged.npz``: extra per-frame arrays from the writer (object poses ...), optional.
- ``frames_<view>.npz``: compressed uint8 (T, H, W, 3) under key ``frames``, read lazily.
"""

from __future__ import annotations

import hashlib
import json
import re
import zipfile
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.atomic import atomic_dir
from rdd.data._walk import find_named
from rdd.data.episode import Episode
from rdd.data.frames import update_with_file
from rdd.errors import InputError
from rdd.registry import register

FORMAT_NAME = "rdd-native-episode"
FORMAT_VERSION = 1
EPISODE_FILE = "episode.json"
LOWDIM_FILE = "lowdim.npz"
PRIVILEGED_FILE = "privileged.npz"
LOWDIM_FIELDS = ("gripper_open", "joint_positions", "joint_velocities", "ee_poses")
_VIEW_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


def frames_file(view: str) -> str:
    """File name holding ``view``'s frames."""
    return f"frames_{view}.npz"


class NpzFrames:
    """Frames of one view stored as a compressed ``.npz`` (key ``frames``), decoded on first use."""

    def __init__(self, path: str | Path, num_frames: int):
        self.path = Path(path)
        self._len = int(num_frames)
        self._array: np.ndarray | None = None
        self._fingerprint: str | None = None

    def __len__(self) -> int:
        return self._len

    def _load_all(self) -> np.ndarray:
        if self._array is None:
            try:
                with np.load(self.path, allow_pickle=False) as data:
                    arr = data["frames"] if "frames" in data else None
            except (OSError, ValueError, zipfile.BadZipFile) as exc:  # ValueError: object arrays, bad headers
                raise InputError(f"cannot read frames file {self.path}: {exc}") from exc
            if arr is None:
                raise InputError(f"{self.path}: no array named 'frames'")
            if arr.ndim != 4 or arr.shape[-1] != 3 or arr.dtype != np.uint8:
                raise InputError(
                    f"{self.path}: 'frames' must be uint8 (T, H, W, 3), got {arr.dtype} {arr.shape}"
                )
            if arr.shape[0] != self._len:
                raise InputError(
                    f"{self.path}: holds {arr.shape[0]} frames but episode.json says {self._len}"
                )
            self._array = arr
        return self._array

    def release(self) -> None:
        """Forget the decoded frames (read again on the next load)."""
        self._array = None

    def load(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """Frames at ``indices`` (all when None)."""
        arr = self._load_all()
        if indices is None:
            return arr
        return arr[np.asarray(indices, dtype=np.int64)]

    def fingerprint(self) -> str:
        """SHA-256 of the file's bytes."""
        if self._fingerprint is None:
            self._fingerprint = update_with_file(hashlib.sha256(), self.path).hexdigest()
        return self._fingerprint


class LazyNpz(Mapping):
    """A read-only mapping over the arrays of an ``.npz`` file, read when first accessed."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._data: dict[str, np.ndarray] | None = None

    def _load(self) -> dict[str, np.ndarray]:
        if self._data is None:
            try:
                with np.load(self.path, allow_pickle=False) as data:
                    self._data = {k: data[k] for k in data.files}
            except (OSError, ValueError, zipfile.BadZipFile) as exc:
                raise InputError(f"cannot read {self.path}: {exc}") from exc
        return self._data

    def release(self) -> None:
        """Forget the arrays read (read again when next accessed)."""
        self._data = None

    def __getitem__(self, key: str) -> np.ndarray:
        data = self._load()
        if key not in data:
            raise KeyError(f"{self.path} has no array {key!r}; available: {sorted(data)}")
        return data[key]

    def __iter__(self):
        return iter(self._load())

    def __len__(self) -> int:
        return len(self._load())

    def __repr__(self) -> str:
        return f"LazyNpz({str(self.path)!r})"


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray]) -> None:
    """Write a compressed ``.npz`` whose bytes depend only on the arrays (fixed zip timestamps).

    ``np.savez_compressed`` stamps the current time into the zip, which would change the
    byte-hash fingerprint of identical frames and invalidate embedding caches for nothing.
    """
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(value), allow_pickle=False)


def _numpy_to_json(value: Any) -> Any:
    """JSON stand-ins for numpy scalars and arrays (anything else stays an error)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple | set | frozenset):
        return list(value)
    raise TypeError(f"object of type {type(value).__name__} is not JSON serializable")


def _jsonable_meta(meta: Mapping[str, Any], name: str) -> dict[str, Any]:
    """``meta`` without the loader-owned ``privileged`` entry, as plain JSON values."""
    out = {k: v for k, v in meta.items() if k != "privileged"}
    try:
        return json.loads(json.dumps(out, default=_numpy_to_json))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"episode {name!r}: meta is not JSON-serialisable ({exc})") from exc


def save_episode(
    episode: Episode,
    directory: str | Path,
    privileged: Mapping[str, np.ndarray] | None = None,
) -> Path:
    """Write ``episode`` to ``directory`` (replaced atomically) and return its path."""
    directory = Path(directory)
    n = episode.num_frames
    for view in episode.views:
        if not _VIEW_NAME.match(view):
            raise ValueError(f"episode {episode.name!r}: view name {view!r} is not a safe file name")
    if episode.segments is not None and episode.instructions is not None:
        if len(episode.instructions) != len(episode.segments):
            raise ValueError(
                f"episode {episode.name!r}: {len(episode.instructions)} instructions "
                f"for {len(episode.segments)} segments"
            )
    priv: dict[str, np.ndarray] = {}
    for key, value in (privileged or {}).items():
        arr = np.asarray(value)
        if arr.dtype == object:
            raise ValueError(f"episode {episode.name!r}: privileged array {key!r} has dtype object")
        if arr.ndim == 0 or arr.shape[0] != n:
            raise ValueError(
                f"episode {episode.name!r}: privileged array {key!r} has shape {arr.shape}, "
                f"expected {n} rows (one per frame)"
            )
        priv[str(key)] = arr
    header = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "name": episode.name,
        "task": episode.task,
        "goal": episode.goal,
        "num_frames": n,
        "views": list(episode.views),
        "segments": None if episode.segments is None else [[int(s), int(e)] for s, e in episode.segments],
        "instructions": None if episode.instructions is None else [str(i) for i in episode.instructions],
        "meta": _jsonable_meta(episode.meta, episode.name),
    }
    # The whole episode folder appears (or replaces the old one) in one rename: a reader never
    # sees a half-written episode.
    with atomic_dir(directory, overwrite=True) as tmp:
        for view in episode.views:
            frames = np.ascontiguousarray(episode.frames(view))
            write_npz(tmp / frames_file(view), {"frames": frames})
        lowdim = {
            f: np.asarray(getattr(episode, f))
            for f in LOWDIM_FIELDS
            if getattr(episode, f) is not None
        }
        write_npz(tmp / LOWDIM_FILE, lowdim)
        if priv:
            write_npz(tmp / PRIVILEGED_FILE, priv)
        (tmp / EPISODE_FILE).write_text(json.dumps(header, indent=1))
    return directory


def natural_key(path: Path) -> list:
    """Sort key that orders ``ep2`` before ``ep10``."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def is_native_episode(directory: str | Path) -> bool:
    """True when ``directory`` holds an ``episode.json``."""
    return (Path(directory) / EPISODE_FILE).is_file()


def _read_header(directory: Path) -> dict[str, Any]:
    path = directory / EPISODE_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{directory} is not a native episode: {EPISODE_FILE} is missing")
    try:
        header = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: invalid JSON ({exc})") from exc
    if not isinstance(header, dict):
        raise InputError(f"{path}: expected a JSON object")
    if header.get("format") != FORMAT_NAME:
        raise InputError(f"{path}: field 'format' is {header.get('format')!r}, expected {FORMAT_NAME!r}")
    if header.get("version") != FORMAT_VERSION:
        raise InputError(
            f"{path}: field 'version' is {header.get('version')!r}; this reader knows {FORMAT_VERSION}"
        )
    for key, kind in (("name", str), ("num_frames", int), ("views", list)):
        if not isinstance(header.get(key), kind):
            raise InputError(f"{path}: field {key!r} is missing or not a {kind.__name__}")
    return header


def load_episode(directory: str | Path) -> Episode:
    """Read one native episode directory (frames and privileged arrays load lazily)."""
    directory = Path(directory)
    header = _read_header(directory)
    n = int(header["num_frames"])
    views = {}
    for view in header["views"]:
        path = directory / frames_file(str(view))
        if not path.is_file():
            raise FileNotFoundError(f"{directory}: view {view!r} listed in {EPISODE_FILE} but {path.name} is missing")
        views[str(view)] = NpzFrames(path, n)
    lowdim: dict[str, np.ndarray] = {}
    lowdim_path = directory / LOWDIM_FILE
    if lowdim_path.is_file():
        try:
            with np.load(lowdim_path, allow_pickle=False) as data:
                unknown = sorted(set(data.files) - set(LOWDIM_FIELDS))
                lowdim = {} if unknown else {k: data[k] for k in data.files}
        except (OSError, ValueError, zipfile.BadZipFile) as exc:  # ValueError: object arrays, bad headers
            raise InputError(f"cannot read {lowdim_path}: {exc}") from exc
        if unknown:
            raise InputError(f"{lowdim_path}: unknown arrays {unknown}")
    for key, arr in lowdim.items():
        if arr.shape[0:1] != (n,):
            raise InputError(f"{lowdim_path}: array {key!r} has shape {arr.shape}, expected {n} rows")
    meta = dict(header.get("meta") or {})
    if not isinstance(header.get("meta") or {}, dict):
        raise InputError(f"{directory / EPISODE_FILE}: field 'meta' must be an object")
    priv_path = directory / PRIVILEGED_FILE
    meta["privileged"] = LazyNpz(priv_path) if priv_path.is_file() else {}
    meta.setdefault("source", str(directory))
    segments = header.get("segments")
    if segments is not None:
        from rdd.segments import validate_segments

        try:
            segments = validate_segments([tuple(s) for s in segments], n)
        except (ValueError, TypeError) as exc:
            raise InputError(f"{directory / EPISODE_FILE}: field 'segments' is invalid: {exc}") from exc
    instructions = header.get("instructions")
    if instructions is not None and segments is not None and len(instructions) != len(segments):
        raise InputError(
            f"{directory / EPISODE_FILE}: {len(instructions)} instructions for {len(segments)} segments"
        )
    return Episode(
        name=header["name"],
        views=views,
        gripper_open=lowdim.get("gripper_open"),
        joint_positions=lowdim.get("joint_positions"),
        joint_velocities=lowdim.get("joint_velocities"),
        ee_poses=lowdim.get("ee_poses"),
        goal=str(header.get("goal") or ""),
        task=str(header.get("task") or ""),
        segments=segments,
        instructions=None if instructions is None else [str(i) for i in instructions],
        meta=meta,
    )


def _episode_dirs(folder: Path) -> list[Path]:
    """Every native episode folder under ``folder`` at any depth, sorted by relative path."""
    if not folder.exists():
        raise FileNotFoundError(f"native episode path {folder} does not exist")
    if is_native_episode(folder):
        return [folder]
    dirs = [
        p.parent
        for p in find_named(folder, EPISODE_FILE)
        if not any(part.startswith(".") for part in p.parent.relative_to(folder).parts)
    ]
    if not dirs:
        raise FileNotFoundError(f"{folder} holds no native episodes (no **/{EPISODE_FILE})")
    dirs.sort(key=lambda d: [natural_key(Path(part)) for part in d.relative_to(folder).parts])
    return dirs


def episode_names(folder: str | Path) -> list[str]:
    """Names of the episodes :func:`load_episodes` would read; only each ``episode.json`` is opened."""
    return [_read_header(d)["name"] for d in _episode_dirs(Path(folder))]


@register("reader", "native")
def load_episodes(folder: str | Path, names: Collection[str] | None = None) -> list[Episode]:
    """All native episodes under ``folder`` at any depth (e.g. ``<split>/<task>/<episode>/``),
    sorted by relative path, or ``folder`` itself if it is one. Hidden (temporary) folders are skipped.
    With ``names``, only those episodes are read (of the others only ``episode.json``, for the name)."""
    dirs = _episode_dirs(Path(folder))
    if names is not None:
        dirs = [d for d in dirs if _read_header(d)["name"] in names]
    return [load_episode(d) for d in dirs]
