"""Grasp execution in PyBullet with the published sequence, and the judgement of each attempt.

Sequence: open the gripper, teleport (``resetJointState``) to a pre-grasp ``pregrasp_offset_m`` back
along the approach and hold it for ``settle_steps``, descend in a straight line through the
waypoints of ``motion.motion_waypoints`` under position control, close, lift ``lift_height_m``,
hold ``hold_steps``. Success: the object's centre of mass at least
``success_height_above_table_m`` above the table and both fingers still touching it.

Joints: the planner's joint path, the motion it checked, is executed as planned once PyBullet's
forward kinematics confirms it reaches every waypoint. Without a planned path (or when it fails
that check) the motion is solved here, and the attempt says so: PyBullet's
``calculateInverseKinematics`` (``ik_iterations``) with joint limits, ranges and rest poses, seeded
by the planner's joints, then Franka's ready pose, mid-limits and seeded random joints, every
solution checked against the limits and by forward kinematics; the batched ``PandaIK`` where
PyBullet fails. Those waypoints are each seeded by their neighbour and must stay on the grasp
solution's IK branch.

Labelling (opt-in, ``execute_grasp(..., shake=ShakeConfig)``): the object's motion while the fingers
close is recorded, and a held grasp is shaken by the arm after the hold (``shake_profile``) and
judged again; without ``shake`` nothing of this runs and an attempt is the study's.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Iterator, Sequence

import numpy as np
import pybullet
import torch
from scipy.spatial.transform import Rotation

from .config import Config, ExecutionConfig, MotionConfig, ShakeConfig
from .robot.ik import panda_ik
from .robot.motion import grasp_waypoint_index, motion_waypoints
from .attempt import AttemptDiagnostics, PlannerPrediction
from .robot.description import RobotDescription
from .world.scene import Scene, make_camera
from .seeds import ik_restart_seed
from .types import Grasp, GraspAttempt, GraspCandidates, InvalidGraspError, as_finite_vector

# Joint-limit slack for accepting an IK solution: PyBullet clamps to the limits within float noise.
LIMIT_SLACK_RAD = 1e-6


def _quat_angle_deg(quat_a: Sequence[float], quat_b: Sequence[float]) -> float:
    dot = abs(float(np.dot(quat_a, quat_b))) / (np.linalg.norm(quat_a) * np.linalg.norm(quat_b))
    return math.degrees(2.0 * math.acos(min(1.0, dot)))


def _movable_joints(scene: Scene) -> list[int]:
    """Indices of the robot's non-fixed joints, the order PyBullet's IK and Jacobian use."""
    client, robot = scene.client, scene.robot_id
    return [j for j in range(pybullet.getNumJoints(robot, physicsClientId=client))
            if pybullet.getJointInfo(robot, j, physicsClientId=client)[2] != pybullet.JOINT_FIXED]


class _ArmIK:
    """Validated IK for ``panda_grasptarget`` in one scene (teleports the arm; call before stepping)."""

    def __init__(self, scene: Scene, config: Config):
        self.scene = scene
        self.config = config
        client, robot = scene.client, scene.robot_id
        movable = _movable_joints(scene)
        info = [pybullet.getJointInfo(robot, j, physicsClientId=client) for j in movable]
        self.movable = movable
        self.lower = np.array([i[8] for i in info])
        self.upper = np.array([i[9] for i in info])
        self.arm_slots = [movable.index(j) for j in scene.robot_indices.arm_joints]
        self.rng = np.random.default_rng(ik_restart_seed(config, scene.trial or 0))
        self.source = "pybullet"

    def _full(self, arm_joints: np.ndarray) -> list[float]:
        full = (self.lower + self.upper) / 2.0
        full[self.arm_slots] = arm_joints
        return full.tolist()

    def check(self, arm_joints: np.ndarray, position: np.ndarray, quat: np.ndarray) -> tuple[bool, float, float]:
        """(valid, position error m, rotation error rad) of arm joints against a grasptarget pose."""
        lower, upper = self.lower[self.arm_slots], self.upper[self.arm_slots]
        inside = bool(np.all(arm_joints >= lower - LIMIT_SLACK_RAD) and np.all(arm_joints <= upper + LIMIT_SLACK_RAD))
        for joint, angle in zip(self.scene.robot_indices.arm_joints, arm_joints):
            pybullet.resetJointState(self.scene.robot_id, joint, float(angle), physicsClientId=self.scene.client)
        reached_position, reached_quat = self.scene.grasptarget_pose()
        position_error = float(np.linalg.norm(reached_position - position))
        rotation_error = math.radians(_quat_angle_deg(reached_quat, quat))
        robot = self.scene.robot
        valid = inside and position_error <= robot.ik_position_tolerance_m and rotation_error <= robot.ik_rotation_tolerance_rad
        return valid, position_error, rotation_error

    def _pybullet(self, position: np.ndarray, quat: np.ndarray, seed: np.ndarray) -> np.ndarray | None:
        client, robot = self.scene.client, self.scene.robot_id
        # PyBullet's IK iterates from the body's current joints, so the seed is set first.
        for joint, angle in zip(self.scene.robot_indices.arm_joints, seed):
            pybullet.resetJointState(robot, joint, float(angle), physicsClientId=client)
        solution = pybullet.calculateInverseKinematics(
            robot,
            self.scene.robot_indices.grasp_target_link,
            position.tolist(),
            quat.tolist(),
            lowerLimits=self.lower.tolist(),
            upperLimits=self.upper.tolist(),
            jointRanges=(self.upper - self.lower).tolist(),
            restPoses=self._full(seed),
            maxNumIterations=self.config.execution.ik_iterations,
            residualThreshold=1e-6,
            physicsClientId=client,
        )
        arm_joints = np.array(solution)[self.arm_slots]
        return arm_joints if self.check(arm_joints, position, quat)[0] else None

    def _panda_ik(self, position: np.ndarray, quat: np.ndarray, seed: np.ndarray) -> np.ndarray | None:
        rotation = np.array(pybullet.getMatrixFromQuaternion(quat.tolist())).reshape(3, 3)
        result = panda_ik(self.config).solve(
            torch.tensor(position, dtype=torch.float32).view(1, 3),
            torch.tensor(rotation, dtype=torch.float32).view(1, 3, 3),
            torch.tensor(seed, dtype=torch.float32).view(1, -1),
        )
        arm_joints = result.joints[0].double().numpy()
        return arm_joints if self.check(arm_joints, position, quat)[0] else None

    def _seeds(self, given: Sequence[np.ndarray]) -> Iterator[np.ndarray]:
        lower, upper = self.lower[self.arm_slots], self.upper[self.arm_slots]
        yield from (np.clip(seed, lower, upper) for seed in given)
        yield np.asarray(self.scene.robot.ik_reference_joints, dtype=float)
        yield (lower + upper) / 2.0
        for _ in range(self.config.execution.ik_random_restarts):
            yield self.rng.uniform(lower, upper)

    def grasp_solutions(self, position: np.ndarray, quat: np.ndarray, seeds: Sequence[np.ndarray]) -> Iterator[np.ndarray]:
        """Valid solutions for one pose, one per seed that converges (PyBullet, then PandaIK)."""
        for seed in self._seeds(seeds):
            arm_joints = self._pybullet(position, quat, seed)
            if arm_joints is not None:
                yield arm_joints
        arm_joints = self._panda_ik(position, quat, next(self._seeds(seeds)))
        if arm_joints is not None:
            self.source = "panda_ik"
            yield arm_joints

    def path(self, start_joints: np.ndarray, positions: Sequence[np.ndarray], quat: np.ndarray) -> list[np.ndarray] | None:
        """Joints for each position in order, each seeded by the previous one; None if IK switches branch."""
        solutions = [start_joints]
        for position in positions:
            arm_joints = self._pybullet(position, quat, solutions[-1])
            if arm_joints is None or np.abs(arm_joints - solutions[-1]).max() > self.config.motion.max_waypoint_joint_step_rad:
                return None
            solutions.append(arm_joints)
        return solutions[1:]

    def plan(self, waypoints: np.ndarray, quat: np.ndarray, seeds: Sequence[np.ndarray], grasp_index: int) -> np.ndarray | None:
        """(W, 7) joints through ``waypoints`` (the motion's positions, the grasp at ``grasp_index``)
        from the first grasp solution whose descent and lift both stay on one IK branch; the
        descent is solved backwards from the grasp."""
        for grasp_joints in self.grasp_solutions(waypoints[grasp_index], quat, seeds):
            backwards = self.path(grasp_joints, list(waypoints[:grasp_index])[::-1], quat)
            lift_joints = self.path(grasp_joints, list(waypoints[grasp_index + 1:]), quat) if backwards is not None else None
            if lift_joints is not None:
                return np.array([*backwards[::-1], grasp_joints, *lift_joints])
        return None

    def reproduces(self, joint_path: np.ndarray, waypoints: np.ndarray, quat: np.ndarray) -> bool:
        """Whether PyBullet's own kinematics puts the grasp target on every waypoint with these joints."""
        return all(self.check(joints, position, quat)[0] for joints, position in zip(joint_path, waypoints))


def _robot_contacts(scene: Scene, other_body: int) -> list[tuple]:
    """The last step's contacts between robot links other than the fixed base (which stands on the table) and ``other_body``."""
    contacts = pybullet.getContactPoints(bodyA=scene.robot_id, bodyB=other_body, physicsClientId=scene.client)
    return [contact for contact in contacts if contact[3] != -1]


def push_n(contacts: Sequence[tuple]) -> float:
    """Total normal force (N) of PyBullet contact points."""
    return float(sum(contact[9] for contact in contacts))


def _touching_links(scene: Scene, bodies: Sequence[int]) -> list[str]:
    """'robot link -> body' names of the robot's current contacts with ``bodies`` (why a collision was called)."""
    names = {scene.table_id: "table", scene.target_id: "target", **{body: f"distractor_{i}" for i, body in enumerate(scene.distractor_ids)}}
    touching = set()
    for body in bodies:
        for contact in _robot_contacts(scene, body):
            link = pybullet.getJointInfo(scene.robot_id, contact[3], physicsClientId=scene.client)[12].decode()
            touching.add(f"{link}->{names.get(body, body)}")
    return sorted(touching)


def fingers_touching(client: int, gripper_id: int, finger_links: Sequence[int], target_id: int) -> bool:
    """Whether every finger link of the gripper body touches the target (the last step's contacts)."""
    return all(
        pybullet.getContactPoints(bodyA=gripper_id, bodyB=target_id, linkIndexA=finger, physicsClientId=client)
        for finger in finger_links
    )


def object_held(client: int, gripper_id: int, finger_links: Sequence[int], target_id: int, config: Config) -> bool:
    """The study's success test: the target's centre of mass ``success_height_above_table_m`` above
    the table and both fingers touching it."""
    com = pybullet.getBasePositionAndOrientation(target_id, physicsClientId=client)[0]
    high_enough = com[2] - config.scene.table_top_z_m >= config.execution.success_height_above_table_m
    return high_enough and fingers_touching(client, gripper_id, finger_links, target_id)


def lift_failure(highest_rise_m: float, fingers_touching_after_close: bool, execution: ExecutionConfig) -> tuple[str, str]:
    """(reason, phase) of a grasp not held after the lift: "slipped" when the object rose at least
    ``lifted_detect_height_m`` before it fell, else "not_lifted"; in the lift when the fingers
    held it after closing, else already in the close."""
    phase = "lift" if fingers_touching_after_close else "close"
    return ("slipped" if highest_rise_m >= execution.lifted_detect_height_m else "not_lifted"), phase


def pose_change(before: tuple[Any, Any], after: tuple[Any, Any]) -> tuple[float, float]:
    """(distance m, rotation angle rad) between two poses (position, xyzw quaternion)."""
    return float(np.linalg.norm(np.subtract(after[0], before[0]))), math.radians(_quat_angle_deg(before[1], after[1]))


def relative_pose(frame: tuple[Any, Any], body: tuple[Any, Any]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The pose ``body`` (world) expressed in the frame ``frame`` (world pose)."""
    inverse_position, inverse_quat = pybullet.invertTransform(frame[0], frame[1])
    return pybullet.multiplyTransforms(inverse_position, inverse_quat, body[0], body[1])


@dataclass(frozen=True)
class ShakeProfile:
    """The shake of ``ShakeConfig`` sampled at every physics step.

    ``offsets`` and ``velocities`` (T, 6): displacement (m) and rotation vector (rad) of the grasp
    target from its lifted pose, in the lifted grasp frame (x, y, z, then about x, y, z), and
    their rates; ``segments``: (axis, first step, end step) of each shaken axis; ``angular_frequency``
    in rad/s."""

    offsets: np.ndarray
    velocities: np.ndarray
    segments: tuple[tuple[int, int, int], ...]
    angular_frequency: float
    time_step_s: float

    @property
    def steps(self) -> int:
        return int(self.offsets.shape[0])


def shake_profile(shake: ShakeConfig, time_step_s: float) -> ShakeProfile:
    """Every step of the shake: one window after another, ``A (1 - cos wt)`` on each of the window's
    axes for ``cycles`` whole cycles, ``A = peak / w^2``. A window is one axis with a non-zero peak,
    or, with ``shake.linear_with_angular``, the motion along and the rotation about one axis at once."""
    omega = 2.0 * math.pi * shake.frequency_hz
    peaks = (*shake.linear_peak_acceleration_m_s2, *shake.angular_peak_acceleration_rad_s2)
    windows = [(axis, axis + 3) for axis in range(3)] if shake.linear_with_angular else [(axis,) for axis in range(6)]
    windows = [tuple(axis for axis in window if peaks[axis] > 0.0) for window in windows]
    windows = [window for window in windows if window]
    steps_per_window = max(1, round(shake.cycles / shake.frequency_hz / time_step_s))
    # Samples at the end of each step, the whole cycles ending exactly at rest on the lifted pose.
    times = np.arange(1, steps_per_window + 1) * (shake.cycles / shake.frequency_hz / steps_per_window)
    offsets = np.zeros((steps_per_window * len(windows), 6))
    velocities = np.zeros_like(offsets)
    segments = []
    for index, window in enumerate(windows):
        start = index * steps_per_window
        for axis in window:
            amplitude = peaks[axis] / omega**2
            offsets[start : start + steps_per_window, axis] = amplitude * (1.0 - np.cos(omega * times))
            velocities[start : start + steps_per_window, axis] = amplitude * omega * np.sin(omega * times)
            segments.append((axis, start, start + steps_per_window))
    return ShakeProfile(offsets=offsets, velocities=velocities, segments=tuple(segments), angular_frequency=omega, time_step_s=time_step_s)


def frame_offsets(start: tuple[Any, Any], poses: Sequence[tuple[Any, Any]]) -> np.ndarray:
    """(T, 6) displacement and rotation vector of each pose from ``start``, in ``start``'s frame:
    the coordinates ``ShakeProfile.offsets`` are written in."""
    start_rotation = Rotation.from_quat(start[1])
    positions = np.array([pose[0] for pose in poses]).reshape(-1, 3)
    rotations = Rotation.from_quat(np.array([pose[1] for pose in poses]).reshape(-1, 4))
    linear = start_rotation.inv().apply(positions - np.asarray(start[0]))
    angular = (start_rotation.inv() * rotations).as_rotvec().reshape(-1, 3)
    return np.concatenate([linear.reshape(-1, 3), angular], axis=1)


def achieved_shake_peaks(profile: ShakeProfile, measured_offsets: np.ndarray) -> tuple[float, ...]:
    """Peak acceleration (m/s^2, then rad/s^2) the hand reached along and about each axis, 0 where
    not shaken: per segment, the measured offset is fitted by ``c0 + c1 cos wt + c2 sin wt`` and
    the peak is ``w^2 |(c1, c2)|``, which ignores the controller's phase lag and the jitter a
    finite difference of contacts would add."""
    peaks = [0.0] * 6
    for axis, start, end in profile.segments:
        times = np.arange(1, end - start + 1) * profile.time_step_s
        omega = profile.angular_frequency
        basis = np.stack([np.ones_like(times), np.cos(omega * times), np.sin(omega * times)], axis=1)
        coefficients = np.linalg.lstsq(basis, measured_offsets[start:end, axis], rcond=None)[0]
        peaks[axis] = float(omega**2 * np.hypot(coefficients[1], coefficients[2]))
    return tuple(peaks)


def _step(scene: Scene, steps: int) -> None:
    for _ in range(steps):
        pybullet.stepSimulation(physicsClientId=scene.client)


def _track(scene: Scene, config: Config, joint_path: np.ndarray, after_each=None) -> float:
    """Command each waypoint of ``joint_path`` in turn for ``steps_per_waypoint`` steps; the largest
    deviation (rad) of the arm's joints from a waypoint when its steps end. ``after_each`` may stop
    the motion early by returning True."""
    deviation = 0.0
    for joints in joint_path:
        scene.command_arm(joints)
        _step(scene, config.execution.steps_per_waypoint)
        deviation = max(deviation, float(np.abs(scene.arm_joints() - joints).max()))
        if after_each is not None and after_each():
            break
    return deviation


def execute_grasp(scene: Scene, config: Config, grasp: Grasp, record_frames: bool = False, shake: ShakeConfig | None = None) -> GraspAttempt:
    """Execute one grasp from the scene's current state and judge it.

    The gripper opens fully whatever ``grasp.width_m`` (published sequence). ``grasp.joint_path``,
    the planner's joints at every waypoint of ``motion.motion_waypoints``, is executed as given
    once PyBullet's kinematics confirms it reaches the waypoints. Without it, or when it does not,
    the motion is solved with PyBullet IK seeded by ``grasp.ik_solution`` (``diagnostics.ik_source``
    says which was executed, ``diagnostics.ik_fallback`` why the plan was not). ``record_frames``
    puts RGB images at contact and after the lift (or when the attempt failed) in the attempt's
    ``frames``. A grasp built by hand comes from ``Grasp.from_pose``.

    With ``shake`` (labelling), the diagnostics also hold ``object_motion_during_closing_linear`` (m)
    and ``_angular`` (rad), the object's world motion from just before the close to its end (the
    arm holds still); a grasp held after the hold is shaken by the arm (``_shake_arm``), and
    ``object_motion_during_shaking_linear``/``_angular`` give the object's motion in the hand's
    frame over the shake and ``shake_achieved_peak_accelerations`` what the hand reached. It
    succeeds if it is still held after the shake, else fails as "slipped" at "shake".

    Returns a ``GraspAttempt`` whose ``failure_reason`` is None, "unreachable", "collision",
    "slipped" or "not_lifted", and whose ``diagnostics.failed_at`` says in which phase ("plan",
    "pregrasp", "descent", "close", "lift", "shake").
    """
    execution = config.execution
    quat, waypoints, joint_path = checked_grasp(grasp, config.motion, scene.robot)
    width_m = grasp.width_m
    grasp_index = grasp_waypoint_index(config.motion)
    client, target = scene.client, scene.target_id
    outcome = _AttemptOutcome(scene, config, record_frames)
    diagnostics, finish, rest_com = outcome.diagnostics, outcome.finish, outcome.rest_com
    set_finger_friction(client, scene.robot_id, scene.robot_indices.finger_joints, execution)

    # Every joint is known before stepping: IK and checks teleport the arm, harmless while time stands still.
    start_joints = scene.arm_joints()
    joint_path = _path_to_execute(scene, config, waypoints, quat, joint_path, grasp.ik_solution, diagnostics)
    if joint_path is None:
        scene.set_arm_joints(start_joints)
        return finish(False, "unreachable", "plan")

    scene.set_finger_width(scene.robot.open_width_m)
    scene.set_arm_joints(joint_path[0])
    pybullet.performCollisionDetection(physicsClientId=client)
    if any(_robot_contacts(scene, body) for body in (scene.table_id, target, *scene.distractor_ids)):
        return finish(False, "collision", "pregrasp")
    _step(scene, execution.settle_steps)

    def descent_blocked() -> bool:
        knocked = np.linalg.norm(scene.centre_of_mass(target)[0] - rest_com) > execution.knock_tolerance_m
        return knocked or push_n(_robot_contacts(scene, scene.table_id)) > execution.table_contact_max_force_n

    diagnostics.descent_tracking_error_rad = _track(scene, config, joint_path[1 : grasp_index + 1], descent_blocked)
    if descent_blocked():
        return finish(False, "collision", "descent")

    before_close = scene.centre_of_mass(target)
    _close_fingers(scene, execution, width_m, diagnostics)
    if shake is not None:
        closing = pose_change(before_close, scene.centre_of_mass(target))
        diagnostics.object_motion_during_closing_linear, diagnostics.object_motion_during_closing_angular = closing
    outcome.record_frame("contact")

    highest_rise = [0.0]

    def note_rise() -> bool:
        highest_rise[0] = max(highest_rise[0], float(scene.centre_of_mass(target)[0][2] - rest_com[2]))
        return False

    diagnostics.lift_tracking_error_rad = _track(scene, config, joint_path[grasp_index + 1 :], note_rise)
    _step(scene, execution.hold_steps)

    fingers = scene.robot_indices.finger_joints
    if not object_held(client, scene.robot_id, fingers, target, config):
        return finish(False, *lift_failure(highest_rise[0], diagnostics.fingers_touching_after_close, execution))
    if shake is None:
        return finish(True, None, None)
    _shake_arm(scene, config, shake, joint_path[-1], diagnostics)
    if object_held(client, scene.robot_id, fingers, target, config):
        return finish(True, None, None)
    return finish(False, "slipped", "shake")


def _shake_arm(scene: Scene, config: Config, shake: ShakeConfig, lifted_joints: np.ndarray, diagnostics: AttemptDiagnostics) -> None:
    """Shake the grasp target around its lifted pose with the arm and record the object's motion
    relative to the hand over the shake (``diagnostics``).

    The Cartesian offsets of ``shake_profile`` are small (centimetres, degrees), so one Jacobian of
    ``panda_grasptarget`` at the lifted joints maps them to joint offsets (damped least squares):
    each step commands the lifted joints plus the mapped offset as position target and the mapped
    offset rate as the motors' target velocity, which makes the position-controlled joints follow
    the sinusoid with little lag. What the hand reached is measured, not assumed: its offsets at
    every step, fitted per axis (``achieved_shake_peaks``), go to ``shake_achieved_peak_accelerations``.
    """
    client, robot = scene.client, scene.robot_id
    profile = shake_profile(shake, config.scene.time_step_s)
    movable = _movable_joints(scene)
    positions = [state[0] for state in pybullet.getJointStates(robot, movable, physicsClientId=client)]
    rest = [0.0] * len(movable)
    linear, angular = pybullet.calculateJacobian(
        robot, scene.robot_indices.grasp_target_link, [0.0, 0.0, 0.0], positions, rest, rest, physicsClientId=client
    )
    arm_columns = [movable.index(joint) for joint in scene.robot_indices.arm_joints]
    jacobian = np.vstack([np.asarray(linear)[:, arm_columns], np.asarray(angular)[:, arm_columns]])  # (6, 7), world
    start = scene.grasptarget_pose()
    rotation = Rotation.from_quat(start[1]).as_matrix()
    hand_to_world = np.kron(np.eye(2), rotation)  # twist in the lifted grasp frame -> world
    # Damping of the planner's damped-least-squares steps: bounded joint offsets near a singular wrist.
    damping = config.ik.damping
    joint_offsets = jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + damping**2 * np.eye(6), hand_to_world)  # (7, 6)
    object_start = relative_pose(start, scene.centre_of_mass(scene.target_id))
    hand_poses = []
    for offset, rate in zip(profile.offsets, profile.velocities):
        scene.command_arm(lifted_joints + joint_offsets @ offset, joint_offsets @ rate)
        _step(scene, 1)
        hand_poses.append(scene.grasptarget_pose())
    end = scene.grasptarget_pose()
    shaking = pose_change(object_start, relative_pose(end, scene.centre_of_mass(scene.target_id)))
    diagnostics.object_motion_during_shaking_linear, diagnostics.object_motion_during_shaking_angular = shaking
    diagnostics.shake_achieved_peak_accelerations = achieved_shake_peaks(profile, frame_offsets(start, hand_poses))


def checked_grasp(grasp: Grasp, motion: MotionConfig, robot: RobotDescription) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(unit quaternion, (W, 3) motion waypoints, (W, 7) planned joints or None) of a grasp, or
    ``InvalidGraspError`` naming what is malformed."""
    if grasp.frame != "world":
        raise InvalidGraspError(f"the grasp is in the {grasp.frame} frame: execution runs world-frame grasps")
    position = as_finite_vector(grasp.position, 3, "position")
    quat = as_finite_vector(grasp.quat_xyzw, 4, "quat_xyzw")
    approach = as_finite_vector(grasp.approach, 3, "approach")
    if np.linalg.norm(quat) < 1e-9 or np.linalg.norm(approach) < 1e-9:
        raise InvalidGraspError("quat_xyzw and approach must be non-zero")
    if not 0.0 <= grasp.width_m <= robot.open_width_m:
        raise InvalidGraspError(f"width_m {grasp.width_m} is outside the gripper's 0..{robot.open_width_m} m")
    quat = quat / np.linalg.norm(quat)
    approach = approach / np.linalg.norm(approach)
    waypoints = motion_waypoints(torch.tensor(position).view(1, 3), torch.tensor(approach).view(1, 3), motion)[0].double().numpy()
    joint_path = grasp.joint_path
    if joint_path is not None:
        joint_path = joint_path.detach().cpu().double().numpy()
        if joint_path.shape != (len(waypoints), 7) or not np.all(np.isfinite(joint_path)):
            raise InvalidGraspError(f"joint_path must be ({len(waypoints)}, 7) finite joints, got shape {joint_path.shape}")
    return quat, waypoints, joint_path


class _AttemptOutcome:
    """Judges an attempt when it ends and keeps its diagnostics: where the object and the distractors
    ended, which links touched what in a collision, and frames when asked for."""

    def __init__(self, scene: Scene, config: Config, record_frames: bool):
        self.scene, self.table_top = scene, config.scene.table_top_z_m
        self.rest_com, self.rest_quat = scene.centre_of_mass(scene.target_id)
        self.distractor_start = [scene.centre_of_mass(body)[0] for body in scene.distractor_ids]
        self.diagnostics = AttemptDiagnostics()
        self.frames: dict[str, np.ndarray] = {}
        self.camera = None
        if record_frames:
            eye = self.rest_com + np.asarray(config.execution.frame_camera_offset_m)
            self.camera = make_camera("frames", config, eye, self.rest_com, (0.0, 0.0, 1.0))

    def record_frame(self, moment: str) -> None:
        if self.camera is not None:
            self.frames[moment] = self.scene.render(self.camera)[0]

    def finish(self, success: bool, reason: str | None, phase: str | None) -> GraspAttempt:
        scene, diagnostics = self.scene, self.diagnostics
        com, com_quat = scene.centre_of_mass(scene.target_id)
        moved = [float(np.linalg.norm(scene.centre_of_mass(body)[0] - start)) for body, start in zip(scene.distractor_ids, self.distractor_start)]
        diagnostics.failed_at = phase
        diagnostics.distractors_max_displacement_m = max(moved, default=0.0)
        diagnostics.object_height_above_table_m = float(com[2] - self.table_top)
        if reason == "collision":
            diagnostics.collision_links = _touching_links(scene, [scene.table_id, scene.target_id, *scene.distractor_ids])
        self.record_frame("lifted" if success else f"failed_{phase}")
        return GraspAttempt(
            success=success,
            failure_reason=reason,
            orientation_change_deg=_quat_angle_deg(com_quat, self.rest_quat),
            diagnostics=diagnostics,
            frames=self.frames,
        )


def _close_fingers(scene: Scene, execution: ExecutionConfig, planned_width_m: float, diagnostics: AttemptDiagnostics) -> None:
    scene.command_fingers(0.0)
    _step(scene, execution.close_steps)
    diagnostics.fingers_touching_after_close = fingers_touching(scene.client, scene.robot_id, scene.robot_indices.finger_joints, scene.target_id)
    # Against the planned contact width this tells a squeeze from fingers stopped by a wider
    # collision shape than the cloud showed.
    diagnostics.finger_width_after_close_m = scene.finger_width()
    diagnostics.planned_width_m = float(planned_width_m)


def set_finger_friction(client: int, gripper_id: int, finger_links: Sequence[int], execution: ExecutionConfig) -> None:
    """The study's finger-pad friction on the gripper's finger links."""
    for finger in finger_links:
        pybullet.changeDynamics(
            gripper_id,
            finger,
            lateralFriction=execution.finger_lateral_friction,
            spinningFriction=execution.finger_spinning_friction,
            physicsClientId=client,
        )


def _path_to_execute(
    scene: Scene, config: Config, waypoints: np.ndarray, quat: np.ndarray, joint_path: np.ndarray | None, ik_seed: Any, diagnostics: AttemptDiagnostics
) -> np.ndarray | None:
    """The planner's joint path if PyBullet's kinematics confirms it reaches the waypoints, else
    PyBullet IK's (None if it finds none); ``diagnostics`` records which and why."""
    ik = _ArmIK(scene, config)
    if joint_path is not None and ik.reproduces(joint_path, waypoints, quat):
        diagnostics.ik_source = "planner"
        return joint_path
    diagnostics.ik_fallback = "no planned path" if joint_path is None else "planned joints miss a waypoint in PyBullet"
    seeds = [as_finite_vector(ik_seed, 7, "ik_seed")] if ik_seed is not None else []
    path = ik.plan(waypoints, quat, seeds, grasp_waypoint_index(config.motion))
    diagnostics.ik_source = ik.source
    return path


def execute_ranked(
    scene: Scene, config: Config, ranked: GraspCandidates, record_frames: bool = False,
    executed: dict[int, GraspAttempt] | None = None,
) -> list[GraspAttempt]:
    """Execute the first ``max_attempts`` grasps of a ranked batch, best first, each from the
    restored settled scene; stops at the first success.

    Each attempt's ``diagnostics`` name its place in the batch (``candidate_index``) and what the
    planner predicted for it (``predicted``: reachable, collision_free, clearance_m).
    ``executed`` maps candidate ids to attempts already made from this settled scene (another
    method's ranking of the same candidates): such a grasp is not simulated again, since from the
    same restored state it would do the same; new attempts are added to it.
    """
    attempts: list[GraspAttempt] = []
    for index in range(min(config.execution.max_attempts, len(ranked))):
        grasp = ranked[index]
        known = executed.get(grasp.candidate_id) if executed is not None else None
        if known is not None:
            attempt = dataclasses.replace(known, diagnostics=dataclasses.replace(known.diagnostics))
        else:
            scene.restore_state()
            attempt = execute_grasp(scene, config, grasp, record_frames=record_frames)
            if executed is not None:
                executed[grasp.candidate_id] = attempt
        attempt.diagnostics.candidate_index = index
        # Planned candidates passed the motion and swept-hand checks; others only the grasp-pose IK.
        attempt.diagnostics.predicted = PlannerPrediction(reachable=True, collision_free=grasp.joint_path is not None, clearance_m=grasp.hand_clearance_m)
        attempts.append(attempt)
        if attempt.success:
            break
    return attempts
