"""Checks of what a LeRobot dataset says about itself, so bad data is an error and not a wrong result.

``meta/info.json`` fields (``fps``, ``features``, the path templates, ``chunks_size``) are checked
when a dataset is opened; each episode's rows when it is read: as many as the metadata records,
timestamps finite, increasing and as far apart as ``fps`` says, the state columns the reader uses
finite. Every failure is an :class:`rdd.errors.InputError` whose one line names the file, the
episode and the field.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from rdd.errors import InputError

# How far the median frame interval may stray from 1/fps (relative): recorded timestamps jitter by
# far less, while a wrong fps (60 written for 30 fps data) is off by a factor.
FPS_TOLERANCE = 0.1


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_info(info: Any, path: Path) -> float:
    """Raise InputError naming the field when ``info.json`` is malformed; return its fps."""
    if not isinstance(info, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(info).__name__}")
    fps = info.get("fps")
    if not _is_number(fps) or not math.isfinite(fps) or fps <= 0:
        raise InputError(f"{path}: field 'fps' is {fps!r}; expected a positive number of frames per second")
    features = info.get("features")
    if not isinstance(features, dict):
        raise InputError(f"{path}: field 'features' is a {type(features).__name__}; expected an object "
                         "mapping each feature name to {dtype, shape, names}")
    for key, feature in features.items():
        if not isinstance(feature, dict):
            raise InputError(f"{path}: field 'features.{key}' is {feature!r}; expected an object "
                             "{dtype, shape, names}")
        if not isinstance(feature.get("dtype", ""), str):
            raise InputError(f"{path}: field 'features.{key}.dtype' is {feature['dtype']!r}; expected a string")
    for key in ("data_path", "video_path"):
        if info.get(key) is not None and not isinstance(info[key], str):
            raise InputError(f"{path}: field {key!r} is {info[key]!r}; expected a path template string")
    chunks = info.get("chunks_size", 1000)
    if not isinstance(chunks, int) or isinstance(chunks, bool) or chunks < 1:
        raise InputError(f"{path}: field 'chunks_size' is {chunks!r}; expected an integer >= 1")
    return float(fps)


def check_length(n: int, meta: dict[str, Any], where: str, meta_file: Path) -> None:
    """Raise InputError when an episode's ``n`` rows differ from the ``length`` its metadata records."""
    length = meta.get("length")
    if length is None:
        return
    if not _is_number(length) or int(length) != length:
        raise InputError(f"{meta_file} (episode {meta.get('episode_index')}): field 'length' is {length!r}; "
                         "expected an integer")
    if n != int(length):
        raise InputError(f"{where}: holds {n} rows but {meta_file} records field 'length' {int(length)} "
                         f"({'truncated' if n < length else 'extra'} rows)")


def check_timestamps(timestamps: np.ndarray, fps: float, where: str, info_path: Path) -> None:
    """Raise InputError unless the timestamps are finite, increasing and 1/fps apart (median)."""
    bad = np.flatnonzero(~np.isfinite(timestamps))
    if bad.size:
        raise InputError(f"{where}: field 'timestamp' is {timestamps[bad[0]]} at frame {bad[0]} "
                         f"({bad.size} non-finite values)")
    steps = np.diff(timestamps)
    back = np.flatnonzero(steps <= 0)
    if back.size:
        i = int(back[0])
        raise InputError(f"{where}: field 'timestamp' is not increasing: {timestamps[i]:.6g} at frame {i}, "
                         f"then {timestamps[i + 1]:.6g} ({back.size} such steps)")
    if steps.size >= 2:
        step = float(np.median(steps))
        if abs(step * fps - 1.0) > FPS_TOLERANCE:
            raise InputError(f"{info_path}: field 'fps' is {fps:g} but the frame timestamps of {where} are "
                             f"{step:.6g} s apart ({1.0 / step:.4g} fps); correct the field")


def check_finite(values: np.ndarray, where: str, field: str) -> None:
    """Raise InputError naming the first row when ``values`` hold NaN or inf."""
    rows = np.flatnonzero(~np.isfinite(values.reshape(len(values), -1)).all(axis=1))
    if rows.size:
        raise InputError(f"{where}: field {field!r} holds NaN or inf at frame {rows[0]} "
                         f"({rows.size} frames affected)")
