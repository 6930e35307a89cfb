"""The robot, described in one file (``data/robots/<name>.toml``) and looked up by name
(``scene.robot``), with the gripper the planner plans for (``planner.gripper``); every module that needs
a robot or gripper fact is handed the ``RobotDescription``.

Everything else about the robot (link offsets, joint limits, collision hulls) is read from its URDF
through ``description_files``.
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
from .gripper_description import GripperDescription, load_gripper

if TYPE_CHECKING:
    from ..config import Config


@dataclass(frozen=True)
class RobotDescription:
    """Every fact about a robot the code needs, read from ``data/robots/<name>.toml``."""

    name: str
    urdf_path: Path
    base_link: str
    arm_joints: tuple[str, ...]
    # The gripper planned for; ``gripper_mounted``: it is the one the robot's URDF carries, so the arm's
    # IK and motion checks apply to it.
    gripper: GripperDescription
    gripper_mounted: bool
    wrist_collision_links: tuple[str, ...]  # arm links beside the hand that a grasp's approach can bring against the object
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

    @property
    def n_arm_joints(self) -> int:
        return len(self.arm_joints)

    @property
    def hand_collision_links(self) -> tuple[str, ...]:
        """The links the planner checks a grasp's approach with: the gripper's, and the wrist where it is mounted."""
        return self.gripper.collision_links + (self.wrist_collision_links if self.gripper_mounted else ())

    def require_mounted_gripper(self, what: str) -> None:
        """Refuse ``what`` (something the arm does) with a gripper the robot does not carry."""
        if not self.gripper_mounted:
            raise ConfigError(f"{what} needs the gripper on the arm: robot '{self.name}' carries no '{self.gripper.name}' "
                              "(plan and label it in hand mode)", "planner.gripper")


@functools.lru_cache(maxsize=None)
def load_robot(name: str = "panda", gripper: str | None = None) -> RobotDescription:
    """The description of robot ``name`` shipped in ``sagp_batched/data/robots``, with ``gripper`` (default:
    the one it carries)."""
    entry = ROBOTS_DIR.joinpath(f"{name}.toml")
    if not entry.is_file():
        raise ConfigError(f"unknown robot '{name}': no data/robots/{name}.toml in the package", "scene.robot")
    values = tomllib.loads(entry.read_text())
    robot = RobotDescription(
        name=name,
        urdf_path=Path(pybullet_data.getDataPath()) / values["urdf"],
        base_link=values["base_link"],
        arm_joints=tuple(values["arm_joints"]),
        gripper=load_gripper(gripper or values["gripper"]),
        gripper_mounted=gripper in (None, values["gripper"]),
        wrist_collision_links=tuple(values["wrist_collision_links"]),
        ik_position_tolerance_m=float(values["ik_position_tolerance_m"]),
        ik_rotation_tolerance_rad=float(values["ik_rotation_tolerance_rad"]),
        ik_reference_joints=tuple(float(q) for q in values["ik_reference_joints"]),
        base_xyz_m=tuple(float(v) for v in values["base_xyz_m"]),
        home_joints=tuple(float(q) for q in values["home_joints"]),
        table_check_links=tuple(values["table_check_links"]),
        joint_twist_rad=tuple(math.radians(float(t)) for t in values["joint_twist_deg"]),
        joint_has_a=tuple(bool(v) for v in values["joint_has_a"]),
        joint_has_d=tuple(bool(v) for v in values["joint_has_d"]),
    )
    per_joint = {"ik_reference_joints": robot.ik_reference_joints, "home_joints": robot.home_joints,
                 "joint_twist_deg": robot.joint_twist_rad, "joint_has_a": robot.joint_has_a, "joint_has_d": robot.joint_has_d}
    wrong = [key for key, values_per_joint in per_joint.items() if len(values_per_joint) != robot.n_arm_joints]
    if wrong or len(robot.base_xyz_m) != 3:
        raise ConfigError(f"robot '{name}': {', '.join(wrong) or 'base_xyz_m'} must hold one value per arm joint "
                          f"({robot.n_arm_joints}) and base_xyz_m three", "scene.robot")
    return robot


def robot_of(config: Config) -> RobotDescription:
    """The robot ``config.scene.robot`` names, with the gripper ``config.planner.gripper`` names, whose grip force
    range holds ``execution.gripper_force_n``."""
    robot = load_robot(config.scene.robot, config.planner.gripper)
    low, high = robot.gripper.grip_force_range_n
    if not low <= config.execution.gripper_force_n <= high:
        raise ConfigError(f"execution.gripper_force_n {config.execution.gripper_force_n:g} N is outside the {low:g}-{high:g} N "
                          f"of gripper '{robot.gripper.name}'", "execution.gripper_force_n")
    return robot
