"""The PyBullet world of one trial: table, Franka Panda, target object and optional distractors.

Each ``Scene`` owns its own PyBullet client (several may live in one process), so every call passes
``physicsClientId``. ``reset`` rebuilds the world from scratch with ``resetSimulation`` and draws
poses from ``numpy.random.default_rng(seeds.scene_seed(config, trial))``: the same trial gives the same settled
poses bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from ..config import Config, SceneConfig
from ..description_files import load_urdf
from ..robot.description import RobotDescription, load_robot
from ..seeds import scene_seed
from ..types import CameraData
from .objects import ObjectLoadError, ObjectSpec

# PyBullet's segmentation value is body_id + ((link_index + 1) << 24) with the flag below.
BODY_ID_BITS = (1 << 24) - 1
# Segmentation value PyBullet writes where no body is hit.
BACKGROUND = -1


class ScenePlacementError(RuntimeError):
    """Distractors could not be placed around the target without overlapping."""


def _footprint(client: int, body_id: int) -> np.ndarray:
    lower, upper = pybullet.getAABB(body_id, physicsClientId=client)
    return np.array([lower[0], lower[1], upper[0], upper[1]])


def _footprint_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between two x/y footprints (min_x, min_y, max_x, max_y); 0 when they overlap."""
    dx = max(0.0, b[0] - a[2], a[0] - b[2])
    dy = max(0.0, b[1] - a[3], a[1] - b[3])
    return math.hypot(dx, dy)


def configure_physics(client: int, scene_config: SceneConfig) -> None:
    """Time step, gravity and solver settings every world of the study (and its labelling) steps with."""
    pybullet.setTimeStep(scene_config.time_step_s, physicsClientId=client)
    pybullet.setGravity(0.0, 0.0, scene_config.gravity_m_s2, physicsClientId=client)
    pybullet.setPhysicsEngineParameter(
        numSolverIterations=scene_config.solver_iterations, deterministicOverlappingPairs=1, physicsClientId=client
    )


def create_table(client: int, scene_config: SceneConfig) -> int:
    """A box with exactly the table's footprint whose top face is at ``table_top_z_m``."""
    half_extents = (scene_config.table_size_m[0] / 2.0, scene_config.table_size_m[1] / 2.0, scene_config.table_top_z_m / 2.0)
    collision = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half_extents, physicsClientId=client)
    visual = pybullet.createVisualShape(pybullet.GEOM_BOX, halfExtents=half_extents, rgbaColor=scene_config.table_rgba, physicsClientId=client)
    centre = (*scene_config.table_center_xy_m, scene_config.table_top_z_m / 2.0)
    return pybullet.createMultiBody(0.0, collision, visual, basePosition=centre, physicsClientId=client)


def command_fingers(client: int, body_id: int, finger_joints: Sequence[int], width_m: float, force_n: float) -> None:
    """Position-control a parallel gripper's two finger joints (each half of ``width_m``) with ``force_n`` each."""
    pybullet.setJointMotorControlArray(
        body_id,
        list(finger_joints),
        pybullet.POSITION_CONTROL,
        targetPositions=[width_m / 2.0] * 2,
        forces=[force_n] * 2,
        physicsClientId=client,
    )


@dataclass(frozen=True)
class BodyIndices:
    """PyBullet's indices of a loaded robot's named joints and links (a link's index is its parent joint's)."""

    arm_joints: tuple[int, ...]
    finger_joints: tuple[int, ...]
    hand_link: int
    grasp_target_link: int
    # Every non-fixed joint, in index order: the order PyBullet's IK and Jacobian use.
    movable_joints: tuple[int, ...]


def body_indices(robot: RobotDescription, body_id: int, client: int) -> BodyIndices:
    """Look ``robot``'s joints and links up by name in the loaded body ``body_id``."""
    joints, links, movable = {}, {}, []
    for index in range(pybullet.getNumJoints(body_id, physicsClientId=client)):
        info = pybullet.getJointInfo(body_id, index, physicsClientId=client)
        joints[info[1].decode()] = index
        links[info[12].decode()] = index
        if info[2] != pybullet.JOINT_FIXED:
            movable.append(index)
    names = (*robot.arm_joints, *robot.gripper.finger_joints)
    missing = [name for name in names if name not in joints] + [n for n in (robot.gripper.base_link, robot.gripper.grasp_target_link) if n not in links]
    if missing:
        raise ValueError(f"{robot.urdf_path} has no joints or links named {missing}")
    return BodyIndices(
        arm_joints=tuple(joints[name] for name in robot.arm_joints),
        finger_joints=tuple(joints[name] for name in robot.gripper.finger_joints),
        hand_link=links[robot.gripper.base_link],
        grasp_target_link=links[robot.gripper.grasp_target_link],
        movable_joints=tuple(movable),
    )


