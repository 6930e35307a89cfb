"""Grasp labels: what to label and how robustly; the protocols (``protocols``) say what is simulated
and an engine (``engines``: PyBullet by default, or MuJoCo) simulates it.

``arm`` mode: the study's execution (``execution.execute_grasp``) with its opt-in shake: the Panda
runs the planned joint path, closes, lifts, holds, then the arm shakes the hand (tabletop only).

``hand`` mode: the Panda hand alone, ACRONYM's convention and far cheaper, in either protocol:
``tabletop`` (the object where it settled on the study's table, the hand approaching from the
pre-grasp) or ``floating`` (the object alone, the hand appearing at the grasp). Every grasp is first
tested by geometry on the object's true mesh (``grasp_geometry``): an open hand that already
intersects the object or the table at the grasp pose is labelled a collision without simulating it.
The rest are simulated, each in a world of its own built from nothing, so a label cannot depend on
which or how many grasps are labelled with it.

Robust labels: with ``labelling.perturbed_simulations`` K > 1 each grasp is simulated K times, at its
pose and at K - 1 poses moved ``perturbation_translation_m`` and turned ``perturbation_rotation_deg``
about the grasp centre in directions drawn from a seed made of the pose itself (the same grasp gets
the same perturbations in any file and any order). The copies are simulated only where the grasp's
own simulation left a thin margin (``thin_margin``: the object slipped or turned in the fingers during
the shake, or let go after the close had gripped it); elsewhere that simulation is the label. The label
is held where most of the K held; the simulations stop once the majority is decided (three alike of
five), since the rest could not change it. ``held_fraction`` keeps the share of the simulations run
(None where the grasp's own simulation alone labelled it), and the label's other fields are those of
its own pose where that agreed with the majority, else of the first perturbed pose that did.

Divergence: a simulation the engine says diverged (``HandEngine.diverged``: a solver warning, a
non-finite state, the object faster than physics allows) is run again with each step divided
``labelling.divergence_step_division`` times; where it diverges again it tested nothing
(``GraspLabel.untested``). A grasp whose own pose is untested is untested (its label would describe
other poses); an untested perturbed copy is left out of the majority, which is over the tested ones.
"""
from __future__ import annotations

import dataclasses
import hashlib
from typing import Any, Sequence

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..config import Config, LabellingConfig
from ..execution.pick import checked_grasp, execute_grasp
from ..grasps import Grasp, GraspCandidates, GraspPoses, InvalidGraspError
from ..robot.description import robot_of
from ..robot.motion import grasp_waypoint_index
from ..types import GraspAttempt
from ..world.objects import ObjectSpec
from ..world.scene import Scene
from .grasp_geometry import contact_widths, floating_hand_links, object_surface, open_hand_collisions
from .engines import check_engine, hand_engine
from .protocols import FloatingPlacement, GraspLabel, HandEngine, HandTarget, LabelProtocol, ObjectPlacement, Placement, label_protocol

__all__ = ["FloatingPlacement", "GraspLabel", "ObjectPlacement", "grasps_from_poses", "label_grasps_arm", "label_grasps_hand",
           "label_object_grasps", "tabletop_placement"]


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


def _tabletop_targets(grasps: Sequence[Grasp], config: Config) -> list[HandTarget]:
    """The pre-grasp and the grasp waypoint of the study's motion, and the orientation, of each grasp."""
    index = grasp_waypoint_index(config.motion)
    targets = []
    for grasp in grasps:
        quat, waypoints, _ = checked_grasp(grasp, config.motion, robot_of(config))
        targets.append(HandTarget(waypoints[0], waypoints[index], quat))
    return targets


def tabletop_placement(spec: ObjectSpec, config: Config, resting_pose: int = 0, trial: int = 0) -> ObjectPlacement:
    """Where ``spec`` settles on the study's table in its resting pose ``resting_pose`` (the scene of ``trial``)."""
    scene = Scene(config)
    try:
        scene.reset(spec, trial=trial, resting_pose=resting_pose)
        return ObjectPlacement.from_scene(scene)
    finally:
        scene.close()


# -- labelling -----------------------------------------------------------------------------------------
def label_grasps_hand(
    placements: ObjectPlacement | Scene | Sequence[ObjectPlacement | Scene],
    grasps: GraspCandidates | Sequence[Grasp],
    config: Config,
    protocol: str = "tabletop",
    engine: str = "pybullet",
) -> list[GraspLabel]:
    """Hand-mode labels of world-frame ``grasps``, in order (robust as the module says).

    ``placements``: where the object rests, one for every grasp or one per grasp (an
    ``ObjectPlacement``, or a reset ``Scene`` whose settled target is taken). Grasps as a
    ``GraspCandidates`` batch or ``Grasp`` values (``grasps_from_poses`` makes them from ``GraspPoses``);
    a malformed one raises ``InvalidGraspError`` before anything is simulated. In the ``floating``
    protocol each grasp keeps its pose on the object, which floats alone at the world's origin.
    ``engine``: the simulator (``engines.ENGINES``).
    """
    label_as = label_protocol(protocol)
    check_engine(engine)
    grasp_list = _as_grasps(grasps)
    placement_list = _as_placements(placements, len(grasp_list))
    return _label(label_as, *label_as.placed(placement_list, _tabletop_targets(grasp_list, config)), config, engine)


