"""Approach directions around a closing axis and the gripper rotations they define.

Grasp frame convention (shared with execution): rotation matrix columns are
x = cross(y, z), y = closing axis, z = approach (the direction the gripper moves in toward the
object). This is the Panda ``panda_hand`` / ``panda_grasptarget`` frame: the fingers slide along
hand y and hand z points out through the fingers.
"""
from __future__ import annotations

import math

import torch


def approach_directions(closing_axis: torch.Tensor, n_approaches: int, preferred: torch.Tensor) -> torch.Tensor:
    """``n_approaches`` unit approach directions evenly spaced on the circle perpendicular to each axis.

    Approach 0 is the direction perpendicular to the axis closest to ``preferred`` (e.g. world
    down for top-down-first grasping); the others follow in order of increasing angle from it,
    alternating sides: steps 0, +1, -1, +2, -2, ... of 2*pi/K. The order is therefore also a
    closest-to-``preferred``-first prior, fixed by index so that mirror-image approaches never
    swap places through rounding. When the axis is parallel to ``preferred``, the world axis least
    aligned with it takes its place.

    Args:
        closing_axis: (C, 3) unit closing axes, world frame.
        n_approaches: K >= 1 approaches per axis.
        preferred: (3,) unit direction approach 0 is rotated towards, world frame.

    Returns:
        (C, K, 3) unit approach directions, world frame, each perpendicular to its closing axis,
        in the prior order described above.
    """
    if closing_axis.ndim != 2 or closing_axis.shape[-1] != 3:
        raise ValueError(f"closing_axis must be (C, 3), got {tuple(closing_axis.shape)}")
    if n_approaches < 1:
        raise ValueError(f"n_approaches must be >= 1, got {n_approaches}")
    preferred = preferred.to(closing_axis)
    first = preferred - (closing_axis @ preferred).unsqueeze(-1) * closing_axis
    first_norm = first.norm(dim=-1, keepdim=True)
    fallback_axis = torch.zeros_like(closing_axis)
    fallback_axis.scatter_(1, closing_axis.abs().argmin(dim=1, keepdim=True), 1.0)
    fallback = fallback_axis - (closing_axis * fallback_axis).sum(-1, keepdim=True) * closing_axis
    # 1e-6 of a unit vector: below it the projection's direction is numerically meaningless.
    degenerate = first_norm < 1e-6
    first = torch.where(degenerate, fallback, first)
    first = first / first.norm(dim=-1, keepdim=True)
    second = torch.linalg.cross(closing_axis, first, dim=-1)
    steps = [(k + 1) // 2 * (1 if k % 2 else -1) for k in range(n_approaches)]
    angles = torch.tensor(steps, dtype=closing_axis.dtype, device=closing_axis.device) * (2.0 * math.pi / n_approaches)
    cos, sin = torch.cos(angles), torch.sin(angles)
    return cos[None, :, None] * first[:, None, :] + sin[None, :, None] * second[:, None, :]


def grasp_rotations(closing_axis: torch.Tensor, approach: torch.Tensor) -> torch.Tensor:
    """Gripper orientations from closing axes and approach directions.

    Args:
        closing_axis: (..., 3) unit closing axes (grasp y), world frame.
        approach: (..., 3) unit approach directions (grasp z), world frame, perpendicular to the axes.

    Returns:
        (..., 3, 3) rotation matrices (grasp frame -> world), columns (x, y, z) with x = cross(y, z),
        right-handed and orthonormal.
    """
    closing_axis, approach = torch.broadcast_tensors(closing_axis, approach)
    x_axis = torch.linalg.cross(closing_axis, approach, dim=-1)
    return torch.stack((x_axis, closing_axis, approach), dim=-1)


def scene_points_about(points: torch.Tensor, object_index: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """(c, N, 3) each candidate's scene points less its grasp centre: ``points[object_index] - centre[:, None]``.

    Args:
        points: (B, N, 3) points of B scenes (NaN-padded rows stay NaN).
        object_index: (c,) int64 scene of each candidate.
        centre: (c, 3) grasp centres.

    Candidates all of one scene (a one-object plan, or a block of scene-sorted candidates) take
    its points by broadcasting: the same values without the (c, N, 3) gather.
    """
    if object_index.numel():
        first, last = object_index.aminmax()
        if first == last:
            return points[int(first)] - centre[:, None, :]
    return points[object_index] - centre[:, None, :]
