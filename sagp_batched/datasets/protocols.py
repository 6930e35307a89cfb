"""Labelling protocols: each one object (a ``LabelProtocol``) that says what is placed where, how the
hand moves and what counts as held; the engines (``engines``: ``pybullet_hand.PyBulletHand``,
``mujoco_hand.MuJoCoHand``) build the world it asks for and step it, and know nothing of protocols.
A new protocol is one more subclass here, listed in ``PROTOCOLS`` (and its name in ``config.run.LABEL_PROTOCOLS``).

``TABLETOP``: the object rests on the study's table where the capture left it; the open hand starts
at the pre-grasp (``pregrasp_offset_m`` back along the approach), moves along the approach to the
grasp, closes with the study's grip force and finger friction, lifts ``lift_height_m``, holds and
shakes (``ShakeConfig``). Held: the study's test (``execution.held.object_held``), the object's centre
of mass ``success_height_above_table_m`` above the table and both fingers on it, after the hold
and again after the shake.

``FLOATING``: ACRONYM's protocol. The object alone, no table, its link frame where the placement puts
it; gravity off while the open hand appears at the grasp pose and closes, then gravity on, the same
lift, hold and shake. Held: the same test without a table, both fingers still on the object after
the hold and after the shake.

In both, a grasp whose open hand already intersects the object's mesh (or the table) at the grasp
pose is a collision decided by geometry (``grasp_geometry``) before any simulation; the caller
(``labelling``) makes those labels. Object motion is recorded as ACRONYM records it: during the
close in the world (the hand holds still), during the shake in the hand's (grasp target's) frame.
"""
from __future__ import annotations

import abc
import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from ..config import Config
from ..execution.held import lift_failure, object_held
from ..execution.poses import pose_change, relative_pose
from ..execution.shake import ShakeProfile, achieved_shake_peaks, frame_offsets, shake_profile
from ..world.objects import ObjectSpec
from .early_stop import FallWatch, chunk_ends, chunks
from .placements import FloatingPlacement, ObjectPlacement, Placement, Pose, com_in_link

__all__ = ["FloatingPlacement", "ObjectPlacement", "Placement", "Pose", "com_in_link"]  # where the protocols put objects, re-exported


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
    ``object_in_hand_after_closing`` / ``object_in_hand_at_verdict``: the object's centre-of-mass pose
    (position, xyzw quaternion: 7 floats) in the hand's grasp-target frame at the close's end and when
    the label was decided (after the hold where the lift dropped it, else after the shake), None where
    the grasp failed before the close; what says how a grasp was lost (``disagreement_causes``).
    ``simulated``: False where geometry decided the label. ``engine``: the engine that simulated it;
    a label from several engines (``cross_engine.combined_labels``) keeps each one's in ``by_engine``.
    ``untested``: why the simulation tested nothing (it diverged, "diverged: QACC warning"), None
    where it did; such an outcome is neither held nor dropped and never written as a label.
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
    object_in_hand_after_closing: tuple[float, ...] | None = None
    object_in_hand_at_verdict: tuple[float, ...] | None = None
    protocol: str = "tabletop"
    simulated: bool = True
    held_fraction: float | None = None
    engine: str = "pybullet"
    by_engine: tuple["GraspLabel", ...] = ()
    untested: str | None = None


@dataclass(frozen=True)
class HandTarget:
    """One simulation's hand motion in the world: start (the pre-grasp, or the grasp where the hand appears there), grasp, orientation."""

    start: np.ndarray
    grasp: np.ndarray
    quat: np.ndarray

    def moved(self, translation: np.ndarray, turn: Rotation) -> "HandTarget":
        """The same motion turned by ``turn`` about the grasp centre and moved by ``translation``."""
        grasp = self.grasp + translation
        return HandTarget(grasp + turn.apply(self.start - self.grasp), grasp, (turn * Rotation.from_quat(self.quat)).as_quat())


@dataclass(frozen=True)
class WorldStart:
    """The world an engine builds before a simulation: the study's table where ``table``, the object
    with its centre-of-mass frame (``object_frame`` "com") or its link frame ("link") at
    ``object_pose``, the open hand's grasp target at ``hand_position`` / ``hand_quat``, gravity on or off."""

    spec: ObjectSpec
    object_pose: Pose
    object_frame: str
    hand_position: np.ndarray
    hand_quat: np.ndarray
    table: bool
    gravity: bool


