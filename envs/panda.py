"""The Franka Panda the scene uses: joint indices, limits, forces, postures and its lightened URDF."""

from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path

import numpy as np

from envs.bullet import pybullet_data
from rdd.atomic import write_text_atomic

ARM_JOINTS = tuple(range(7))
FINGER_JOINTS = (9, 10)
HAND_LINK = 8
EE_LINK = 11  # panda_grasptarget: the point between the fingertips
HOME_Q = (0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785)
# Postures with the hand horizontal, pointing away from the robot (IK seeds for side grasps).
SIDE_SEEDS = ((0.0, 0.3, 0.0, -2.0, 0.0, 2.3, -0.785), (0.0, 0.3, 0.0, -2.0, 0.0, 2.3, 2.35))
JOINT_LOWER = np.array([-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671])
JOINT_UPPER = np.array([2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671])
ARM_FORCES = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
FINGER_OPEN = 0.04


def lite_panda_urdf() -> str:
    """Path of panda.urdf with its collision meshes also used as visuals.

    The stock visual meshes are ~1 MB each and make TinyRenderer ~15x slower; the collision
    meshes keep the silhouette. Kinematics and dynamics are the stock file's, untouched.
    """
    data = Path(pybullet_data.getDataPath()) / "franka_panda"
    text = (data / "panda.urdf").read_text()
    text = text.replace("package://meshes/visual/", "package://meshes/collision/")
    text = text.replace("package://meshes/", f"{data / 'meshes'}/")
    key = hashlib.sha256(text.encode()).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / f"rdd_envs_panda_{key}.urdf"
    if not out.is_file():
        write_text_atomic(out, text)
    return str(out)
