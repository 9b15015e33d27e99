"""Privileged record layout helpers."""

from __future__ import annotations

import numpy as np
import pytest

from envs.record import ArticulationInfo, ObjectInfo, PrivilegedRecorder, validate_privileged


def test_recorder_arrays_and_meta():
    rec = PrivilegedRecorder([ObjectInfo("red_block", "block", "red", (0.05,) * 3, "target")],
                             [ArticulationInfo("top_drawer", "drawer", 0.0, 0.2)])
    for t in range(3):
        rec.append(np.full(3, t), [0, 0, 0, 1], [0.1 * t], held=-1 if t < 2 else 0, success=t == 2)
    arrays, meta = rec.arrays(), rec.meta()
    assert arrays["object_positions"].shape == (3, 1, 3)
    assert arrays["held_object"].tolist() == [-1, -1, 0]
    assert arrays["success"].tolist() == [False, False, True]
    validate_privileged(arrays, meta, 3)
    assert meta["objects"][0]["name"] == "red_block" and meta["articulations"][0]["open"] == 0.2


def test_recorder_rejects_bad_values():
    rec = PrivilegedRecorder([ObjectInfo("a", "block")], [])
    with pytest.raises(ValueError, match="held object"):
        rec.append(np.zeros(3), [0, 0, 0, 1], [], held=1, success=False)
    with pytest.raises(ValueError, match="role"):
        ObjectInfo("a", "block", role="boss").to_json()
    with pytest.raises(ValueError, match="object_positions"):
        validate_privileged({"object_positions": np.zeros((2, 2, 3))}, {"objects": [{}]}, 2)
