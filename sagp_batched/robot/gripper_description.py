"""A gripper, described in one file (``data/grippers/<name>.toml``) and looked up by name (``planner.gripper``):
where its description files are, its grasp frame, how its fingers move, which links hold and which collide,
its opening, grip force range and the name the grasp file formats give it.

Frames: every gripper's base link has z along the approach and its fingers closing along y; the grasp
target lies ``grasp_depth_m`` along z from the base link's origin, between the pads.
"""
from __future__ import annotations

import functools
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet_data

from ..config.settings import ConfigError
from ..config.world import GRIPPERS_DIR
from .. import description_files

FINGER_MOTIONS = ("slide", "linkage")
# Driven-joint values the linkage's opening is tabulated at, between the joint's limits.
LINKAGE_SAMPLES = 161
# A pad hull's vertices this close to its innermost one (along the closing axis) are its face.
PAD_FACE_DEPTH_M = 0.0005
# A pad's path is followed this far (rad) either side of a driven joint's value.
PAD_PATH_STEP_RAD = 1e-4


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
class GripperDescription:
    """Every fact about a gripper the code needs, read from ``data/grippers/<name>.toml``."""

    name: str
    urdf_path: Path
    mjcf_path: Path | None  # the MuJoCo model where the gripper has its own; else MuJoCo builds it from the URDF
    base_link: str
    grasp_target_link: str | None  # a link of the URDF at the grasp target, where it has one
    grasp_depth_m_given: float | None
    finger_joints: tuple[str, ...]  # the joints the engines drive, each to the same value
    finger_motion: str  # "slide": prismatic fingers; "linkage": the pads move on the driven joint's arc
    pad_links: tuple[str, ...]  # the links whose surfaces hold the object
    finger_links: tuple[str, ...]  # every link the finger joints move
    collision_links: tuple[str, ...]
    open_width_m: float
    grip_force_range_n: tuple[float, float]
    file_name: str  # ACRONYM's gripper/type, GraspGen's gripper name
    file_aliases: tuple[str, ...]  # other names grasp files give it
    gripper_boxes: GripperBoxes
    mujoco: tuple[tuple[str, object], ...] = ()  # the MJCF's names and calibration ([mujoco] table)
    # PyBullet's solver substeps per step and iterations ([pybullet] table); None: the scene's iterations.
    pybullet_substeps: int = 1
    pybullet_solver_iterations: int | None = None

    @property
    def grasp_depth_m(self) -> float:
        """Distance of the grasp target from the base link's origin along the approach."""
        if self.grasp_target_link is not None:
            return _grasp_target_depth_m(self.urdf_path, self.base_link, self.grasp_target_link)
        return float(self.grasp_depth_m_given)

    def finger_joint_value(self, width_m: float) -> float:
        """The value each finger joint is driven to for a gap of ``width_m`` between the pads (clamped to the stroke)."""
        width_m = min(max(float(width_m), 0.0), self.open_width_m)
        if self.finger_motion == "slide":
            return width_m / 2.0
        values, gaps = linkage_table(self)
        return float(np.interp(width_m, gaps[::-1], values[::-1]))

    def drive_torque_per_pad_newton(self, joint_value: float) -> float:
        """The torque (N m) the driven joint of a linkage exerts per newton each pad presses with, at
        ``joint_value``: by virtual work, the rate at which the gap between the pads closes per radian,
        |d gap / d q|, from the URDF's kinematics (one driven joint moves both pads)."""
        values, closing_rates = linkage_closing_rates(self)
        return float(np.interp(joint_value, values, closing_rates))

    def pad_path_slope(self, width_m: float) -> float:
        """How far each pad moves along the approach, away from the palm, per metre it moves toward the
        closing plane as the fingers close through the opening ``width_m``: 0 for fingers that slide, more
        the wider a linkage stands (it swings its pads on arcs). By virtual work, with the drive's force
        fixed, a force the object puts on a pad along its path adds this times itself to the pad's normal
        force (``benchmarks.coulomb_slip.PinchGrip``)."""
        if self.finger_motion == "slide":
            return 0.0
        return _pad_path_slope(self, self.finger_joint_value(width_m))

    def mujoco_value(self, key: str):
        return dict(self.mujoco)[key]


@functools.lru_cache(maxsize=8)
def _grasp_target_depth_m(urdf_path: Path, base_link: str, grasp_target_link: str) -> float:
    poses = description_files.link_poses(urdf_path, {})
    base_to_target = np.linalg.inv(poses[base_link]) @ poses[grasp_target_link]
    if not np.allclose(base_to_target[:3, :3], np.eye(3), atol=1e-6) or not np.allclose(base_to_target[:2, 3], 0.0, atol=1e-6):
        raise ValueError(f"{urdf_path}: {grasp_target_link} is not on {base_link}'s z axis with its orientation")
    return float(base_to_target[2, 3])


@functools.lru_cache(maxsize=8)
def linkage_table(gripper: GripperDescription) -> tuple[np.ndarray, np.ndarray]:
    """(driven joint values, gaps between the pads' faces) across the driven joint's range, from the
    URDF's kinematics with its mimic joints following: the opening as a function of the joint."""
    lower, upper = description_files.joint_limits(gripper.urdf_path, gripper.finger_joints[0])
    values = np.linspace(lower, upper, LINKAGE_SAMPLES)
    return values, np.array([pad_gap_m(gripper, value) for value in values])


