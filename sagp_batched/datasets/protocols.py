"""Labelling protocols: what is placed where, how the hand moves, and what counts as held.

Two protocols, each run on any hand engine (``engines``: ``pybullet_hand.PyBulletHand``,
``mujoco_hand.MuJoCoHand``; an engine builds the world and steps it, the protocol decides everything else):

``tabletop``: the object rests on the study's table where the capture left it; the open hand starts
at the pre-grasp (``pregrasp_offset_m`` back along the approach), moves along the approach to the
grasp, closes with the study's grip force and finger friction, lifts ``lift_height_m``, holds and
shakes (``ShakeConfig``). Held: execution's own test (``execution.object_held``), the object's centre
of mass ``success_height_above_table_m`` above the table and both fingers on it, after the hold
and again after the shake.

``floating``: ACRONYM's protocol. The object alone, no table, its link frame where the placement puts
it; gravity off while the open hand appears at the grasp pose and closes, then gravity on, the same
lift, hold and shake. Held: both fingers still on the object after the hold and after the shake.

In both, a grasp whose open hand already intersects the object's mesh (or the table) at the grasp
pose is a collision decided by geometry (``grasp_geometry``) before any simulation; the caller
(``labelling``) makes those labels. Object motion is recorded as ACRONYM records it: during the
close in the world (the hand holds still), during the shake in the hand's (grasp target's) frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from ..config import Config
from ..execution.pick import lift_failure
from ..execution.poses import pose_change, relative_pose
from ..execution.shake import ShakeProfile, achieved_shake_peaks, frame_offsets, shake_profile
from ..world.objects import ObjectSpec

PROTOCOLS: tuple[str, ...] = ("tabletop", "floating")
Pose = tuple[Sequence[float], Sequence[float]]  # position (3,), xyzw quaternion (4,)


@dataclass(frozen=True)
class GraspLabel:
    """What simulation (or, for a collision at the grasp pose, geometry) made of one grasp.

    ``held``: still held after the shake; over several perturbed simulations, held in most of them
    (``held_fraction``, None where the grasp was simulated once). ``failure_reason``/``failed_at``:
    execution's reasons ("unreachable" is never a label: an arm that cannot reach a grasp has not
    tested it) and phases ("grasp_pose": the open hand intersects the object or the table there,
    decided by geometry; "pregrasp", "descent", "close", "lift", "shake"). Object motion (m, rad),
    None where the grasp failed before that phase: ``closing`` in the world from just before the
    close to its end, ``shaking`` relative to the hand from the shake's start to its end.
    ``shake_achieved_peak_accelerations``: what the hand reached along and about its x, y, z
    (m/s^2, rad/s^2; ``shake.achieved_shake_peaks``), None where it was not shaken.
    ``simulated``: False where geometry decided the label. ``engine``: the engine that simulated it;
    a label from several engines (``cross_engine.combined_labels``) keeps each one's in ``by_engine``.
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
    protocol: str = "tabletop"
    simulated: bool = True
    held_fraction: float | None = None
    engine: str = "pybullet"
    by_engine: tuple["GraspLabel", ...] = ()


@dataclass(frozen=True)
class ObjectPlacement:
    """An object resting on the study's table: its spec and the world pose of its centre-of-mass
    frame (what ``getBasePositionAndOrientation`` reports)."""

    spec: ObjectSpec
    com_position_world: tuple[float, float, float]
    com_quat_xyzw: tuple[float, float, float, float]

    @classmethod
    def from_scene(cls, scene) -> "ObjectPlacement":
        """The target of a reset ``Scene`` where it settled (the scene is restored to its saved state first)."""
        if scene.target_spec is None:
            raise ValueError("ObjectPlacement.from_scene needs a Scene after reset")
        scene.restore_state()
        position, quat = scene.centre_of_mass(scene.target_id)
        return cls(scene.target_spec, tuple(float(v) for v in position), tuple(float(v) for v in quat))


class HandEngine(Protocol):
    """What a protocol asks of an engine (``pybullet_hand.PyBulletHand`` and ``mujoco_hand.MuJoCoHand`` are two)."""

    def build(self, spec: ObjectSpec, object_pose: Pose, pose_of: str, hand_position: np.ndarray, quat: np.ndarray,
              table: bool, gravity: bool) -> None: ...
    def set_gravity(self, on: bool) -> None: ...
    def command_fingers(self, width_m: float) -> None: ...
    def step(self, steps: int) -> None: ...
    def move(self, position: Sequence[float], quat: Sequence[float] | None = None) -> None: ...
    def hand_pose(self) -> Pose: ...
    def object_pose(self) -> Pose: ...
    def hand_in_contact(self) -> tuple[bool, bool]: ...
    def table_push_n(self) -> float: ...
    def fingers_touching(self) -> bool: ...
    def held_above_table(self) -> bool: ...


def _half_cosine(fraction: float) -> float:
    """Progress along a straight move that starts and stops at rest."""
    return 0.5 * (1.0 - math.cos(math.pi * fraction))


def _checkpoints(steps: int, count: int) -> set[int]:
    """Steps (1-based) after which a motion of ``steps`` is checked ``count`` times, evenly, the last at its end."""
    return {round(steps * (k + 1) / count) for k in range(count)}


