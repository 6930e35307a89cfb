"""The robot, described in one file (``data/robots/<name>.toml``) and looked up by name.

Everything else about the robot (link offsets, joint limits, collision hulls, the grasp target's
offset from the hand) is read from its URDF by the code that needs it.
"""
from __future__ import annotations

import functools
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import pybullet
import pybullet_data


@dataclass(frozen=True)
class RobotDescription:
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


@functools.lru_cache(maxsize=None)
def load_robot(name: str = "panda") -> RobotDescription:
    """The description of robot ``name`` shipped in ``sagp_batched/data/robots``."""
    entry = resources.files("sagp_batched").joinpath(f"data/robots/{name}.toml")
    if not entry.is_file():
        raise ValueError(f"unknown robot '{name}': no data/robots/{name}.toml in the package")
    values = tomllib.loads(entry.read_text())
    return RobotDescription(
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
    )


PANDA = load_robot("panda")


@dataclass(frozen=True)
class BodyIndices:
    """PyBullet's indices of a loaded robot's named joints and links (a link's index is its parent joint's)."""

    arm_joints: tuple[int, ...]
    finger_joints: tuple[int, ...]
    hand_link: int
    grasp_target_link: int


def body_indices(robot: RobotDescription, body_id: int, client: int) -> BodyIndices:
    """Look ``robot``'s joints and links up by name in the loaded body ``body_id``."""
    joints, links = {}, {}
    for index in range(pybullet.getNumJoints(body_id, physicsClientId=client)):
        info = pybullet.getJointInfo(body_id, index, physicsClientId=client)
        joints[info[1].decode()] = index
        links[info[12].decode()] = index
    names = (*robot.arm_joints, *robot.finger_joints)
    missing = [name for name in names if name not in joints] + [n for n in (robot.hand_link, robot.grasp_target_link) if n not in links]
    if missing:
        raise ValueError(f"{robot.urdf_path} has no joints or links named {missing}")
    return BodyIndices(
        arm_joints=tuple(joints[name] for name in robot.arm_joints),
        finger_joints=tuple(joints[name] for name in robot.finger_joints),
        hand_link=links[robot.hand_link],
        grasp_target_link=links[robot.grasp_target_link],
    )
