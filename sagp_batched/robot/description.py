"""The robot, described in one file (``data/robots/<name>.toml``) and looked up by name
(``scene.robot``); every module that needs a robot fact is handed the ``RobotDescription``.

Everything else about the robot (link offsets, joint limits, collision hulls, the grasp target's
offset from the hand) is read from its URDF by the code that needs it.
"""
from __future__ import annotations

import functools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pybullet_data

from ..config.settings import ConfigError
from ..config.world import ROBOTS_DIR

if TYPE_CHECKING:
    from ..config import Config


@dataclass(frozen=True)
class GripperBoxes:
    """The open gripper as boxes in the grasp frame: the published occupancy proxy's dimensions."""

    finger_width_m: float
    finger_thickness_m: float
    finger_length_m: float
    fingertip_offset_m: float  # how far the fingertips reach beyond the grasp target along the approach
    palm_width_m: float
    palm_span_m: float
    palm_depth_m: float


@dataclass(frozen=True)
class RobotDescription:
    """Every fact about a robot the code needs, read from ``data/robots/<name>.toml``."""

    name: str
    urdf_path: Path
    base_link: str
    arm_joints: tuple[str, ...]
    finger_joints: tuple[str, ...]
    hand_link: str
    grasp_target_link: str
    hand_collision_links: tuple[str, ...]
    finger_links: tuple[str, ...]
    open_width_m: float
    ik_position_tolerance_m: float
    ik_rotation_tolerance_rad: float
    ik_reference_joints: tuple[float, ...]
    base_xyz_m: tuple[float, float, float]  # world position of the base, which faces +x
    home_joints: tuple[float, ...]  # the arm's waiting pose
    table_check_links: tuple[str, ...]  # links the motion check keeps above the table
    # The arm's joint frames as the closed-form IK models them (modified Denavit-Hartenberg).
    joint_twist_rad: tuple[float, ...]
    joint_has_a: tuple[bool, ...]
    joint_has_d: tuple[bool, ...]
    gripper_boxes: GripperBoxes

    @property
    def n_arm_joints(self) -> int:
        return len(self.arm_joints)


@functools.lru_cache(maxsize=None)
def load_robot(name: str = "panda") -> RobotDescription:
    """The description of robot ``name`` shipped in ``sagp_batched/data/robots``."""
    entry = ROBOTS_DIR.joinpath(f"{name}.toml")
    if not entry.is_file():
        raise ConfigError(f"unknown robot '{name}': no data/robots/{name}.toml in the package", "scene.robot")
    values = tomllib.loads(entry.read_text())
    robot = RobotDescription(
        name=name,
        urdf_path=Path(pybullet_data.getDataPath()) / values["urdf"],
        base_link=values["base_link"],
        arm_joints=tuple(values["arm_joints"]),
        finger_joints=tuple(values["finger_joints"]),
        hand_link=values["hand_link"],
        grasp_target_link=values["grasp_target_link"],
        hand_collision_links=tuple(values["hand_collision_links"]),
        finger_links=tuple(values["finger_links"]),
        open_width_m=float(values["open_width_m"]),
        ik_position_tolerance_m=float(values["ik_position_tolerance_m"]),
        ik_rotation_tolerance_rad=float(values["ik_rotation_tolerance_rad"]),
        ik_reference_joints=tuple(float(q) for q in values["ik_reference_joints"]),
        base_xyz_m=tuple(float(v) for v in values["base_xyz_m"]),
        home_joints=tuple(float(q) for q in values["home_joints"]),
        table_check_links=tuple(values["table_check_links"]),
        joint_twist_rad=tuple(math.radians(float(t)) for t in values["joint_twist_deg"]),
        joint_has_a=tuple(bool(v) for v in values["joint_has_a"]),
        joint_has_d=tuple(bool(v) for v in values["joint_has_d"]),
        gripper_boxes=GripperBoxes(**{key: float(value) for key, value in values["gripper_boxes"].items()}),
    )
    per_joint = {"ik_reference_joints": robot.ik_reference_joints, "home_joints": robot.home_joints,
                 "joint_twist_deg": robot.joint_twist_rad, "joint_has_a": robot.joint_has_a, "joint_has_d": robot.joint_has_d}
    wrong = [key for key, values_per_joint in per_joint.items() if len(values_per_joint) != robot.n_arm_joints]
    if wrong or len(robot.base_xyz_m) != 3:
        raise ConfigError(f"robot '{name}': {', '.join(wrong) or 'base_xyz_m'} must hold one value per arm joint "
                          f"({robot.n_arm_joints}) and base_xyz_m three", "scene.robot")
    return robot


def robot_of(config: Config) -> RobotDescription:
    """The robot ``config.scene.robot`` names."""
    return load_robot(config.scene.robot)
