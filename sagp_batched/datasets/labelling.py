"""Grasp labels from simulation, in two modes, each ending with a shake (ACRONYM / GraspGen style).

``arm``: the study's execution (``execution.execute_grasp``) with its opt-in shake: the Panda runs
the planned joint path, closes, lifts, holds, then the arm shakes the hand.

``hand``: ACRONYM's convention, far cheaper: the Panda hand alone (the robot URDF's hand subtree,
collision meshes only, fingers as prismatic joints), carried by a fixed constraint. It starts at
the pre-grasp (``pregrasp_offset_m`` back along the approach), moves along the approach to the
grasp, closes with the study's grip force and finger friction, lifts ``lift_height_m``, holds and
shakes (``ShakeConfig``); the object rests on the study's table at the trial's settled pose.

Hand mode takes a batch and labels each grasp in a PyBullet world of its own, built from nothing
for that grasp, so a label cannot depend on which or how many grasps are labelled with it. Grasps
do not share a world: PyBullet's solver stops on the residual of the whole world, sorts
constraints and contact manifolds by island with an unstable quicksort (the several manifolds
between a finger and a V-HACD object tie, so their order depends on the other pairs' bodies), and
drops stale broadphase pairs a few per step across the whole world. Hands at the same pose beside
others then differ after one step, and outcomes after a lift and a shake.

Both modes judge with execution's own test (``execution.object_held``): the object's centre of
mass ``success_height_above_table_m`` above the table and both fingers touching it, after the
hold and again after the shake. Object motion is recorded as ACRONYM records it: during the close
in the world (the hand holds still), during the shake in the hand's (grasp target's) frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import pybullet

from ..config import Config, ShakeConfig
from ..execution.pick import checked_grasp, execute_grasp, fingers_touching, lift_failure, object_held, push_n, set_finger_friction
from ..execution.poses import pose_change, relative_pose
from ..execution.shake import achieved_shake_peaks, frame_offsets, shake_profile
from ..grasps import Grasp, GraspCandidates, GraspPoses, InvalidGraspError
from ..robot.description import robot_of
from ..robot.hand import hand_to_grasp_target_m
from ..robot.motion import grasp_waypoint_index
from ..types import GraspAttempt
from ..world.objects import ObjectLoadError, ObjectSpec
from ..world.scene import Scene, command_fingers, configure_physics, create_table
from .collision_urdf import collision_only_urdf, floating_hand_urdf


@dataclass(frozen=True)
class GraspLabel:
    """What simulation made of one grasp.

    ``held``: still held after the shake. ``failure_reason``/``failed_at``: execution's reasons
    ("unreachable" is never a label: an arm that cannot reach a grasp has not tested it) and
    phases ("pregrasp", "descent", "close", "lift", "shake"). Object motion (m, rad), None where
    the grasp failed before that phase: ``closing`` in the world from just before the close to its
    end, ``shaking`` relative to the hand from the shake's start to its end.
    ``shake_achieved_peak_accelerations``: what the hand reached along and about its x, y, z
    (m/s^2, rad/s^2; ``shake.achieved_shake_peaks``), None where it was not shaken.
    """

    mode: str
    held: bool
    failure_reason: str | None
    failed_at: str | None
    object_motion_during_closing_linear: float | None = None
    object_motion_during_closing_angular: float | None = None
    object_motion_during_shaking_linear: float | None = None
    object_motion_during_shaking_angular: float | None = None
    shake_achieved_peak_accelerations: tuple[float, ...] | None = None


def _arm_label(attempt: GraspAttempt) -> GraspLabel | None:
    """The label of an attempt ``execute_grasp`` ran with a shake; None for an unreachable grasp (untested)."""
    if attempt.failure_reason == "unreachable":
        return None
    diagnostics = attempt.diagnostics
    return GraspLabel(
        mode="arm",
        held=attempt.success,
        failure_reason=attempt.failure_reason,
        failed_at=diagnostics.failed_at,
        object_motion_during_closing_linear=diagnostics.object_motion_during_closing_linear,
        object_motion_during_closing_angular=diagnostics.object_motion_during_closing_angular,
        object_motion_during_shaking_linear=diagnostics.object_motion_during_shaking_linear,
        object_motion_during_shaking_angular=diagnostics.object_motion_during_shaking_angular,
        shake_achieved_peak_accelerations=diagnostics.shake_achieved_peak_accelerations,
    )


@dataclass(frozen=True)
class ObjectPlacement:
    """An object resting on the study's table: its spec and the world pose of its centre-of-mass
    frame (what ``getBasePositionAndOrientation`` reports)."""

    spec: ObjectSpec
    com_position_world: tuple[float, float, float]
    com_quat_xyzw: tuple[float, float, float, float]

    @classmethod
    def from_scene(cls, scene: Scene) -> "ObjectPlacement":
        """The target of a reset ``Scene`` where it settled (the scene is restored to its saved state first)."""
        if scene.target_spec is None:
            raise ValueError("ObjectPlacement.from_scene needs a Scene after reset")
        scene.restore_state()
        position, quat = scene.centre_of_mass(scene.target_id)
        return cls(scene.target_spec, tuple(float(v) for v in position), tuple(float(v) for v in quat))


# -- the floating hand ------------------------------------------------------------------------------
def _half_cosine(fraction: float) -> float:
    """Progress along a straight move that starts and stops at rest."""
    return 0.5 * (1.0 - math.cos(math.pi * fraction))


class _HandWorld:
    """A PyBullet client in which one floating hand at a time labels one grasp: every grasp gets a
    world built from nothing (``resetSimulation``), the study's table, the object at its settled
    pose and the hand at the grasp's pre-grasp, so no grasp's label depends on any other's."""

    def __init__(self, config: Config):
        self.config = config
        self.client = pybullet.connect(pybullet.DIRECT)
        self.robot = robot_of(config)
        self.hand_urdf = str(floating_hand_urdf(self.robot, config.labelling.hand_urdf_cache_dir))
        self.grasp_offset_m = hand_to_grasp_target_m(self.robot)
        self._object_urdfs: dict[str, str] = {}

    def _object_urdf(self, spec: ObjectSpec) -> str:
        key = str(spec.urdf_path)
        if key not in self._object_urdfs:
            self._object_urdfs[key] = str(collision_only_urdf(spec.urdf_path, self.config.labelling.hand_urdf_cache_dir))
        return self._object_urdfs[key]

    def close(self) -> None:
        if pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)

    def __enter__(self) -> "_HandWorld":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- building ------------------------------------------------------------------------------------
    def _build(self, placement: ObjectPlacement, pregrasp: np.ndarray, quat: np.ndarray) -> None:
        client, config = self.client, self.config
        pybullet.resetSimulation(physicsClientId=client)
        configure_physics(client, config.scene)
        pybullet.setPhysicsEngineParameter(erp=config.labelling.hand_constraint_erp, physicsClientId=client)
        self.table = create_table(client, config.scene)
        try:
            self.target = pybullet.loadURDF(self._object_urdf(placement.spec), flags=pybullet.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
        except pybullet.error as exc:
            raise ObjectLoadError(f"object '{placement.spec.id}': PyBullet cannot load {placement.spec.urdf_path}: {exc}") from exc
        pybullet.resetBasePositionAndOrientation(self.target, placement.com_position_world, placement.com_quat_xyzw, physicsClientId=client)
        self.rest_com = np.array(placement.com_position_world)
        self.hand = pybullet.loadURDF(self.hand_urdf, physicsClientId=client)
        names = {pybullet.getJointInfo(self.hand, j, physicsClientId=client)[1].decode(): j for j in range(pybullet.getNumJoints(self.hand, physicsClientId=client))}
        self.finger_joints = tuple(names[name] for name in self.robot.finger_joints)
        # The constraint holds the grasp target; PyBullet pins a base by its inertial frame.
        inertial = pybullet.getDynamicsInfo(self.hand, -1, physicsClientId=client)[3:5]
        self.target_in_base = pybullet.multiplyTransforms(*pybullet.invertTransform(*inertial), [0.0, 0.0, self.grasp_offset_m], [0.0, 0.0, 0.0, 1.0])
        base = pybullet.multiplyTransforms(list(pregrasp), list(quat), *pybullet.invertTransform(*self.target_in_base))
        pybullet.resetBasePositionAndOrientation(self.hand, *base, physicsClientId=client)
        for joint in self.finger_joints:
            pybullet.resetJointState(self.hand, joint, self.robot.open_width_m / 2.0, physicsClientId=client)
        self._command_fingers(self.robot.open_width_m)
        set_finger_friction(client, self.hand, self.finger_joints, config.execution)
        self.constraint = pybullet.createConstraint(
            self.hand, -1, -1, -1, pybullet.JOINT_FIXED, [0.0, 0.0, 0.0],
            parentFramePosition=self.target_in_base[0], childFramePosition=list(pregrasp),
            parentFrameOrientation=self.target_in_base[1], childFrameOrientation=list(quat),
            physicsClientId=client,
        )
        self.quat = tuple(quat)
        self._move(pregrasp)

    # -- helpers -------------------------------------------------------------------------------------
    def _command_fingers(self, width_m: float) -> None:
        command_fingers(self.client, self.hand, self.finger_joints, width_m, self.config.execution.gripper_force_n)

    def _step(self, steps: int) -> None:
        for _ in range(steps):
            pybullet.stepSimulation(physicsClientId=self.client)

    def _move(self, position: Sequence[float], quat: Sequence[float] | None = None) -> None:
        pybullet.changeConstraint(
            self.constraint, jointChildPivot=list(position), jointChildFrameOrientation=list(quat or self.quat),
            maxForce=self.config.labelling.hand_constraint_max_force_n, physicsClientId=self.client,
        )

    def _target_pose(self) -> tuple[Any, Any]:
        """World pose of the object's centre-of-mass frame."""
        return pybullet.getBasePositionAndOrientation(self.target, physicsClientId=self.client)

    def _hand_pose(self) -> tuple[Any, Any]:
        """World pose of the hand's grasp target."""
        base = pybullet.getBasePositionAndOrientation(self.hand, physicsClientId=self.client)
        return pybullet.multiplyTransforms(*base, *self.target_in_base)

    def _touching(self, body: int) -> list[tuple]:
        return pybullet.getContactPoints(bodyA=self.hand, bodyB=body, physicsClientId=self.client)

    def _held(self) -> bool:
        return object_held(self.client, self.hand, self.finger_joints, self.target, self.config)

    @staticmethod
    def _checkpoints(steps: int, count: int) -> set[int]:
        """Steps (1-based) after which a motion of ``steps`` is checked ``count`` times, evenly, the last at its end."""
        return {round(steps * (k + 1) / count) for k in range(count)}

    # -- the sequence --------------------------------------------------------------------------------
    def label(self, placement: ObjectPlacement, pregrasp: np.ndarray, grasp: np.ndarray, quat: np.ndarray) -> GraspLabel:
        """Approach, close, lift, hold, shake: the label of one grasp."""
        execution, labelling = self.config.execution, self.config.labelling
        self._build(placement, pregrasp, quat)
        motion: dict[str, Any] = {}

        def failed(reason: str, phase: str) -> GraspLabel:
            return GraspLabel(mode="hand", held=False, failure_reason=reason, failed_at=phase, **motion)

        pybullet.performCollisionDetection(physicsClientId=self.client)
        if self._touching(self.target) or self._touching(self.table):
            return failed("collision", "pregrasp")
        self._step(labelling.hand_settle_steps)

        # Checked as the study checks its descent: after each of its waypoints.
        checks = self._checkpoints(labelling.hand_approach_steps, self.config.motion.descent_waypoints)
        for step in range(1, labelling.hand_approach_steps + 1):
            self._move(pregrasp + (grasp - pregrasp) * _half_cosine(step / labelling.hand_approach_steps))
            self._step(1)
            if step in checks:
                knocked = np.linalg.norm(np.subtract(self._target_pose()[0], self.rest_com)) > execution.knock_tolerance_m
                if knocked or push_n(self._touching(self.table)) > execution.table_contact_max_force_n:
                    return failed("collision", "descent")

        before_close = self._target_pose()
        self._command_fingers(0.0)
        self._step(labelling.hand_close_steps)
        closing = pose_change(before_close, self._target_pose())
        motion["object_motion_during_closing_linear"], motion["object_motion_during_closing_angular"] = closing
        touching_after_close = fingers_touching(self.client, self.hand, self.finger_joints, self.target)

        checks = self._checkpoints(labelling.hand_lift_steps, self.config.motion.lift_waypoints)
        up = np.array([0.0, 0.0, self.config.motion.lift_height_m])
        highest_rise = 0.0
        for step in range(1, labelling.hand_lift_steps + 1):
            self._move(grasp + up * _half_cosine(step / labelling.hand_lift_steps))
            self._step(1)
            if step in checks:
                highest_rise = max(highest_rise, float(self._target_pose()[0][2] - self.rest_com[2]))
        self._step(labelling.hand_hold_steps)
        if not self._held():
            return failed(*lift_failure(highest_rise, touching_after_close, execution))

        motion.update(self._shake(labelling.shake))
        if self._held():
            return GraspLabel(mode="hand", held=True, failure_reason=None, failed_at=None, **motion)
        return failed("slipped", "shake")

    def _shake(self, shake: ShakeConfig) -> dict[str, Any]:
        """Follow ``shake_profile`` around the lifted pose, the constraint carrying the grasp target
        (so rotations turn about it); the object's motion relative to the hand over the shake and
        the peaks the hand reached (``achieved_shake_peaks`` of its pose at every step)."""
        profile = shake_profile(shake, self.config.scene.time_step_s)
        start = self._hand_pose()
        object_start = relative_pose(start, self._target_pose())
        hand_poses = []
        for offset in profile.offsets:
            position, _ = pybullet.multiplyTransforms(*start, offset[:3].tolist(), [0.0, 0.0, 0.0, 1.0])
            angle = float(np.linalg.norm(offset[3:]))
            turn = pybullet.getQuaternionFromAxisAngle((offset[3:] / angle).tolist(), angle) if angle > 0.0 else (0.0, 0.0, 0.0, 1.0)
            self._move(position, pybullet.multiplyTransforms([0.0, 0.0, 0.0], start[1], [0.0, 0.0, 0.0], turn)[1])
            self._step(1)
            hand_poses.append(self._hand_pose())
        linear, angular = pose_change(object_start, relative_pose(self._hand_pose(), self._target_pose()))
        measured = frame_offsets(start, hand_poses)
        return {
            "object_motion_during_shaking_linear": linear,
            "object_motion_during_shaking_angular": angular,
            "shake_achieved_peak_accelerations": achieved_shake_peaks(profile, measured),
        }


# -- inputs ------------------------------------------------------------------------------------------
def grasps_from_poses(poses: GraspPoses, widths_m: Any) -> list[Grasp]:
    """World-frame grasps from their poses (``GraspPoses``, e.g. ``GraspPoses.from_quat_xyzw``:
    the grasp frame's z is the approach) and (N,) contact widths. A malformed input raises
    ``InvalidGraspError`` naming what is wrong."""
    if poses.frame != "world":
        raise InvalidGraspError(f"grasps are executed in the world frame, got poses in the {poses.frame} frame")
    widths = np.atleast_1d(np.asarray(widths_m, dtype=float))
    if widths.ndim != 1 or len(widths) != len(poses):
        raise InvalidGraspError(f"{len(poses)} poses and {widths.size} widths: give one of each per grasp")
    return [
        Grasp.from_frame(position, rotation, width, rotation[:, 2] / np.linalg.norm(rotation[:, 2]))
        for position, rotation, width in zip(poses.position.numpy(), poses.rotation.numpy(), widths)
    ]


def _as_grasps(grasps: GraspCandidates | Sequence[Grasp]) -> list[Grasp]:
    return [grasps[i] for i in range(len(grasps))] if isinstance(grasps, GraspCandidates) else list(grasps)


def _as_placements(placements: ObjectPlacement | Scene | Sequence[ObjectPlacement | Scene], count: int) -> list[ObjectPlacement]:
    one = isinstance(placements, (ObjectPlacement, Scene))
    given = [placements] * count if one else list(placements)
    if len(given) != count:
        raise ValueError(f"{len(given)} object placements for {count} grasps: give one, or one per grasp")
    cache: dict[int, ObjectPlacement] = {}
    return [p if isinstance(p, ObjectPlacement) else cache.setdefault(id(p), ObjectPlacement.from_scene(p)) for p in given]


def _hand_targets(grasps: Sequence[Grasp], config: Config) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(pre-grasp, grasp, quaternion) of each grasp: the first and the grasp waypoint of the study's motion."""
    index = grasp_waypoint_index(config.motion)
    targets = []
    for grasp in grasps:
        quat, waypoints, _ = checked_grasp(grasp, config.motion, robot_of(config))
        targets.append((waypoints[0], waypoints[index], quat))
    return targets


# -- labelling -----------------------------------------------------------------------------------------
def label_grasps_hand(
    placements: ObjectPlacement | Scene | Sequence[ObjectPlacement | Scene],
    grasps: GraspCandidates | Sequence[Grasp],
    config: Config,
) -> list[GraspLabel]:
    """Hand-mode labels of ``grasps``, in order, each from a world of its own (``_HandWorld``).

    ``placements``: where the object rests, one for every grasp or one per grasp (an
    ``ObjectPlacement``, or a reset ``Scene`` whose settled target is taken). Grasps as a
    ``GraspCandidates`` batch or ``Grasp`` values (``grasps_from_poses`` makes them from ``GraspPoses``);
    a malformed one raises ``InvalidGraspError`` before anything is simulated. Every grasp is
    simulated, so every grasp gets a label.
    """
    grasp_list = _as_grasps(grasps)
    placement_list = _as_placements(placements, len(grasp_list))
    targets = _hand_targets(grasp_list, config)
    with _HandWorld(config) as world:
        return [world.label(placement, pregrasp, grasp, quat) for placement, (pregrasp, grasp, quat) in zip(placement_list, targets)]


def label_grasps_arm(scene: Scene, grasps: GraspCandidates | Sequence[Grasp], config: Config) -> list[GraspLabel | None]:
    """Arm-mode labels: each grasp executed from the scene's settled state as the study executes it,
    then shaken (``config.labelling.shake``); None for a grasp the arm cannot reach (untested)."""
    labels = []
    for grasp in _as_grasps(grasps):
        scene.restore_state()
        labels.append(_arm_label(execute_grasp(scene, config, grasp, shake=config.labelling.shake)))
    return labels