class HandEngine(Protocol):
    """What a protocol asks of an engine (``pybullet_hand.PyBulletHand`` and ``mujoco_hand.MuJoCoHand`` are two)."""

    def build(self, start: WorldStart) -> None: ...
    def set_gravity(self, on: bool) -> None: ...
    def command_fingers(self, width_m: float) -> None: ...
    def step(self, steps: int) -> None: ...
    def move(self, position: Sequence[float], quat: Sequence[float] | None = None) -> None: ...
    def hand_pose(self) -> Pose: ...
    def object_pose(self) -> Pose: ...
    def follow(self, positions: np.ndarray, quats: np.ndarray | None = None) -> np.ndarray: ...
    def hand_in_contact(self) -> tuple[bool, bool]: ...
    def hand_touching(self) -> bool: ...
    def table_push_n(self) -> float: ...
    def fingers_touching(self) -> bool: ...
    def diverged(self) -> str | None: ...

    #: Each protocol step divided into this many more engine steps from the next ``build`` on (1: as configured).
    step_division: int


def speed_past_bound(relative_speed_m_s: float, simulated_s: float, config: Config) -> str | None:
    """Why an object moving at ``relative_speed_m_s`` relative to the hand ``simulated_s`` into a
    simulation has diverged, or None: faster than ``labelling.divergence_speed_m_s`` plus a free
    fall over the whole simulation (gravity the one force the protocol lets act on a dropped object)."""
    bound = config.labelling.divergence_speed_m_s + abs(config.scene.gravity_m_s2) * simulated_s
    if not math.isfinite(relative_speed_m_s):
        return "diverged: non-finite object speed"
    return f"diverged: object speed {relative_speed_m_s:.3g} m/s" if relative_speed_m_s > bound else None


def half_cosine(fraction: float) -> float:
    """Progress along a straight move that starts and stops at rest."""
    return 0.5 * (1.0 - math.cos(math.pi * fraction))


def _checkpoints(steps: int, count: int) -> set[int]:
    """Steps (1-based) after which a motion of ``steps`` is checked ``count`` times, evenly, the last at its end."""
    return {round(steps * (k + 1) / count) for k in range(count)}


