"""Differences between PyBullet poses (position, xyzw quaternion): how far a body moved and turned."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation


def quat_angle_deg(quat_a: Sequence[float], quat_b: Sequence[float]) -> float:
    """Angle (degrees) between two orientations (xyzw quaternions, either sign, any norm)."""
    dot = abs(float(np.dot(quat_a, quat_b))) / (np.linalg.norm(quat_a) * np.linalg.norm(quat_b))
    return math.degrees(2.0 * math.acos(min(1.0, dot)))


def pose_change(before: tuple[Any, Any], after: tuple[Any, Any]) -> tuple[float, float]:
    """(distance m, rotation angle rad) between two poses (position, xyzw quaternion)."""
    return float(np.linalg.norm(np.subtract(after[0], before[0]))), math.radians(quat_angle_deg(before[1], after[1]))


def relative_pose(frame: tuple[Any, Any], body: tuple[Any, Any]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The pose ``body`` (world) expressed in the frame ``frame`` (world pose)."""
    inverse_position, inverse_quat = pybullet.invertTransform(frame[0], frame[1])
    return pybullet.multiplyTransforms(inverse_position, inverse_quat, body[0], body[1])


def pose_matrix(position: Sequence[float], quat_xyzw: Sequence[float]) -> np.ndarray:
    """(4, 4) homogeneous transform of a pose (position, xyzw quaternion)."""
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    matrix[:3, 3] = position
    return matrix
