"""The open gripper as the planner models it: its collision proxies, its hulls, its jaw width, the widest pair it draws."""
from __future__ import annotations

from sagp_batched_kernels.gripper_occupancy import GripperGeometry

from ..config import PlannerConfig
from ..robot.description import RobotDescription
from ..robot.hand import HandGeometry, load_hand_geometry


def gripper_geometry(robot: RobotDescription, planner: PlannerConfig) -> GripperGeometry:
    """The boxes the 12 % occupancy check counts points in: the robot's, with the planner's contact clearance."""
    boxes = robot.gripper.gripper_boxes
    return GripperGeometry(
        open_width_m=robot.gripper.open_width_m,
        finger_width_m=boxes.finger_width_m,
        finger_thickness_m=boxes.finger_thickness_m,
        finger_length_m=boxes.finger_length_m,
        fingertip_offset_m=boxes.fingertip_offset_m,
        palm_width_m=boxes.palm_width_m,
        palm_span_m=boxes.palm_span_m,
        palm_depth_m=boxes.palm_depth_m,
        contact_clearance_m=planner.contact_clearance_m,
    )


def hand_geometry(robot: RobotDescription) -> HandGeometry:
    """The open hand's collision hulls, derived from the robot's URDF."""
    return load_hand_geometry(robot)


def widest_pair_m(robot: RobotDescription, planner: PlannerConfig) -> float:
    """The widest contact pair the planner draws: ``max_width_m``, or where that is 0 the gripper's opening."""
    return planner.max_width_m or robot.gripper.open_width_m


def jaw_width_limit(robot: RobotDescription, planner: PlannerConfig) -> float:
    """Widest pair the open jaws can descend around with ``jaw_clearance_m`` on each side."""
    return robot.gripper.open_width_m - 2.0 * planner.jaw_clearance_m