def _resting_rotation(spec: ObjectSpec, index: int) -> np.ndarray | None:
    """(3, 3) rotation from the link frame onto resting pose ``index`` of ``spec``; None for the upright link frame."""
    if index == 0:
        return None
    if not 0 <= index < len(spec.resting_poses):
        raise ValueError(f"object '{spec.id}' has {max(1, len(spec.resting_poses))} resting pose(s), not a pose {index}")
    return np.asarray(spec.resting_poses[index].link_to_rest, dtype=float)[:3, :3]


def make_camera(name: str, config: Config, eye_world: Sequence[float], target_world: Sequence[float], up_world: Sequence[float]) -> CameraData:
    """A pinhole camera at ``eye_world`` looking at ``target_world``; intrinsics follow PyBullet's projection."""
    camera = config.camera
    view = pybullet.computeViewMatrix(list(eye_world), list(target_world), list(up_world))
    aspect = camera.width_px / camera.height_px
    projection = pybullet.computeProjectionMatrixFOV(camera.fov_deg, aspect, camera.near_m, camera.far_m)
    focal_px = camera.height_px / (2.0 * math.tan(math.radians(camera.fov_deg) / 2.0))
    # Pixel (u, v) covers [u, u + 1] in OpenGL's raster, so its centre sits half a pixel in.
    intrinsics = np.array(
        [[focal_px, 0.0, camera.width_px / 2.0 - 0.5], [0.0, focal_px, camera.height_px / 2.0 - 0.5], [0.0, 0.0, 1.0]]
    )
    world_to_opengl = np.array(view).reshape(4, 4).T
    # OpenGL's camera looks down -z with y up; the pinhole frame looks down +z with y down.
    opengl_to_pinhole = np.diag([1.0, -1.0, -1.0, 1.0])
    camera_to_world = np.linalg.inv(world_to_opengl) @ opengl_to_pinhole
    return CameraData(
        name=name,
        width_px=camera.width_px,
        height_px=camera.height_px,
        intrinsics=intrinsics,
        camera_to_world=camera_to_world,
        view_matrix=np.array(view),
        projection_matrix=np.array(projection),
        near_m=camera.near_m,
        far_m=camera.far_m,
    )


