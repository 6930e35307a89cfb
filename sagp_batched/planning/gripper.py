"""The open Panda gripper as the planner models it: its collision proxies, its hulls, its jaw width."""
from __future__ import annotations

from sagp_batched_kernels.gripper_volume import GripperGeometry

from ..config import PlannerConfig
from ..hand import HandGeometry, load_hand_geometry
from ..robot import PANDA


def gripper_geometry(config: PlannerConfig) -> GripperGeometry:
    """The boxes the 12 % occupancy check counts points in."""
    return GripperGeometry(
        open_width_m=PANDA.open_width_m,
        finger_width_m=config.finger_width_m,
        finger_thickness_m=config.finger_thickness_m,
        finger_length_m=config.finger_length_m,
        fingertip_offset_m=config.fingertip_offset_m,
        palm_width_m=config.palm_width_m,
        palm_span_m=config.palm_span_m,
        palm_depth_m=config.palm_depth_m,
        contact_clearance_m=config.contact_clearance_m,
    )


def hand_geometry(config: PlannerConfig) -> HandGeometry:
    """The open Panda hand's collision hulls, derived from the robot's URDF."""
    return load_hand_geometry(PANDA.urdf_path, PANDA.open_width_m)


def jaw_width_limit(planner: PlannerConfig) -> float:
    """Widest pair the open jaws can descend around with ``jaw_clearance_m`` on each side."""
    return PANDA.open_width_m - 2.0 * planner.jaw_clearance_m