def run_tabletop(engine: HandEngine, placement: ObjectPlacement, pregrasp: np.ndarray, grasp: np.ndarray, quat: np.ndarray,
                 config: Config) -> GraspLabel:
    """Approach, close, lift, hold, shake, with the object on the table: the label of one grasp."""
    execution, labelling = config.execution, config.labelling
    engine.build(placement.spec, (placement.com_position_world, placement.com_quat_xyzw), "com", pregrasp, quat, table=True, gravity=True)
    rest_com = np.array(placement.com_position_world)
    if any(engine.hand_in_contact()):
        return _failed("tabletop", "collision", "pregrasp", {})
    engine.step(labelling.hand_settle_steps)
    # Checked as the study checks its descent: after each of its waypoints.
    checks = _checkpoints(labelling.hand_approach_steps, config.motion.descent_waypoints)
    for step in range(1, labelling.hand_approach_steps + 1):
        engine.move(pregrasp + (grasp - pregrasp) * _half_cosine(step / labelling.hand_approach_steps))
        engine.step(1)
        if step in checks:
            knocked = np.linalg.norm(np.subtract(engine.object_pose()[0], rest_com)) > execution.knock_tolerance_m
            if knocked or engine.table_push_n() > execution.table_contact_max_force_n:
                return _failed("tabletop", "collision", "descent", {})
    return _close_lift_shake(engine, grasp, config, "tabletop", engine.held_above_table, rise_from_z=float(rest_com[2]))


def run_floating(engine: HandEngine, spec: ObjectSpec, object_link_pose: Pose, grasp: np.ndarray, quat: np.ndarray,
                 config: Config) -> GraspLabel:
    """The object floating with gravity off, the open hand at the grasp; close, then gravity, lift, hold, shake."""
    engine.build(spec, object_link_pose, "link", grasp, quat, table=False, gravity=False)
    return _close_lift_shake(engine, grasp, config, "floating", engine.fingers_touching, rise_from_z=None, gravity_after_close=True)


def _close_lift_shake(engine: HandEngine, grasp: np.ndarray, config: Config, protocol: str, held, rise_from_z: float | None,
                      gravity_after_close: bool = False) -> GraspLabel:
    """The phases both protocols share once the hand is at the grasp: close, lift, hold, judge, shake, judge.

    The object's rise during the lift (slipped or never lifted) is measured from ``rise_from_z``,
    where it rested, or from where the close left it (None)."""
    execution, labelling = config.execution, config.labelling
    motion: dict[str, Any] = {}
    before_close = engine.object_pose()
    engine.command_fingers(0.0)
    engine.step(labelling.hand_close_steps)
    after_close = engine.object_pose()
    motion["object_motion_during_closing_linear"], motion["object_motion_during_closing_angular"] = pose_change(before_close, after_close)
    touching_after_close = engine.fingers_touching()
    if gravity_after_close:
        engine.set_gravity(True)
    checks = _checkpoints(labelling.hand_lift_steps, config.motion.lift_waypoints)
    up = np.array([0.0, 0.0, config.motion.lift_height_m])
    highest_rise, rise_from_z = 0.0, (after_close[0][2] if rise_from_z is None else rise_from_z)
    for step in range(1, labelling.hand_lift_steps + 1):
        engine.move(grasp + up * _half_cosine(step / labelling.hand_lift_steps))
        engine.step(1)
        if step in checks:
            highest_rise = max(highest_rise, float(engine.object_pose()[0][2] - rise_from_z))
    engine.step(labelling.hand_hold_steps)
    if not held():
        return _failed(protocol, *lift_failure(highest_rise, touching_after_close, execution), motion)
    motion.update(_shake(engine, shake_profile(labelling.shake, config.scene.time_step_s)))
    if held():
        return GraspLabel(mode="hand", held=True, failure_reason=None, failed_at=None, protocol=protocol, **motion)
    return _failed(protocol, "slipped", "shake", motion)


def _shake(engine: HandEngine, profile: ShakeProfile) -> dict[str, Any]:
    """Follow ``profile`` around the hand's pose, rotations about the grasp target: the object's motion
    relative to the hand over the shake and the peaks the hand reached (``achieved_shake_peaks`` of its
    pose at every step)."""
    start = engine.hand_pose()
    object_start = relative_pose(start, engine.object_pose())
    turn = Rotation.from_quat(start[1])
    positions = np.asarray(start[0]) + turn.apply(profile.offsets[:, :3])
    quats = (turn * Rotation.from_rotvec(profile.offsets[:, 3:])).as_quat()
    hand_poses = []
    for position, quat in zip(positions.tolist(), quats.tolist()):
        engine.move(position, quat)
        engine.step(1)
        hand_poses.append(engine.hand_pose())
    linear, angular = pose_change(object_start, relative_pose(engine.hand_pose(), engine.object_pose()))
    return {
        "object_motion_during_shaking_linear": linear,
        "object_motion_during_shaking_angular": angular,
        "shake_achieved_peak_accelerations": achieved_shake_peaks(profile, frame_offsets(start, hand_poses)),
    }


def _failed(protocol: str, reason: str, phase: str, motion: dict[str, Any]) -> GraspLabel:
    return GraspLabel(mode="hand", held=False, failure_reason=reason, failed_at=phase, protocol=protocol, **motion)