@functools.lru_cache(maxsize=8)
def linkage_closing_rates(gripper: GripperDescription) -> tuple[np.ndarray, np.ndarray]:
    """(driven joint values, |d gap / d value| there, m per radian): how fast the pads close along the stroke."""
    values, gaps = linkage_table(gripper)
    return values, np.abs(np.gradient(gaps, values))


def _pad_path_slope(gripper: GripperDescription, joint_value: float) -> float:
    """``GripperDescription.pad_path_slope`` of a linkage at its driven joint's ``joint_value``: the centre of each
    pad's face (its hull's vertices within ``PAD_FACE_DEPTH_M`` of the closing plane's nearest), a point fixed in
    the pad, followed by the URDF's kinematics over ``PAD_PATH_STEP_RAD`` either side (within the joint's limits),
    in the base link's frame (z the approach, y the closing axis); the mean of the pads."""
    hulls = description_files.link_hulls(gripper.urdf_path, gripper.pad_links)
    lower, upper = description_files.joint_limits(gripper.urdf_path, gripper.finger_joints[0])

    def pad_frames(value: float) -> dict[str, np.ndarray]:
        poses = description_files.link_poses(gripper.urdf_path, {joint: value for joint in gripper.finger_joints})
        base = np.linalg.inv(poses[gripper.base_link])
        return {link: base @ poses[link] for link in gripper.pad_links}

    at = pad_frames(joint_value)
    first, second = (pad_frames(min(max(joint_value + step, lower), upper)) for step in (-PAD_PATH_STEP_RAD, PAD_PATH_STEP_RAD))
    slopes = []
    for link in gripper.pad_links:
        placed = hulls[link] @ at[link][:3, :3].T + at[link][:3, 3]
        inward = np.abs(placed[:, 1])
        face_centre = hulls[link][inward <= inward.min() + PAD_FACE_DEPTH_M].mean(axis=0)
        start, end = (frames[link][:3, :3] @ face_centre + frames[link][:3, 3] for frames in (first, second))
        moved_in = np.sign(start[1]) * (start[1] - end[1])
        slopes.append((end[2] - start[2]) / moved_in)
    return float(np.mean(slopes))


def pad_gap_m(gripper: GripperDescription, joint_value: float) -> float:
    """The gap between the pads' faces along the closing axis (y) with the finger joints at ``joint_value``."""
    hulls = description_files.link_hulls(gripper.urdf_path, gripper.pad_links)
    poses = description_files.link_poses(gripper.urdf_path, {joint: joint_value for joint in gripper.finger_joints})
    ys = [(hulls[link] @ poses[link][:3, :3].T + poses[link][:3, 3])[:, 1] for link in gripper.pad_links]
    low, high = sorted(ys, key=lambda y: y.mean())
    return float(high.min() - low.max())


def _frozen(value):
    """A TOML value with its arrays as tuples: the description is hashed (``linkage_table``'s cache)."""
    return tuple(_frozen(item) for item in value) if isinstance(value, list) else value


def _path(entry: str, folder: Path) -> Path:
    if entry.startswith("pybullet_data:"):
        return Path(pybullet_data.getDataPath()) / entry.removeprefix("pybullet_data:")
    return folder / entry


@functools.lru_cache(maxsize=None)
def load_gripper(name: str) -> GripperDescription:
    """The description of gripper ``name`` shipped in ``sagp_batched/data/grippers``."""
    entry = GRIPPERS_DIR.joinpath(f"{name}.toml")
    if not entry.is_file():
        raise ConfigError(f"unknown gripper '{name}': no data/grippers/{name}.toml in the package", "planner.gripper")
    values = tomllib.loads(entry.read_text())
    folder = Path(str(GRIPPERS_DIR))
    if values["finger_motion"] not in FINGER_MOTIONS:
        raise ConfigError(f"gripper '{name}': finger_motion must be one of {', '.join(FINGER_MOTIONS)}", "planner.gripper")
    return GripperDescription(
        name=name,
        urdf_path=_path(values["urdf"], folder),
        mjcf_path=_path(values["mjcf"], folder) if "mjcf" in values else None,
        base_link=values["base_link"],
        grasp_target_link=values.get("grasp_target_link"),
        grasp_depth_m_given=values.get("grasp_depth_m"),
        finger_joints=tuple(values["finger_joints"]),
        finger_motion=values["finger_motion"],
        pad_links=tuple(values["pad_links"]),
        finger_links=tuple(values["finger_links"]),
        collision_links=tuple(values["collision_links"]),
        open_width_m=float(values["open_width_m"]),
        grip_force_range_n=tuple(float(v) for v in values["grip_force_range_n"]),
        file_name=values["file_name"],
        file_aliases=tuple(values.get("file_aliases", ())),
        gripper_boxes=GripperBoxes(**{key: float(value) for key, value in values["gripper_boxes"].items()}),
        mujoco=tuple(sorted((key, _frozen(value)) for key, value in values.get("mujoco", {}).items())),
        pybullet_substeps=int(values.get("pybullet", {}).get("substeps", 1)),
        pybullet_solver_iterations=values.get("pybullet", {}).get("solver_iterations"),
    )


def gripper_by_file_name(file_name: str) -> GripperDescription:
    """The gripper a grasp file names (ACRONYM's ``gripper/type``, GraspGen's gripper name)."""
    from ..config.world import GRIPPERS

    by_file_name = {file_name: name for name in GRIPPERS for file_name in (load_gripper(name).file_name, *load_gripper(name).file_aliases)}
    if file_name not in by_file_name:
        raise ConfigError(f"unknown gripper '{file_name}' in the grasp file; known: {', '.join(sorted(by_file_name))}", "gripper/type")
    return load_gripper(by_file_name[file_name])