class LabelProtocol(abc.ABC):
    """One way of labelling a grasp by simulation. ``start`` says what is placed where, ``simulate``
    moves the hand from there and ``held`` judges; after the close every protocol here lifts, holds and
    shakes (``_close_lift_shake``), a protocol with another motion overrides ``simulate``.

    ``table``: the study's table is in the world (and the dataset's grasps come from the table's
    captures); without it the object floats alone and grasps are taken from all around it.
    ``geometry_verdicts``: the planner's verdicts whose grasps geometry alone mostly fails, of which a
    dataset takes few, since a learner gains little from many. ``approaches``: the hand starts at the
    pre-grasp and moves along the study's approach to the grasp; else it appears at the grasp.
    ``placement_type``: where a ``simulate`` call's object is (``ObjectPlacement``, ``FloatingPlacement``)."""

    name: ClassVar[str]
    table: ClassVar[bool]
    geometry_verdicts: ClassVar[tuple[str, ...]]
    approaches: ClassVar[bool]
    placement_type: ClassVar[type]

    def start(self, placement: Placement, target: HandTarget) -> WorldStart:
        """The world a simulation starts from: the object where ``placement`` has it, the hand at the
        pre-grasp where it ``approaches``, else at the grasp; gravity on from the start where there is a table."""
        hand_position = target.start if self.approaches else target.grasp
        return WorldStart(placement.spec, placement.pose, placement.frame, hand_position, target.quat, table=self.table, gravity=self.table)

    @abc.abstractmethod
    def simulate(self, engine: HandEngine, placement: Placement, target: HandTarget, config: Config) -> GraspLabel:
        """The label of one simulation of a grasp, in a world ``engine`` builds from nothing."""

    def held(self, engine: HandEngine, config: Config) -> bool:
        """The study's test (``object_held``) on what the engine measures, the table where there is one."""
        height = engine.object_pose()[0][2] - config.scene.table_top_z_m if self.table else None
        return object_held(engine.fingers_touching(), height, config.execution)

    def placed(self, placements: Sequence[ObjectPlacement], targets: Sequence[HandTarget]) -> tuple[list[Placement], list[HandTarget]]:
        """Where grasps planned on objects resting on the table (``placements``, ``targets`` in the world)
        are simulated in this protocol: as they are."""
        return list(placements), list(targets)

    def _close_lift_shake(self, engine: HandEngine, grasp: np.ndarray, config: Config, rise_from_z: float | None,
                          gravity_after_close: bool = False) -> GraspLabel:
        """Once the hand is at the grasp: close, lift, hold, judge, shake, judge.

        The object's rise during the lift (slipped or never lifted) is measured from ``rise_from_z``,
        where it rested, or from where the close left it (None). The lift and the shake are known in
        advance, so the engine follows each (``follow``) from one check to the next. Once the object
        has fallen away from the hand (``early_stop.FallWatch``) the grasp is dropped whatever
        follows, and the simulation stops there."""
        execution, labelling = config.execution, config.labelling
        motion: dict[str, Any] = {}
        before_close = engine.object_pose()
        engine.command_fingers(0.0)
        engine.step(labelling.hand_close_steps)
        after_close = engine.object_pose()
        motion["object_motion_during_closing_linear"], motion["object_motion_during_closing_angular"] = pose_change(before_close, after_close)
        motion["object_in_hand_after_closing"] = _object_in_hand(engine)
        touching_after_close = engine.fingers_touching()
        if (reason := engine.diverged()) is not None:
            return self._untested(reason, "close", motion)
        if gravity_after_close:
            engine.set_gravity(True)
        steps = labelling.hand_lift_steps
        rise_checks = _checkpoints(steps, config.motion.lift_waypoints)
        up = np.array([0.0, 0.0, config.motion.lift_height_m])
        lift = np.array([grasp + up * half_cosine(step / steps) for step in range(1, steps + 1)])
        highest_rise, rise_from_z, done = 0.0, (after_close[0][2] if rise_from_z is None else rise_from_z), 0
        fall = FallWatch(engine, labelling.early_stop_distance_m)

        def lift_failed() -> GraspLabel:  # untested where the simulation diverged
            if (reason := engine.diverged()) is not None:
                return self._untested(reason, "lift", motion)
            motion["object_in_hand_at_verdict"] = _object_in_hand(engine)
            return self._failed(*lift_failure(highest_rise, touching_after_close, execution), motion)

        for end in chunk_ends(steps, rise_checks, labelling.early_stop_check_steps):
            engine.follow(lift[done:end])
            done = end
            rise = float(engine.object_pose()[0][2] - rise_from_z)
            if end in rise_checks:
                highest_rise = max(highest_rise, rise)
            if end % labelling.early_stop_check_steps and end != steps:
                continue
            # Later checks of the rise see the falling object lower: the reason is decided once it is below the height that names it.
            if fall.seen() and (highest_rise >= execution.lifted_detect_height_m or rise < execution.lifted_detect_height_m):
                return lift_failed()
        for chunk in chunks(labelling.hand_hold_steps, labelling.early_stop_check_steps):
            engine.step(chunk)
            if fall.seen():
                return lift_failed()
        if engine.diverged() is not None or not self.held(engine, config):
            return lift_failed()
        shaken, fell = _shake(engine, shake_profile(labelling.shake, config.scene.time_step_s), fall, labelling.early_stop_check_steps)
        motion.update(shaken)
        if (reason := engine.diverged()) is not None:
            return self._untested(reason, "shake", motion)
        motion["object_in_hand_at_verdict"] = _object_in_hand(engine)
        if not fell and self.held(engine, config):
            return GraspLabel(mode="hand", held=True, failure_reason=None, failed_at=None, protocol=self.name, **motion)
        return self._failed("slipped", "shake", motion)

    def _failed(self, reason: str, phase: str, motion: dict[str, Any]) -> GraspLabel:
        return GraspLabel(mode="hand", held=False, failure_reason=reason, failed_at=phase, protocol=self.name, **motion)

    def _untested(self, reason: str, phase: str, motion: dict[str, Any]) -> GraspLabel:
        """A simulation that diverged by the end of ``phase``: no outcome, whatever the state says."""
        return GraspLabel(mode="hand", held=False, failure_reason="diverged", failed_at=phase, protocol=self.name, untested=reason, **motion)


class Tabletop(LabelProtocol):
    """The object where it settled on the study's table, the hand approaching from the pre-grasp."""

    name, table, approaches, placement_type = "tabletop", True, True, ObjectPlacement
    # The open hand through the table or in the object's points.
    geometry_verdicts = ("table", "volume")

    def simulate(self, engine: HandEngine, placement: ObjectPlacement, target: HandTarget, config: Config) -> GraspLabel:
        """Approach, close, lift, hold, shake, with the object on the table."""
        execution, labelling = config.execution, config.labelling
        engine.build(self.start(placement, target))
        rest_com = np.array(placement.com_position_world)
        if any(engine.hand_in_contact()):
            return self._failed("collision", "pregrasp", {})
        engine.step(labelling.hand_settle_steps)
        # Checked as the study checks its descent: after each of its waypoints.
        steps = labelling.hand_approach_steps
        approach = np.array([target.start + (target.grasp - target.start) * half_cosine(step / steps) for step in range(1, steps + 1)])
        done = 0
        for end in sorted(_checkpoints(steps, config.motion.descent_waypoints)):
            engine.follow(approach[done:end])
            done = end
            knocked = np.linalg.norm(np.subtract(engine.object_pose()[0], rest_com)) > execution.knock_tolerance_m
            if knocked or engine.table_push_n() > execution.table_contact_max_force_n:
                if (reason := engine.diverged()) is not None:
                    return self._untested(reason, "descent", {})
                return self._failed("collision", "descent", {})
        if (reason := engine.diverged()) is not None:
            return self._untested(reason, "descent", {})
        return self._close_lift_shake(engine, target.grasp, config, rise_from_z=float(rest_com[2]))


