"""KeyframeAction validation and round trips."""

from __future__ import annotations

import numpy as np
import pytest

from policy.interface import KeyframeAction


def test_normalises_quaternion_and_round_trips():
    a = KeyframeAction(position=[0.1, 0.2, 0.3], quaternion=[0, 0, 0, 2], gripper_open=0)
    assert np.allclose(a.quaternion, [0, 0, 0, 1])
    assert a.gripper_open is False
    b = KeyframeAction.from_array(a.to_array())
    assert np.allclose(b.position, a.position) and np.allclose(b.quaternion, a.quaternion)
    assert b.gripper_open == a.gripper_open


@pytest.mark.parametrize("pos,quat", [([0, 0], [0, 0, 0, 1]), ([0, 0, np.nan], [0, 0, 0, 1]),
                                      ([0, 0, 0], [0, 0, 0, 0]), ([0, 0, 0], [1, 0, 0])])
def test_rejects_malformed_actions(pos, quat):
    with pytest.raises(ValueError, match="KeyframeAction"):
        KeyframeAction(position=pos, quaternion=quat, gripper_open=True)
