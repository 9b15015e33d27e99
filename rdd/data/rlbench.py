"""RLBench episode folders (``<view>_rgb/N.png``, ``low_dim_obs.pkl``, ``variation_*.pkl``).

RLBench pickles its ``Demo`` of ``Observation`` objects. Unpickling can run arbitrary code, so a
restricted unpickler maps ``rlbench.*`` / ``pyrep.*`` classes to inert records, lets through only
the handful of numpy functions that rebuild arrays, and refuses every other global.
"""

from __future__ import annotations

import io
import pickle
import re
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.data._walk import find_named
from rdd.data.episode import Episode
from rdd.data.frames import ImageFileFrames
from rdd.errors import InputError
from rdd.registry import register

LOW_DIM_FILE = "low_dim_obs.pkl"
DESCRIPTIONS_FILE = "variation_descriptions.pkl"
VARIATION_FILE = "variation_number.pkl"
RECORD_MODULES = ("rlbench", "pyrep")


class PickleRecord:
    """An inert stand-in for a pickled rlbench/pyrep object: holds its state, runs nothing."""

    _type: str = "record"

    def __setstate__(self, state: Any) -> None:
        # Objects pickled with __slots__ arrive as (dict, slots); keep both as attributes.
        if isinstance(state, tuple) and len(state) == 2:
            merged = dict(state[0] or {})
            merged.update(state[1] or {})
            state = merged
        if isinstance(state, dict):
            self.__dict__.update({str(k): v for k, v in state.items()})
        else:
            self.__dict__["_state"] = state

    def __repr__(self) -> str:
        return f"<{self._type} record: {sorted(self.__dict__)}>"


_RECORD_CLASSES: dict[str, type] = {}


def _record_class(module: str, name: str) -> type:
    """One PickleRecord subclass per pickled class name (so records say what they were)."""
    key = f"{module}.{name}"
    if key not in _RECORD_CLASSES:
        _RECORD_CLASSES[key] = type(name, (PickleRecord,), {"_type": key})
    return _RECORD_CLASSES[key]


def _numpy_allowed() -> dict[tuple[str, str], Any]:
    """The exact numpy globals a pickled ndarray / numpy scalar needs, under old and new paths."""
    from numpy._core import multiarray

    allowed = {}
    for mod in ("numpy.core.multiarray", "numpy._core.multiarray"):
        allowed[(mod, "_reconstruct")] = multiarray._reconstruct
        allowed[(mod, "scalar")] = multiarray.scalar
    allowed[("numpy", "ndarray")] = np.ndarray
    allowed[("numpy", "dtype")] = np.dtype
    for name in ("Float64DType", "Float32DType", "Int64DType", "Int32DType", "BoolDType", "UInt8DType"):
        if hasattr(np.dtypes, name):
            allowed[("numpy.dtypes", name)] = getattr(np.dtypes, name)
    return allowed


class RestrictedUnpickler(pickle.Unpickler):
    """Unpickler that maps rlbench/pyrep classes to records and refuses any other global."""

    def __init__(self, file, source: str = "<pickle>"):
        super().__init__(file)
        self.source = source
        self._numpy = _numpy_allowed()

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in self._numpy:
            return self._numpy[(module, name)]
        if module.split(".")[0] in RECORD_MODULES:
            return _record_class(module, name)
        raise pickle.UnpicklingError(
            f"{self.source}: refusing to load global {module}.{name} "
            f"(only {', '.join(m + '.*' for m in RECORD_MODULES)} and numpy arrays are allowed)"
        )


