"""The motion a grasp is executed with, as the positions ``panda_grasptarget`` passes through.

One definition serves the planner (which solves and checks every waypoint) and execution (which
tracks the planned joints, or solves these same waypoints when it has no plan): open gripper at a
pre-grasp ``pregrasp_offset_m`` back along the approach, a straight descent onto the grasp, close,
then a straight lift of ``lift_height_m`` with the orientation held throughout.
"""
from __future__ import annotations

import torch

from ..config import MotionConfig


def grasp_waypoint_index(motion: MotionConfig) -> int:
    """Position of the grasp pose in ``motion_waypoints``: after the pre-grasp and descent waypoints."""
    return motion.descent_waypoints


def waypoint_count(motion: MotionConfig) -> int:
    """W, the waypoints of ``motion_waypoints``: the pre-grasp and descent, the grasp, the lift."""
    return motion.descent_waypoints + 1 + motion.lift_waypoints


def motion_waypoints(position_world: torch.Tensor, approach_world: torch.Tensor, motion: MotionConfig) -> torch.Tensor:
    """Waypoints of the whole motion for N grasps.

    Args:
        position_world: (N, 3) grasp positions (where ``panda_grasptarget`` closes), world, metres.
        approach_world: (N, 3) unit directions the gripper moves in toward the object.
        motion: pre-grasp offset, lift height and waypoint counts.

    Returns:
        (N, W, 3) positions, W = descent_waypoints + 1 + lift_waypoints: the pre-grasp first, the
        descent waypoints evenly spaced up to (not including) the grasp, the grasp at
        ``grasp_waypoint_index``, then the lift waypoints evenly spaced up to ``lift_height_m``.
    """
    position = position_world.to(torch.float32)
    pregrasp = position - approach_world.to(torch.float32) * motion.pregrasp_offset_m
    descent_fractions = torch.linspace(0.0, 1.0, motion.descent_waypoints + 1, device=position.device)  # ends at the grasp
    descent = pregrasp[:, None, :] + (position - pregrasp)[:, None, :] * descent_fractions[None, :, None]
    lift_heights = torch.linspace(0.0, motion.lift_height_m, motion.lift_waypoints + 1, device=position.device)[1:]
    lift = position[:, None, :] + lift_heights[None, :, None] * position.new_tensor([0.0, 0.0, 1.0])
    return torch.cat((descent, lift), dim=1)
