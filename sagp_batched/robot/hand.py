"""The hand as PyBullet collides it, derived from the URDF for the planner's checks.

PyBullet collides each link with the convex hull of its collision geometry placed at the collision
``<origin>``. This module places each hull (``description_files.link_hulls``) with the URDF's forward
kinematics (fingers fully open, a linkage's mimic joints following), and expresses the hull vertices in
the grasp frame (z = approach, y = closing axis, origin at the grasp target). Nothing about the hand's
shape is typed in.

For batched point tests each hull is bounded by a k-DOP: its extent along 13 fixed directions
(the 3 axes, 6 edge and 4 corner diagonals). A k-DOP contains its hull (conservative) and, unlike
a box, follows the hand's bevels and the fingers' taper; its extents along a straight stroke are
exact (extent + stroke * direction), which is how the descent sweep is built.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch

from .. import description_files
from .description import RobotDescription


def _dop_directions() -> torch.Tensor:
    axes = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
    edges = [(1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1)]
    corners = [(1, 1, 1), (1, 1, -1), (1, -1, 1), (-1, 1, 1)]
    directions = torch.tensor(axes + edges + corners, dtype=torch.float64)
    return (directions / directions.norm(dim=1, keepdim=True)).to(torch.float32)


DOP_DIRECTIONS = _dop_directions()  # (13, 3) unit directions, grasp frame


@dataclass(frozen=True)
class HandGeometry:
    """Convex collision hulls of the open hand in the grasp frame, and their k-DOP bounds.

    ``hull_vertices[i]`` is link ``links[i]``'s hull, (V_i, 3) metres in the grasp frame, with the
    fingers open to ``open_width_m``; ``dop_low``/``dop_high`` (S, D) bound hull i along
    ``DOP_DIRECTIONS``.
    """

    links: tuple[str, ...]
    open_width_m: float
    hull_vertices: tuple[torch.Tensor, ...]
    dop_low: torch.Tensor
    dop_high: torch.Tensor

    def vertices(self, links: tuple[str, ...] | None = None) -> torch.Tensor:
        """(V, 3) the hull vertices of ``links`` (default: every link), grasp frame: what the table check tests."""
        return torch.cat([hull for name, hull in zip(self.links, self.hull_vertices) if links is None or name in links])

    def swept(self, stroke_local: tuple[float, float, float]) -> tuple[torch.Tensor, torch.Tensor]:
        """k-DOP extents (low, high), (S, D), of each hull swept by the straight stroke from its
        pose to its pose + ``stroke_local`` (grasp frame, metres): exact for k-DOPs, since the
        sweep adds the stroke's projection to one side of every extent."""
        along = DOP_DIRECTIONS @ torch.tensor(stroke_local, dtype=torch.float32)  # (D,)
        return self.dop_low + along.clamp(max=0.0), self.dop_high + along.clamp(min=0.0)


def grasp_frame_link_poses(robot: RobotDescription, width_m: float) -> dict[str, np.ndarray]:
    """(4, 4) pose of every link of the gripper's URDF in the grasp frame with the fingers at the opening
    ``width_m``: from the robot's URDF where the gripper is the one it carries (the wrist beside it), else from
    the gripper's own, its linkage's mimic joints following the driven one."""
    gripper = robot.gripper
    urdf_path = robot.urdf_path if robot.gripper_mounted else gripper.urdf_path
    joint_value = gripper.finger_joint_value(width_m)
    poses = description_files.link_poses(urdf_path, {joint: joint_value for joint in gripper.finger_joints})
    if gripper.grasp_target_link is not None:
        grasp_pose = poses[gripper.grasp_target_link]
    else:
        grasp_pose = poses[gripper.base_link] @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, gripper.grasp_depth_m], [0, 0, 0, 1]])
    grasp_from_base = np.linalg.inv(grasp_pose)
    return {name: grasp_from_base @ pose for name, pose in poses.items()}


def hulls_in_grasp_frame(robot: RobotDescription, links: tuple[str, ...], width_m: float) -> list[torch.Tensor]:
    """The collision hulls of ``links`` (float32 (V, 3) each), in the grasp frame with the fingers at the opening
    ``width_m`` (``grasp_frame_link_poses``)."""
    urdf_path = robot.urdf_path if robot.gripper_mounted else robot.gripper.urdf_path
    poses = grasp_frame_link_poses(robot, width_m)
    return [torch.tensor(vertices @ poses[name][:3, :3].T + poses[name][:3, 3], dtype=torch.float32)
            for name, vertices in description_files.link_hulls(urdf_path, links).items()]


@functools.lru_cache(maxsize=8)
def load_hand_geometry(robot: RobotDescription) -> HandGeometry:
    """The collision hulls of the hand's links (``robot.hand_collision_links``), in the grasp frame with the
    fingers fully open (``hulls_in_grasp_frame``)."""
    gripper, links = robot.gripper, robot.hand_collision_links
    hulls = hulls_in_grasp_frame(robot, links, gripper.open_width_m)
    projections = [hull @ DOP_DIRECTIONS.T for hull in hulls]  # (V_i, D)
    return HandGeometry(
        links=tuple(links),
        open_width_m=float(gripper.open_width_m),
        hull_vertices=tuple(hulls),
        dop_low=torch.stack([p.min(dim=0).values for p in projections]),
        dop_high=torch.stack([p.max(dim=0).values for p in projections]),
    )
