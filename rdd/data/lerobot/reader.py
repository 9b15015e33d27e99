"""LeRobot datasets (format v2.1 and v3.0) from a local folder: parquet via pyarrow, video via PyAV.

The folder layout of each version is :mod:`rdd.data.lerobot.dataset`'s; frames are decoded on
demand (:mod:`rdd.data.lerobot.video`).

Camera keys and the gripper signal are options (:data:`READER_OPTIONS`). When ``info.json`` names
the state dims, the arm joints and the gripper/hand dims (names with gripper, hand or finger; one
group per side) are inferred from the names; datasets without a gripper flag (e.g. dexterous
hands) derive one per hand by thresholding the mean of its dims. Sub-tasks written by LeRobot's
annotation tools (or ``rdd.data.lerobot.write``) are read from the ``language_persistent`` column.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rdd.data.episode import Episode
from rdd.data.lerobot.checks import check_finite, check_length, check_timestamps
from rdd.data.lerobot.dataset import LeRobotDataset, column, need
from rdd.data.lerobot.language import read_subtasks
from rdd.data.lerobot.layout import (
    arm_sides,
    feature_names,
    finger_levels,
    hand_flags,
    hand_levels,
    infer_layout,
)
from rdd.data.lerobot.video import VideoFrames
from rdd.registry import register

log = logging.getLogger(__name__)
IMAGE_PREFIX = "observation.images."


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
    need("pyarrow")
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
        mask = column(table, "episode_index", data_path) == ep
        if not mask.any():
            raise ValueError(f"{data_path}: holds no rows of episode {ep}")
        table = table.filter(mask)
    if "frame_index" in table.column_names:
        order = np.argsort(column(table, "frame_index", data_path), kind="stable")
        table = table.take(order)
    n = table.num_rows
    where = f"{data_path} (episode {ep})"
    check_length(n, ds.episodes[ep], where, ds.episode_meta_file.get(ep, ds.root / "meta"))
    if "timestamp" in table.column_names:
        timestamps = column(table, "timestamp", data_path).astype(np.float64)
        check_timestamps(timestamps, ds.fps, where, ds.info_path)
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
    arms: dict[str, list[int]] = {}
    levels = None
    if state_key in table.column_names:
        state = column(table, state_key, data_path).astype(np.float64)
        state = state if state.ndim == 2 else state[:, None]
        check_finite(state, where, state_key)
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
        if state_names is not None and len(state_names) == state.shape[1]:
            arms = arm_sides(state_names, range(state.shape[1]) if joint_indices is None else joint_indices)
        if n > 1:
            joint_velocities = np.gradient(joint_positions, axis=0) * ds.fps
        else:
            joint_velocities = np.zeros_like(joint_positions)
    elif joint_indices is not None:
        raise KeyError(f"{data_path}: state column {state_key!r} is missing")
    gripper = openings = None
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
            width = column(table, key, data_path).reshape(n, -1).shape[1]
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
        values = column(table, source_key, data_path).astype(np.float64)
        check_finite(values, where, source_key)
        levels = hand_levels(values, groups, f"{data_path}:{source_key}")
        names = feature_names(ds.info, source_key)
        aligned = names is not None and len(names) == values.reshape(n, -1).shape[1]
        openings = finger_levels(values, groups, names if aligned else None, levels)
        flags = hand_flags(values, groups,
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
        tasks = [ds.tasks.get(int(column(table, "task_index", data_path)[0]), "")]
    goal = str(tasks[0]) if tasks else ""
    return Episode(
        name=episode_name(ep),
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
            # Per-hand levels (T, H; the order of gripper.indices) and each arm's columns of
            # joint_positions: the signals the expert rule's hand events and the signals labeler read.
            "hand_levels": levels,
            # Per-hand opening, the median of the finger dims (the state view's hand signal).
            "hand_openings": openings,
            "arm_sides": arms,
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


def _wanted(ds: LeRobotDataset, episodes: Sequence[int] | None, skip_missing: bool,
            names: Collection[str] | None = None) -> list[int]:
    """The episode indices to read: ``episodes`` (default: every listed one), those named in ``names``
    only, and with ``skip_missing`` only those whose data file exists (files are only checked, not opened)."""
    wanted = sorted(ds.episodes) if episodes is None else [int(e) for e in episodes]
    unknown = [e for e in wanted if e not in ds.episodes]
    if unknown:
        raise ValueError(f"reader option episodes: {unknown} are not listed in {ds.root}/meta")
    if names is not None:
        wanted = [e for e in wanted if episode_name(e) in names]
    if skip_missing:
        present = set(ds.present_episodes())
        missing = [e for e in wanted if e not in present]
        if missing:
            # skip_missing asked for exactly this, and the command's own summary counts the episodes it
            # read: a detail shown with -v, not a warning repeated by every command on a partial copy
            log.info("%s: skipping %d listed episodes whose files are missing", ds.root, len(missing))
        wanted = [e for e in wanted if e in present]
        if not wanted:
            raise FileNotFoundError(f"{ds.root}: none of the requested episodes is present")
    return wanted


def episode_name(ep: int) -> str:
    """The name the reader gives episode index ``ep`` (``episode_000001``)."""
    return f"episode_{ep:06d}"


def episode_names(root: str | Path, episodes: Sequence[int] | None = None, skip_missing: bool = False,
                  **options: Any) -> list[str]:
    """Names of the episodes :func:`load_episodes` would read, from the metadata alone (no episode file opened)."""
    check_reader_options({"episodes": episodes, "skip_missing": skip_missing, **options})
    return [episode_name(e) for e in _wanted(LeRobotDataset(root), episodes, skip_missing)]


@register("reader", "lerobot")
def load_episodes(
    root: str | Path,
    episodes: Sequence[int] | None = None,
    skip_missing: bool = False,
    names: Collection[str] | None = None,
    **options: Any,
) -> list[Episode]:
    """Episodes of the dataset at ``root`` (all listed ones when ``episodes`` is None; of those, only
    the ones named in ``names`` when given: no other episode's files are opened).

    A listed episode whose files are missing is an error unless ``skip_missing`` (then it is
    skipped with a warning). ``options`` go to :func:`load_episode` (see :data:`READER_OPTIONS`).
    """
    check_reader_options({"episodes": episodes, "skip_missing": skip_missing, **options})
    ds = LeRobotDataset(root)
    return [load_episode(ds, e, **options) for e in _wanted(ds, episodes, skip_missing, names)]