def label_object_grasps(spec: ObjectSpec, poses: GraspPoses, widths_m: Any, protocol: str, config: Config,
                        placement: ObjectPlacement | FloatingPlacement | None = None, engine: str = "pybullet") -> list[GraspLabel]:
    """Hand-mode labels of grasps given in the object's link frame, in ``protocol``.

    ``placement``: where the object is; by default floating at the world's origin, or settled on the
    table in its first resting pose (``tabletop_placement``). ``widths_m`` (N,) or None, measured on
    the mesh then (``grasp_geometry.contact_widths``): the hand closes fully either way, the width
    only checks the grasp. ``engine``: the simulator (``engines.ENGINES``).
    """
    label_as = label_protocol(protocol)
    check_engine(engine)
    if poses.frame != "object":
        raise InvalidGraspError(f"object grasps are given in the object frame, got poses in the {poses.frame} frame")
    if placement is None:
        placement = tabletop_placement(spec, config) if label_as.table else FloatingPlacement(spec)
    if not isinstance(placement, label_as.placement_type):
        needed = label_as.placement_type.__name__
        raise ValueError(f"the {protocol} protocol needs {'an' if needed[0] in 'AEIOU' else 'a'} {needed}")
    robot = robot_of(config)
    widths = contact_widths(object_surface(spec), poses, robot.gripper.open_width_m) if widths_m is None else widths_m
    world = poses.transform(placement.link_pose_world(), "world")
    grasps = grasps_from_poses(world, widths)
    if label_as.approaches:
        targets = _tabletop_targets(grasps, config)
    else:
        targets = [HandTarget(g, g, q) for g, q in zip(world.position.numpy(), world.quat_xyzw().numpy())]
    return _label(label_as, [placement] * len(grasps), targets, config, engine)


def _label(protocol: LabelProtocol, placements: Sequence[Placement], targets: Sequence[HandTarget], config: Config,
           engine_name: str) -> list[GraspLabel]:
    """Each grasp's label: its pose and its perturbed copies tested by geometry, its pose simulated where
    clear; the copies simulated only where that simulation left a thin margin (``thin_margin``). A grasp
    most of whose copies put the open hand in the object or the table is dropped by that geometry, which
    is every engine's alike: a pose error decides its label in every engine, not only in one whose
    simulation happened to leave a thin margin (no copy is simulated for it: the majority is decided)."""
    copies = [_perturbed(target, config) for target in targets]
    geometry = _geometry_verdicts(protocol, placements, [[target, *own_copies] for target, own_copies in zip(targets, copies)], config)
    own, copy_verdicts = [verdicts[0] for verdicts in geometry], [verdicts[1:] for verdicts in geometry]
    with hand_engine(engine_name, config) as engine:
        labels = [verdict or _simulated(protocol, engine, placement, target, config) for placement, target, verdict in zip(placements, targets, own)]
        for i, label in enumerate(labels):
            # A grasp whose own pose tested nothing is untested: its copies could only describe other poses.
            if own[i] is not None or label.untested is not None or not copies[i]:
                continue
            colliding = sum(verdict is not None for verdict in copy_verdicts[i])
            if thin_margin(label, config.labelling) or colliding > (1 + len(copies[i])) / 2:
                poses = [targets[i], *copies[i]]
                labels[i] = _majority(_decisive_outcomes(protocol, engine, placements[i], poses, [label, *copy_verdicts[i]], config))
    return [dataclasses.replace(label, engine=engine_name) for label in labels]


def _decisive_outcomes(protocol: LabelProtocol, engine: HandEngine, placement: Placement, poses: list[HandTarget],
                       verdicts: list[GraspLabel | None], config: Config) -> list[GraspLabel]:
    """The grasp's simulations in order (its pose, then its perturbations; a verdict already made stands
    for its simulation) until their majority is decided: the simulations left could not change the
    label, only its ``held_fraction``."""
    outcomes: list[GraspLabel] = []
    for target, verdict in zip(poses, verdicts):
        outcomes.append(verdict or _simulated(protocol, engine, placement, target, config))
        if outcomes[0].untested is not None:
            break
        held = sum(outcome.held for outcome in outcomes)
        dropped = sum(not outcome.held and outcome.untested is None for outcome in outcomes)
        # Decided where the simulations left, all going the other way, could not turn the tested majority.
        if held > dropped + len(poses) - len(outcomes) or held + len(poses) - len(outcomes) <= dropped:
            break
    return outcomes