def restricted_load(path: str | Path) -> Any:
    """Unpickle ``path`` with :class:`RestrictedUnpickler`."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FileNotFoundError(f"cannot read {path}: {exc}") from exc
    try:
        return RestrictedUnpickler(io.BytesIO(data), source=str(path)).load()
    except pickle.UnpicklingError as exc:
        if str(exc).startswith(str(path)):  # a refused global: already names the file
            raise
        raise pickle.UnpicklingError(f"{path}: not a readable RLBench pickle ({exc})") from exc
    except Exception as exc:  # corrupt or truncated pickles raise many types; report the file either way
        raise InputError(f"{path}: not a readable RLBench pickle ({type(exc).__name__}: {exc})") from exc


def _kind(value: Any) -> str:
    return value._type if isinstance(value, PickleRecord) else type(value).__name__


def _what(value: Any) -> str:
    """A short description of an unpickled value for an error message (never its whole repr)."""
    if isinstance(value, list | tuple):
        kinds = sorted({_kind(v) for v in value[:50]})
        return f"a {type(value).__name__} of {len(value)} items ({', '.join(kinds) or 'empty'})"
    return f"a {_kind(value)}"


def _observations(demo: Any, path: Path) -> list[Any]:
    """The list of Observation records inside an unpickled Demo (or a bare list of them)."""
    obs = demo if isinstance(demo, list) else getattr(demo, "_observations", None)
    if not isinstance(obs, list) or not all(isinstance(o, PickleRecord) for o in obs):
        got = _what(demo) if obs is demo or not isinstance(demo, PickleRecord) else \
            f"{_what(demo)} whose '_observations' is {_what(obs)}"
        raise InputError(f"{path}: expected an rlbench Demo (a list of rlbench Observation records), got {got}")
    return obs


def _stack(observations: list[Any], attr: str, path: Path, required: bool) -> np.ndarray | None:
    values = [getattr(o, attr, None) for o in observations]
    if all(v is None for v in values):
        if required:
            raise InputError(f"{path}: observations have no {attr!r}")
        return None
    if any(v is None for v in values):
        missing = next(i for i, v in enumerate(values) if v is None)
        raise InputError(f"{path}: observation {missing} lacks {attr!r}")
    try:
        return np.asarray([np.asarray(v, dtype=np.float64) for v in values])
    except (ValueError, TypeError) as exc:  # strings, or arrays of different lengths
        raise InputError(f"{path}: observation attribute {attr!r} is not one numeric array per frame "
                         f"({type(exc).__name__}: {exc})") from exc


def _frame_number(p: Path) -> int:
    return int(p.stem)


def available_views(directory: str | Path) -> list[str]:
    """Camera views present as ``<view>_rgb`` folders."""
    return sorted(p.name[: -len("_rgb")] for p in Path(directory).glob("*_rgb") if p.is_dir())


def image_paths(directory: str | Path, views: Sequence[str] = ("front", "wrist"),
                num_frames: int | None = None) -> list[list[str]]:
    """Each frame's image files, one per view (``<directory>/<view>_rgb/<i>.png``), frame by frame;
    ``num_frames`` defaults to the PNGs in the first view's folder. Nothing is opened."""
    directory = Path(directory)
    if num_frames is None:
        num_frames = len(list((directory / f"{views[0]}_rgb").glob("*.png")))
    return [[str(directory / f"{v}_rgb" / f"{i}.png") for v in views] for i in range(num_frames)]


def _view_frames(directory: Path, view: str, num_frames: int) -> ImageFileFrames:
    folder = directory / f"{view}_rgb"
    if not folder.is_dir():
        raise FileNotFoundError(
            f"{directory}: view {view!r} has no folder {folder.name}; "
            f"available views: {available_views(directory)}"
        )
    files = [p for p in folder.iterdir() if p.suffix.lower() == ".png" and p.stem.isdigit()]
    files.sort(key=_frame_number)
    numbers = [_frame_number(p) for p in files]
    if numbers != list(range(num_frames)):
        raise InputError(
            f"{folder}: expected images 0.png..{num_frames - 1}.png to match {LOW_DIM_FILE}, "
            f"found {len(files)} images"
        )
    return ImageFileFrames(files)


