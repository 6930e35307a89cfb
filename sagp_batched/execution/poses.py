"""Differences between PyBullet poses (position, xyzw quaternion): how far a body moved and turned.

``relative_pose`` computes as PyBullet's ``invertTransform`` and ``multiplyTransforms`` do, in single
precision and in their order of operations, so every recorded motion is the value PyBullet gave while
an engine without PyBullet (``datasets.mujoco_hand``) can record it too."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
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
    frame_basis = _basis(frame[1])
    inverse_basis = tuple(tuple(frame_basis[row][column] for row in range(3)) for column in range(3))
    minus_origin = tuple(-np.float32(value) for value in frame[0])
    inverse_position = tuple(_dot(row, minus_origin) for row in inverse_basis)
    # PyBullet hands the inverse back as a quaternion and reads it again: the round trip rounds.
    inverse_basis = _basis(_quat(inverse_basis))
    body_basis, body_position = _basis(body[1]), tuple(np.float32(value) for value in body[0])
    position = tuple(float(_dot(row, body_position) + inverse_position[k]) for k, row in enumerate(inverse_basis))
    rotation = tuple(tuple(_dot(row, tuple(body_basis[r][column] for r in range(3))) for column in range(3)) for row in inverse_basis)
    return position, tuple(float(value) for value in _quat(rotation))


_Basis = tuple[tuple[np.float32, ...], ...]


def _dot(first: Sequence[np.float32], second: Sequence[np.float32]) -> np.float32:
    return first[0] * second[0] + first[1] * second[1] + first[2] * second[2]


def _basis(quat: Sequence[float]) -> _Basis:
    """Bullet's rotation matrix of a quaternion of any norm (``btMatrix3x3::setRotation``), in single precision."""
    x, y, z, w = (np.float32(value) for value in quat)
    s = np.float32(2.0) / (x * x + y * y + z * z + w * w)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    one = np.float32(1.0)
    return ((one - (yy + zz), xy - wz, xz + wy), (xy + wz, one - (xx + zz), yz - wx), (xz - wy, yz + wx, one - (xx + yy)))


def _quat(basis: _Basis) -> tuple[np.float32, ...]:
    """Bullet's quaternion of a rotation matrix (``btMatrix3x3::getRotation``), in single precision."""
    half, quat = np.float32(0.5), [np.float32(0.0)] * 4
    trace = basis[0][0] + basis[1][1] + basis[2][2]
    if trace > 0.0:
        s = np.sqrt(trace + np.float32(1.0))
        quat[3], s = s * half, half / s
        quat[0] = (basis[2][1] - basis[1][2]) * s
        quat[1] = (basis[0][2] - basis[2][0]) * s
        quat[2] = (basis[1][0] - basis[0][1]) * s
        return tuple(quat)
    if basis[0][0] < basis[1][1]:
        i = 2 if basis[1][1] < basis[2][2] else 1
    else:
        i = 2 if basis[0][0] < basis[2][2] else 0
    j, k = (i + 1) % 3, (i + 2) % 3
    s = np.sqrt(basis[i][i] - basis[j][j] - basis[k][k] + np.float32(1.0))
    quat[i], s = s * half, half / s
    quat[3] = (basis[k][j] - basis[j][k]) * s
    quat[j] = (basis[j][i] + basis[i][j]) * s
    quat[k] = (basis[k][i] + basis[i][k]) * s
    return tuple(quat)


def pose_matrix(position: Sequence[float], quat_xyzw: Sequence[float]) -> np.ndarray:
    """(4, 4) homogeneous transform of a pose (position, xyzw quaternion)."""
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat(quat_xyzw).as_matrix()
    matrix[:3, 3] = position
    return matrix