def thin_margin(outcome: GraspLabel, labelling: LabellingConfig) -> bool:
    """Whether a grasp's own simulation leaves its label open to a pose error, so that its perturbed
    copies decide it (``perturb_only_thin_margins``): held, but the object slipped more than
    ``thin_margin_slip_m`` or turned more than ``thin_margin_rotation_deg`` relative to the hand during
    the shake; or dropped in the lift or the shake, after the close had gripped it. A grasp that never
    gripped (dropped in the close) or collided is not. Every outcome is thin where the rule is off."""
    if not labelling.perturb_only_thin_margins:
        return True
    if not outcome.held:
        return outcome.failed_at in ("lift", "shake")
    return (outcome.object_motion_during_shaking_linear > labelling.thin_margin_slip_m
            or outcome.object_motion_during_shaking_angular > np.radians(labelling.thin_margin_rotation_deg))


def _simulated(protocol: LabelProtocol, engine: HandEngine, placement: Placement, target: HandTarget, config: Config) -> GraspLabel:
    """One simulation's outcome; one that diverged is run again at a smaller step, and untested where it diverges again."""
    outcome = protocol.simulate(engine, placement, target, config)
    if outcome.untested is None:
        return outcome
    engine.step_division = config.labelling.divergence_step_division
    try:
        finer = protocol.simulate(engine, placement, target, config)
    finally:
        engine.step_division = 1
    if finer.untested is None:
        return finer
    return dataclasses.replace(finer, untested=f"{finer.untested} (also at 1/{config.labelling.divergence_step_division} of the step)")


def _majority(outcomes: list[GraspLabel]) -> GraspLabel:
    if outcomes[0].untested is not None:
        return outcomes[0]
    outcomes = [outcome for outcome in outcomes if outcome.untested is None]
    if len(outcomes) == 1:
        return outcomes[0]
    fraction = sum(outcome.held for outcome in outcomes) / len(outcomes)
    held = fraction > 0.5
    representative = next(outcome for outcome in outcomes if outcome.held == held)
    return dataclasses.replace(representative, held_fraction=fraction)


def _perturbed(target: HandTarget, config: Config) -> list[HandTarget]:
    """The K - 1 perturbed copies of a target, from a seed made of the target's own pose."""
    labelling = config.labelling
    count = labelling.perturbed_simulations - 1
    if count <= 0:
        return []
    key = np.round(np.concatenate([target.grasp, target.quat * np.sign(target.quat[np.argmax(np.abs(target.quat))])]), 6)
    rng = np.random.default_rng(int.from_bytes(hashlib.sha256(key.tobytes()).digest()[:8], "little"))
    directions = rng.normal(size=(count, 2, 3))
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    angle = np.deg2rad(labelling.perturbation_rotation_deg)
    return [target.moved(labelling.perturbation_translation_m * shift, Rotation.from_rotvec(angle * axis)) for shift, axis in directions]


def _geometry_verdicts(protocol: LabelProtocol, placements: Sequence[Placement], samples: list[list[HandTarget]],
                       config: Config) -> list[list[GraspLabel | None]]:
    """Per grasp and sample, the collision label where the open hand intersects the object or the
    table at the grasp pose (tested on the object's mesh, in its frame), else None."""
    verdicts: list[list[GraspLabel | None]] = [[None] * len(s) for s in samples]
    robot = robot_of(config)
    links = floating_hand_links(robot)
    by_placement: dict[int, list[tuple[int, int]]] = {}
    for i, placement in enumerate(placements):
        by_placement.setdefault(id(placement), []).extend((i, k) for k in range(len(samples[i])))
    for indices in by_placement.values():
        placement = placements[indices[0][0]]
        world_from_object = placement.link_pose_world()
        targets = [samples[i][k] for i, k in indices]
        world = GraspPoses(torch.as_tensor(np.array([t.grasp for t in targets]), dtype=torch.float64),
                           torch.as_tensor(Rotation.from_quat([t.quat for t in targets]).as_matrix(), dtype=torch.float64), "world")
        poses = world.transform(np.linalg.inv(world_from_object), "object")
        table = None
        if protocol.table:  # the table top, z = top in the world, in the object's frame
            up = world_from_object[2, :3]
            table = (up, float(world_from_object[2, 3] - config.scene.table_top_z_m))
        object_hit, table_hit = open_hand_collisions(object_surface(placement.spec), poses, robot, links,
                                                     config.labelling.geometry_tolerance_m, table)
        for (i, k), hit in zip(indices, object_hit | table_hit):
            if hit:
                verdicts[i][k] = GraspLabel(mode="hand", held=False, failure_reason="collision", failed_at="grasp_pose",
                                            protocol=protocol.name, simulated=False)
    return verdicts


def label_grasps_arm(scene: Scene, grasps: GraspCandidates | Sequence[Grasp], config: Config) -> list[GraspLabel | None]:
    """Arm-mode labels: each grasp executed from the scene's settled state as the study executes it,
    then shaken (``config.labelling.shake``); None for a grasp the arm cannot reach (untested)."""
    labels = []
    for grasp in _as_grasps(grasps):
        scene.restore_state()
        labels.append(_arm_label(execute_grasp(scene, config, grasp, shake=config.labelling.shake)))
    return labels