class Floating(LabelProtocol):
    """The object alone with gravity off, the open hand at the grasp; close, then gravity, lift, hold, shake."""

    name, table, approaches, placement_type = "floating", False, False, FloatingPlacement
    # No descent, but the hand's sweep ends in the hand at the grasp.
    geometry_verdicts = ("volume", "hand_sweep")

    def simulate(self, engine: HandEngine, placement: FloatingPlacement, target: HandTarget, config: Config) -> GraspLabel:
        engine.build(self.start(placement, target))
        return self._close_lift_shake(engine, target.grasp, config, rise_from_z=None, gravity_after_close=True)

    def placed(self, placements: Sequence[ObjectPlacement], targets: Sequence[HandTarget]) -> tuple[list[Placement], list[HandTarget]]:
        """Each grasp keeps its pose on the object, which floats alone at the world's origin."""
        floating: dict[ObjectSpec, FloatingPlacement] = {}
        object_from_world_of: dict[int, np.ndarray] = {}  # one per placement: a batch usually shares one
        on_object = []
        for placement, target in zip(placements, targets):
            if id(placement) not in object_from_world_of:
                object_from_world_of[id(placement)] = np.linalg.inv(placement.link_pose_world())
            object_from_world = object_from_world_of[id(placement)]
            grasp = object_from_world[:3, :3] @ target.grasp + object_from_world[:3, 3]
            quat = (Rotation.from_matrix(object_from_world[:3, :3]) * Rotation.from_quat(target.quat)).as_quat()
            on_object.append(HandTarget(grasp, grasp, quat))
        return [floating.setdefault(p.spec, FloatingPlacement(p.spec)) for p in placements], on_object


TABLETOP, FLOATING = Tabletop(), Floating()
PROTOCOLS: dict[str, LabelProtocol] = {protocol.name: protocol for protocol in (TABLETOP, FLOATING)}


def label_protocol(name: str) -> LabelProtocol:
    """The protocol called ``name``; ``ValueError`` naming the known ones where none is."""
    if name not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, got {name!r}")
    return PROTOCOLS[name]


def _object_in_hand(engine: HandEngine) -> tuple[float, ...]:
    """The object's centre-of-mass pose in the hand's grasp-target frame as 7 floats (position, xyzw quaternion)."""
    position, quat = relative_pose(engine.hand_pose(), engine.object_pose())
    return (*position, *quat)


def _shake(engine: HandEngine, profile: ShakeProfile, fall: FallWatch, check_steps: int) -> tuple[dict[str, Any], bool]:
    """Follow ``profile`` around the hand's pose, rotations about the grasp target, until its end or
    until the object has fallen away (``fall``, checked every ``check_steps``): the object's motion
    relative to the hand over the steps followed, the peaks the hand reached on the axes it shook to
    the end (``achieved_shake_peaks`` of its pose at every step; 0 on the rest), and whether it fell."""
    start = engine.hand_pose()
    object_start = relative_pose(start, engine.object_pose())
    turn = Rotation.from_quat(start[1])
    positions = np.asarray(start[0]) + turn.apply(profile.offsets[:, :3])
    quats = (turn * Rotation.from_rotvec(profile.offsets[:, 3:])).as_quat()
    hand_poses, fell, done = [], False, 0
    for chunk in chunks(profile.steps, check_steps):
        hand_poses.append(engine.follow(positions[done : done + chunk], quats[done : done + chunk]))
        done += chunk
        fell = fall.seen()
        if fell:
            break
    followed = np.concatenate(hand_poses) if hand_poses else np.empty((0, 7))  # a shake of no axis
    linear, angular = pose_change(object_start, relative_pose(engine.hand_pose(), engine.object_pose()))
    shaken = dataclasses.replace(profile, offsets=profile.offsets[:done], segments=tuple(s for s in profile.segments if s[2] <= done))
    return {
        "object_motion_during_shaking_linear": linear,
        "object_motion_during_shaking_angular": angular,
        "shake_achieved_peak_accelerations": achieved_shake_peaks(shaken, frame_offsets(start, [(row[:3], row[3:]) for row in followed])),
    }, fell