class Scene:
    """Table, robot and objects in one PyBullet client; ``reset`` builds a trial's settled scene."""

    def __init__(self, config: Config, gui: bool = False):
        self.config = config
        # The arm with the gripper its URDF carries, whichever gripper is planned for: a scene also settles
        # objects and renders captures for grippers no arm carries (the arm waits out of view); execution
        # refuses those. Read before connecting: an unknown robot leaves no client behind.
        self.robot = load_robot(config.scene.robot)
        self.client = pybullet.connect(pybullet.GUI if gui else pybullet.DIRECT)
        self.robot_id: int = -1
        self.table_id: int = -1
        self.target_id: int = -1
        self.distractor_ids: list[int] = []
        self.target_spec: ObjectSpec | None = None
        self.distractor_specs: list[ObjectSpec] = []
        self.trial: int | None = None
        self._state_id: int | None = None
        self._arm_max_forces = ()

    # -- lifecycle -------------------------------------------------------------------------------
    def close(self) -> None:
        if self.client >= 0 and pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)
        self.client = -1

    def __enter__(self) -> "Scene":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def reset(self, target: ObjectSpec, trial: int, distractors: Sequence[ObjectSpec] = (), resting_pose: int = 0) -> None:
        """Rebuild the world for ``trial``: target at a seeded (x, y, yaw), seeded distractors, settled.

        The target rests in its link frame's upright pose, or in ``target.resting_poses[resting_pose]``
        where the object lists its stable poses (an imported mesh; pose 0 is the upright link frame).

        With ``distractors`` given, 3-4 of them (count seeded) are placed within
        ``distractor_max_distance_m`` of the target without footprint overlap. The arm waits in its
        home pose, clear of the cameras.
        """
        scene_config, robot = self.config.scene, self.robot
        client = self.client
        pybullet.resetSimulation(physicsClientId=client)
        configure_physics(client, scene_config)
        self._state_id = None
        self.trial = trial
        self.target_spec = target
        self.table_id = create_table(client, scene_config)
        self.robot_id = load_urdf(client, robot.urdf_path, basePosition=robot.base_xyz_m, useFixedBase=True)
        self.robot_indices = body_indices(robot, self.robot_id, client)
        self._arm_max_forces = tuple(pybullet.getJointInfo(self.robot_id, j, physicsClientId=client)[10] for j in self.robot_indices.arm_joints)
        self.set_arm_joints(robot.home_joints)
        self.set_finger_width(robot.gripper.open_width_m)

        rng = np.random.default_rng(scene_seed(self.config, trial))
        x = rng.uniform(*scene_config.object_x_range_m)
        y = rng.uniform(*scene_config.object_y_range_m)
        yaw = rng.uniform(*scene_config.object_yaw_range_rad)
        self.target_id = self._load_on_table(target, x, y, yaw, _resting_rotation(target, resting_pose))
        self.distractor_ids = []
        self.distractor_specs = []
        if distractors:
            self._place_distractors(list(distractors), rng)
        for _ in range(scene_config.settle_steps):
            pybullet.stepSimulation(physicsClientId=client)
        self.save_state()

    # -- state -----------------------------------------------------------------------------------
    def save_state(self) -> None:
        """Remember the current (settled) scene so ``restore_state`` can return to it exactly."""
        if self._state_id is not None:
            pybullet.removeState(self._state_id, physicsClientId=self.client)
        self._state_id = pybullet.saveState(physicsClientId=self.client)

    def restore_state(self) -> None:
        """Return to the saved scene; the arm's motors are re-commanded to hold the home pose."""
        if self._state_id is None:
            raise RuntimeError("Scene.restore_state called before reset/save_state")
        pybullet.restoreState(self._state_id, physicsClientId=self.client)
        # saveState keeps joint positions and velocities, not motor targets.
        self.command_arm(self.robot.home_joints)
        self.command_fingers(self.robot.gripper.open_width_m)

    # -- robot -----------------------------------------------------------------------------------
    def arm_joints(self) -> np.ndarray:
        states = pybullet.getJointStates(self.robot_id, self.robot_indices.arm_joints, physicsClientId=self.client)
        return np.array([s[0] for s in states])

    def set_arm_joints(self, joints: Sequence[float]) -> None:
        """Teleport the arm (resetJointState) and command its motors to hold there."""
        for joint, angle in zip(self.robot_indices.arm_joints, joints):
            pybullet.resetJointState(self.robot_id, joint, float(angle), physicsClientId=self.client)
        self.command_arm(joints)

    def finger_width(self) -> float:
        """Current distance between the fingers, metres (each finger joint is half of it)."""
        states = pybullet.getJointStates(self.robot_id, self.robot_indices.finger_joints, physicsClientId=self.client)
        return float(sum(state[0] for state in states))

    def set_finger_width(self, width_m: float) -> None:
        for joint in self.robot_indices.finger_joints:
            pybullet.resetJointState(self.robot_id, joint, width_m / 2.0, physicsClientId=self.client)
        self.command_fingers(width_m)

    def command_arm(self, joints: Sequence[float], velocities: Sequence[float] | None = None) -> None:
        """Position-control the arm to ``joints``; ``velocities`` (rad/s), when given, are the motors'
        target velocities along a moving trajectory (PyBullet's default target is rest)."""
        gain = self.config.execution.arm_position_gain
        moving = {} if velocities is None else {"targetVelocities": [float(v) for v in velocities]}
        pybullet.setJointMotorControlArray(
            self.robot_id,
            self.robot_indices.arm_joints,
            pybullet.POSITION_CONTROL,
            targetPositions=[float(j) for j in joints],
            forces=self._arm_max_forces,
            positionGains=[gain] * len(self.robot_indices.arm_joints),
            physicsClientId=self.client,
            **moving,
        )

    def command_fingers(self, width_m: float, force_n: float | None = None) -> None:
        force = self.config.execution.gripper_force_n if force_n is None else force_n
        command_fingers(self.client, self.robot_id, self.robot_indices.finger_joints, width_m, force)

    def grasptarget_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """World position and xyzw quaternion of ``panda_grasptarget`` from forward kinematics."""
        state = pybullet.getLinkState(
            self.robot_id, self.robot_indices.grasp_target_link, computeForwardKinematics=True, physicsClientId=self.client
        )
        return np.array(state[4]), np.array(state[5])

    def render(self, camera: CameraData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8, depth buffer (H, W) float in [0, 1], body-id image (H, W) int (-1 = none)."""
        _, _, rgba, depth, segmentation = pybullet.getCameraImage(
            camera.width_px,
            camera.height_px,
            viewMatrix=camera.view_matrix.tolist(),
            projectionMatrix=camera.projection_matrix.tolist(),
            renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_SEGMENTATION_MASK_OBJECT_AND_LINKINDEX,
            physicsClientId=self.client,
        )
        shape = (camera.height_px, camera.width_px)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(*shape, 4)[..., :3].copy()
        depth_buffer = np.asarray(depth, dtype=np.float64).reshape(shape)
        segmentation = np.asarray(segmentation, dtype=np.int64).reshape(shape)
        body_ids = np.where(segmentation >= 0, segmentation & BODY_ID_BITS, BACKGROUND)
        return rgb, depth_buffer, body_ids

    # -- objects ---------------------------------------------------------------------------------
    def object_link_pose(self, body_id: int) -> tuple[np.ndarray, np.ndarray]:
        """World pose (position, xyzw quaternion) of a body's URDF link frame.

        ``getBasePositionAndOrientation`` reports the centre-of-mass frame; YCB link frames sit at
        the bottom centre, so the inertial offset is undone here.
        """
        com_position, com_quat = pybullet.getBasePositionAndOrientation(body_id, physicsClientId=self.client)
        info = pybullet.getDynamicsInfo(body_id, -1, physicsClientId=self.client)
        inverse_position, inverse_quat = pybullet.invertTransform(info[3], info[4])
        position, quat = pybullet.multiplyTransforms(com_position, com_quat, inverse_position, inverse_quat)
        return np.array(position), np.array(quat)

    def centre_of_mass(self, body_id: int) -> tuple[np.ndarray, np.ndarray]:
        position, quat = pybullet.getBasePositionAndOrientation(body_id, physicsClientId=self.client)
        return np.array(position), np.array(quat)

    def _load_on_table(self, spec: ObjectSpec, x: float, y: float, yaw: float, resting: np.ndarray | None = None) -> int:
        """Load ``spec`` turned by ``resting`` (3, 3) onto its resting pose, then by ``yaw`` about the vertical."""
        quat = pybullet.getQuaternionFromEuler((0.0, 0.0, yaw))
        if resting is not None:
            quat = (Rotation.from_quat(quat) * Rotation.from_matrix(resting)).as_quat()
        try:
            body = load_urdf(self.client, spec.urdf_path, basePosition=(x, y, self.config.scene.table_top_z_m), baseOrientation=quat,
                             flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
        except pybullet.error as exc:
            raise ObjectLoadError(f"object '{spec.id}': PyBullet cannot load {spec.urdf_path}: {exc}") from exc
        self._move_on_table(body, x, y, quat)
        return body

    def _move_on_table(self, body: int, x: float, y: float, quat: Sequence[float]) -> None:
        """Put the body's footprint centre at (x, y) with its lowest point just above the table."""
        client = self.client
        com_position, _ = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
        pybullet.resetBasePositionAndOrientation(body, com_position, quat, physicsClientId=client)
        lower, upper = pybullet.getAABB(body, physicsClientId=client)
        shift = np.array(
            [
                x - (lower[0] + upper[0]) / 2.0,
                y - (lower[1] + upper[1]) / 2.0,
                self.config.scene.table_top_z_m + self.config.scene.drop_clearance_m - lower[2],
            ]
        )
        pybullet.resetBasePositionAndOrientation(body, np.asarray(com_position) + shift, quat, physicsClientId=client)

    def _place_distractors(self, pool: list[ObjectSpec], rng: np.random.Generator) -> None:
        scene_config = self.config.scene
        low, high = scene_config.distractor_count_range
        count = int(rng.integers(low, high + 1))
        picks = rng.choice(len(pool), size=count, replace=len(pool) < count)
        target_footprint = _footprint(self.client, self.target_id)
        centre = (target_footprint[:2] + target_footprint[2:]) / 2.0
        target_half_diagonal = float(np.linalg.norm(target_footprint[2:] - target_footprint[:2])) / 2.0
        placed = [target_footprint]
        for pick in picks:
            spec = pool[int(pick)]
            body = self._load_on_table(spec, float(centre[0]), float(centre[1]), 0.0)
            # Centres farther than this cannot keep the footprint gap within the limit.
            reach = target_half_diagonal + float(np.hypot(*spec.extents_m[:2])) / 2.0 + scene_config.distractor_max_distance_m
            for _ in range(scene_config.distractor_placement_tries):
                radius = reach * math.sqrt(rng.uniform())
                angle = rng.uniform(0.0, 2.0 * math.pi)
                yaw = rng.uniform(*scene_config.object_yaw_range_rad)
                self._move_on_table(
                    body,
                    float(centre[0] + radius * math.cos(angle)),
                    float(centre[1] + radius * math.sin(angle)),
                    pybullet.getQuaternionFromEuler((0.0, 0.0, yaw)),
                )
                footprint = _footprint(self.client, body)
                near_target = _footprint_gap(footprint, target_footprint) <= scene_config.distractor_max_distance_m
                if near_target and all(_footprint_gap(footprint, other) >= scene_config.distractor_min_gap_m for other in placed):
                    break
            else:
                raise ScenePlacementError(
                    f"trial {self.trial}: no free spot for distractor '{spec.id}' within "
                    f"{scene_config.distractor_max_distance_m} m of target '{self.target_spec.id}' "
                    f"after {scene_config.distractor_placement_tries} tries"
                )
            placed.append(footprint)
            self.distractor_ids.append(body)
            self.distractor_specs.append(spec)
