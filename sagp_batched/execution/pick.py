"""Grasp execution in PyBullet with the published sequence, and the judgement of each attempt.

Sequence: open the gripper, teleport (``resetJointState``) to a pre-grasp ``pregrasp_offset_m`` back
along the approach and hold it for ``settle_steps``, descend in a straight line through the
waypoints of ``motion.motion_waypoints`` under position control, close, lift ``lift_height_m``,
hold ``hold_steps``. Success: the object's centre of mass at least
``success_height_above_table_m`` above the table and both fingers still touching it.

Joints: the planner's joint path, the motion it checked, once PyBullet's forward kinematics
confirms it reaches every waypoint, else a motion solved by PyBullet's IK (``execution_ik``); the
attempt says which.

Labelling (opt-in, ``execute_grasp(..., shake=ShakeConfig)``): the object's motion while the fingers
close is recorded, and a held grasp is shaken by the arm after the hold (``shake.shake_profile``) and
judged again; without ``shake`` nothing of this runs and an attempt is the study's.
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np
import pybullet
import torch
from scipy.spatial.transform import Rotation

from ..attempt import AttemptDiagnostics, PlannerPrediction
from ..config import Config, ExecutionConfig, MotionConfig, ShakeConfig
from ..grasps import Grasp, GraspCandidates, InvalidGraspError, as_finite_vector
from ..robot.description import RobotDescription, robot_of
from ..robot.motion import grasp_waypoint_index, motion_waypoints
from ..types import GraspAttempt
from ..world.scene import Scene, make_camera
from .arm_joints import path_to_execute
from .contact_model import EnginePad, engine_pad, pybullet_pad_dynamics, reduced_mass_kg
from .held import lift_failure, object_held
from .poses import pose_change, quat_angle_deg, relative_pose
from .shake import achieved_shake_peaks, frame_offsets, shake_profile


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


def _held(scene: Scene, config: Config) -> bool:
    """The study's success test (``held.object_held``) on the scene's target."""
    client, target, fingers = scene.client, scene.target_id, scene.robot_indices.finger_joints
    com = pybullet.getBasePositionAndOrientation(target, physicsClientId=client)[0]
    touching = fingers_touching(client, scene.robot_id, fingers, target)
    return object_held(touching, com[2] - config.scene.table_top_z_m, config.execution)


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
    robot_of(config).require_mounted_gripper("executing a grasp with the arm")
    quat, waypoints, joint_path = checked_grasp(grasp, config.motion, scene.robot)
    grasp_index = grasp_waypoint_index(config.motion)
    set_finger_friction(scene.client, scene.robot_id, scene.robot_indices.finger_joints, engine_pad(execution, robot_of(config)), scene.target_id)
    outcome = _AttemptOutcome(scene, config, record_frames)
    diagnostics, finish = outcome.diagnostics, outcome.finish

    # Every joint is known before stepping: IK and checks teleport the arm, harmless while time stands still.
    start_joints = scene.arm_joints()
    joint_path = path_to_execute(scene, config, waypoints, quat, joint_path, grasp.ik_solution, diagnostics)
    if joint_path is None:
        scene.set_arm_joints(start_joints)
        return finish(False, "unreachable", "plan")
    if _pregrasp_in_contact(scene, joint_path[0]):
        return finish(False, "collision", "pregrasp")
    _step(scene, execution.settle_steps)
    if _descent_blocked(scene, config, joint_path[1 : grasp_index + 1], outcome.rest_com, diagnostics):
        return finish(False, "collision", "descent")
    _close_fingers(scene, execution, grasp.width_m, diagnostics, record_motion=shake is not None)
    outcome.record_frame("contact")
    highest_rise = _lift_and_hold(scene, config, joint_path[grasp_index + 1 :], outcome.rest_com, diagnostics)

    if not _held(scene, config):
        return finish(False, *lift_failure(highest_rise, diagnostics.fingers_touching_after_close, execution))
    if shake is None:
        return finish(True, None, None)
    _shake_arm(scene, config, shake, joint_path[-1], diagnostics)
    if _held(scene, config):
        return finish(True, None, None)
    return finish(False, "slipped", "shake")


def _pregrasp_in_contact(scene: Scene, pregrasp_joints: np.ndarray) -> bool:
    """Open the gripper, teleport the arm to the pre-grasp and tell whether it touches the table,
    the target or a distractor there."""
    scene.set_finger_width(scene.robot.gripper.open_width_m)
    scene.set_arm_joints(pregrasp_joints)
    pybullet.performCollisionDetection(physicsClientId=scene.client)
    return any(_robot_contacts(scene, body) for body in (scene.table_id, scene.target_id, *scene.distractor_ids))


def _descent_blocked(scene: Scene, config: Config, descent_path: np.ndarray, rest_com: np.ndarray, diagnostics: AttemptDiagnostics) -> bool:
    """Track the descent to the grasp, stopped early once the hand knocks the object more than
    ``knock_tolerance_m`` off its rest or presses on the table harder than
    ``table_contact_max_force_n``; whether it was."""
    execution = config.execution

    def blocked() -> bool:
        knocked = np.linalg.norm(scene.centre_of_mass(scene.target_id)[0] - rest_com) > execution.knock_tolerance_m
        return knocked or push_n(_robot_contacts(scene, scene.table_id)) > execution.table_contact_max_force_n

    diagnostics.descent_tracking_error_rad = _track(scene, config, descent_path, blocked)
    return blocked()


def _lift_and_hold(scene: Scene, config: Config, lift_path: np.ndarray, rest_com: np.ndarray, diagnostics: AttemptDiagnostics) -> float:
    """Track the lift, then hold still ``hold_steps``; the highest the object's centre of mass rose
    above its rest (m) at the end of a lift waypoint, which tells a slip from a grasp that never lifted."""
    highest_rise = 0.0

    def note_rise() -> bool:
        nonlocal highest_rise
        highest_rise = max(highest_rise, float(scene.centre_of_mass(scene.target_id)[0][2] - rest_com[2]))
        return False

    diagnostics.lift_tracking_error_rad = _track(scene, config, lift_path, note_rise)
    _step(scene, config.execution.hold_steps)
    return highest_rise


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
    movable = list(scene.robot_indices.movable_joints)
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
    if not 0.0 <= grasp.width_m <= robot.gripper.open_width_m:
        raise InvalidGraspError(f"width_m {grasp.width_m} is outside the gripper's 0..{robot.gripper.open_width_m} m")
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
            orientation_change_deg=quat_angle_deg(com_quat, self.rest_quat),
            diagnostics=diagnostics,
            frames=self.frames,
        )


def _close_fingers(scene: Scene, execution: ExecutionConfig, planned_width_m: float, diagnostics: AttemptDiagnostics,
                   record_motion: bool) -> None:
    """Close the fingers for ``close_steps`` and record how they ended; with ``record_motion`` also
    the object's world motion over the close (the arm holds still)."""
    before_close = scene.centre_of_mass(scene.target_id)
    scene.command_fingers(0.0)
    _step(scene, execution.close_steps)
    diagnostics.fingers_touching_after_close = fingers_touching(scene.client, scene.robot_id, scene.robot_indices.finger_joints, scene.target_id)
    # Against the planned contact width this tells a squeeze from fingers stopped by a wider
    # collision shape than the cloud showed.
    diagnostics.finger_width_after_close_m = scene.finger_width()
    diagnostics.planned_width_m = float(planned_width_m)
    if record_motion:
        closing = pose_change(before_close, scene.centre_of_mass(scene.target_id))
        diagnostics.object_motion_during_closing_linear, diagnostics.object_motion_during_closing_angular = closing


def _finger_mass(client: int, body: int, link: int) -> float:
    """The mass a pad's contact pushes: the pad's link and the links between it and the base (a linkage's
    finger moves with its pad; a Panda finger is its own pad)."""
    mass = 0.0
    while link != -1:
        mass += pybullet.getDynamicsInfo(body, link, physicsClientId=client)[0]
        link = pybullet.getJointInfo(body, link, physicsClientId=client)[16]
    return mass


def set_finger_friction(client: int, gripper_id: int, pad_links: Sequence[int], pad: EnginePad, object_id: int) -> None:
    """The contact model's pads (``contact_model.pybullet_pad_dynamics``) on the gripper's pad links, for
    their contacts with ``object_id``: its friction and mass enter what the pads are given."""
    info = pybullet.getDynamicsInfo(object_id, -1, physicsClientId=client)
    object_mass, object_surface = info[0], (info[1], info[7], info[6])  # lateral, spinning, rolling
    for link in pad_links:
        dynamics = pybullet_pad_dynamics(pad, object_surface, reduced_mass_kg(_finger_mass(client, gripper_id, link), object_mass))
        pybullet.changeDynamics(gripper_id, link, physicsClientId=client, **dynamics)


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