def _task_name(directory: Path) -> str:
    """``open_drawer`` from ``.../open_drawer/all_variations/episodes/episode0``."""
    parts = directory.resolve().parts
    if len(parts) >= 4 and parts[-2] == "episodes":
        return parts[-4]
    return ""


def load_episode(
    directory: str | Path, views: Sequence[str] | None = ("front", "wrist"), name: str | None = None
) -> Episode:
    """Read one RLBench episode folder; ``views=None`` takes every ``<view>_rgb`` folder."""
    directory = Path(directory)
    low_dim = directory / LOW_DIM_FILE
    if not low_dim.is_file():
        raise FileNotFoundError(f"{directory} is not an RLBench episode: {LOW_DIM_FILE} is missing")
    observations = _observations(restricted_load(low_dim), low_dim)
    if not observations:
        raise InputError(f"{low_dim}: the demo has no observations")
    n = len(observations)
    view_names = available_views(directory) if views is None else list(views)
    frames = {v: _view_frames(directory, v, n) for v in view_names}
    goal, descriptions, variation = "", [], None
    if (directory / DESCRIPTIONS_FILE).is_file():
        descriptions = restricted_load(directory / DESCRIPTIONS_FILE)
        if not isinstance(descriptions, list) or not all(isinstance(d, str) for d in descriptions):
            raise InputError(f"{directory / DESCRIPTIONS_FILE}: expected a list of strings, got {_what(descriptions)}")
        goal = descriptions[0] if descriptions else ""
    if (directory / VARIATION_FILE).is_file():
        variation = restricted_load(directory / VARIATION_FILE)
        if not isinstance(variation, int):
            raise InputError(f"{directory / VARIATION_FILE}: expected an int, got {_what(variation)}")
    gripper = _stack(observations, "gripper_open", low_dim, required=True)
    return Episode(
        name=name or directory.name,
        views=frames,
        gripper_open=gripper.reshape(-1),
        joint_positions=_stack(observations, "joint_positions", low_dim, required=False),
        joint_velocities=_stack(observations, "joint_velocities", low_dim, required=False),
        ee_poses=_stack(observations, "gripper_pose", low_dim, required=False),
        goal=goal,
        task=_task_name(directory),
        meta={
            "format": "rlbench",
            "source": str(directory),
            "variation_descriptions": descriptions,
            "variation_number": variation,
        },
    )


def _natural_key(p: Path) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", str(p))]


def _episode_dirs(path: Path) -> list[tuple[str | None, Path]]:
    """``(name, folder)`` of every episode under ``path``; name None means the folder's own name."""
    if not path.exists():
        raise FileNotFoundError(f"RLBench path {path} does not exist")
    if (path / LOW_DIM_FILE).is_file():
        return [(None, path)]
    dirs = sorted({p.parent for p in find_named(path, LOW_DIM_FILE)}, key=_natural_key)
    if not dirs:
        raise FileNotFoundError(f"{path} holds no RLBench episodes (no */{LOW_DIM_FILE})")
    names = [d.name for d in dirs]
    unique = len(set(names)) == len(names)
    # Prefix the task (and variation folder) only when bare episode names would collide.
    return [(None if unique else "/".join(d.relative_to(path).parts), d) for d in dirs]


def episode_names(path: str | Path, views: Sequence[str] | None = ("front", "wrist")) -> list[str]:
    """Names of the episodes :func:`load_episodes` would read, from the folder names alone (nothing opened)."""
    return [name or d.name for name, d in _episode_dirs(Path(path))]


@register("reader", "rlbench")
def load_episodes(path: str | Path, views: Sequence[str] | None = ("front", "wrist"),
                  names: Collection[str] | None = None) -> list[Episode]:
    """Every RLBench episode under ``path`` (an episode folder, or any folder above episodes); only
    those named in ``names`` when given, and no other episode's files are opened."""
    return [load_episode(d, views, name=name) for name, d in _episode_dirs(Path(path))
            if names is None or (name or d.name) in names]
