"""An object's dataset work as it passes between the driver and the workers, and the labels it joins into.

A worker's ``ObjectLabeller.plan_object`` gives an ``ObjectPlan``; its grasps are simulated in
``SimulationChunk``s, each giving a ``ChunkOutcome``; the driver joins a plan and the outcomes of all
its chunks, in any order, into the object's ``ObjectLabels`` (``object_labels``): its grasps as labels
in the object frame, the grasps whose simulation could not run kept apart as untested.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..formats.frames import acronym_gripper_transforms_object
from ..formats.object_grasps import LabelledGrasps, UntestedGrasps
from ..grasps import Grasp, GraspCandidates
from ..robot.gripper_description import GripperDescription
from .captures import DATASET_TASKS, PosePlan
from .cross_engine import engine_columns, failure_text


@dataclass
class ObjectLabels:
    """One object's labelled and untested grasps, with what making them cost."""

    object_id: str
    grasps: LabelledGrasps
    untested: UntestedGrasps
    rater: str
    neutral_tasks: dict[str, str]  # task -> why its rating is neutral (the rater does not know the object)
    surface_centre: np.ndarray  # (3,) the centre of the object's mesh's bounding box, link frame: the octants' centre
    skipped_poses: list[str] = field(default_factory=list)
    times_s: dict[str, float] = field(default_factory=dict)  # reset, capture, plan, simulate (summed over workers)
    engine_seconds: dict[str, float] = field(default_factory=dict)  # the simulate stage's share of each engine
    shortfall: str | None = None  # why fewer grasps were planned than asked


@dataclass
class ObjectPlan:
    """Every capture of one object, planned; what the captures that failed reported; planning times."""

    object_id: str
    poses: list[PosePlan]
    skipped_poses: list[str]
    rater: str
    neutral_tasks: dict[str, str]
    surface_centre: np.ndarray  # (3,) the centre of the object's mesh's bounding box, link frame
    times_s: dict[str, float]
    shortfall: str | None = None  # why fewer grasps were planned than asked (``ObjectLabeller._plan_more``)

    def chunks(self, mode: str, grasps_per_chunk: int) -> list["SimulationChunk"]:
        """The plan's grasps in chunks of at most ``grasps_per_chunk``, each simulated on its own; in
        ``arm`` mode one chunk a capture, its grasps in order: the arm restores the capture's saved
        state between grasps, and PyBullet's ``restoreState`` leaves small traces of the grasp before
        (object motions differ in the fourth decimal), so a grasp's label would depend on where a
        chunk began."""
        return [chunk for pose in self.poses for chunk in pose_chunks(self.object_id, pose, mode, grasps_per_chunk)]


def pose_chunks(object_id: str, pose: PosePlan, mode: str, grasps_per_chunk: int) -> list["SimulationChunk"]:
    """One capture's grasps in chunks (``ObjectPlan.chunks``)."""
    grasps = pose.simulated_grasps(mode)
    size = grasps_per_chunk if mode == "hand" else max(1, len(grasps))
    return [SimulationChunk(object_id, pose.pose_index, first, pose.com_position_world, pose.com_quat_xyzw, grasps[first:first + size])
            for first in range(0, len(grasps), size)]


@dataclass(frozen=True)
class SimulationChunk:
    """Grasps of one capture to simulate: what a worker needs and nothing of the planning worker's world."""

    object_id: str
    pose_index: int
    first: int  # index of the chunk's first grasp among its capture's picks
    com_position_world: tuple[float, float, float]
    com_quat_xyzw: tuple[float, float, float, float]
    grasps: list[Grasp]


@dataclass
class ChunkOutcome:
    """A chunk's outcomes, in its order: a ``GraspLabel``, or why the grasp could not be simulated."""

    chunk: SimulationChunk
    outcomes: list
    seconds: float
    engine_seconds: dict[str, float] = field(default_factory=dict)


def _motion(value: float | None) -> float:
    """A motion the grasp never reached (it failed before that phase) is NaN, not 0."""
    return math.nan if value is None else float(value)


def _pose_row(pose: tuple[float, ...] | None) -> list[float]:
    """A pose of 7 floats the grasp never reached is NaN."""
    return [math.nan] * 7 if pose is None else [float(v) for v in pose]


def _zone_levels(candidates: GraspCandidates, ratings: dict) -> tuple[list[str], dict[str, list[str]]]:
    names = candidates.primary_zone_names()
    levels = {task: [(rating.level(name) or "") if name else "" for name in names] for task, rating in ratings.items()}
    return names, levels


def object_labels(plan: ObjectPlan, outcomes: list[ChunkOutcome], gripper: GripperDescription, engines: tuple[str, ...] = ("pybullet",)) -> ObjectLabels:
    """An object's labels from its plan and the outcomes of every chunk of it (in any order), made by ``gripper`` and
    labelled by ``engines``."""
    by_pose: dict[int, list] = {pose.pose_index: [None] * len(pose.candidates) for pose in plan.poses}
    for outcome in outcomes:
        by_pose[outcome.chunk.pose_index][outcome.chunk.first:outcome.chunk.first + len(outcome.outcomes)] = outcome.outcomes
    parts = [_pose_labels(pose, by_pose[pose.pose_index], gripper, engines) for pose in plan.poses]
    labelled = [p[0] for p in parts]
    grasps = LabelledGrasps.concatenate(labelled) if labelled else LabelledGrasps.empty(DATASET_TASKS, engines)
    untested = UntestedGrasps(np.concatenate([p[1].transforms for p in parts] + [np.zeros((0, 4, 4))]), sum((p[1].reason for p in parts), []))
    times = {**plan.times_s, "simulate": sum(o.seconds for o in outcomes)}
    engine_seconds = {engine: sum(o.engine_seconds.get(engine, 0.0) for o in outcomes) for engine in engines}
    return ObjectLabels(plan.object_id, grasps, untested, plan.rater, plan.neutral_tasks, plan.surface_centre, plan.skipped_poses,
                        times, engine_seconds, plan.shortfall)


def _pose_labels(pose: PosePlan, outcomes: list, gripper: GripperDescription, engines: tuple[str, ...]) -> tuple[LabelledGrasps, UntestedGrasps]:
    """The capture's simulated grasps as labels in the object frame, and the grasps whose simulation could not run."""
    zoned, classified = pose.candidates, pose.classified
    tested = [i for i, outcome in enumerate(outcomes) if not isinstance(outcome, str)]
    object_frame = zoned.transform(pose.object_from_world, "object")
    transforms = acronym_gripper_transforms_object(object_frame.poses(), gripper)
    untested = [i for i, outcome in enumerate(outcomes) if isinstance(outcome, str)]
    kept = torch.as_tensor(tested, dtype=torch.int64)
    chosen = zoned.select(kept)
    zone_names, levels = _zone_levels(chosen, pose.ratings)
    verdicts = classified.verdict_names()
    simulated = [outcomes[i] for i in tested]
    labelled = LabelledGrasps(
        transforms=transforms[tested].reshape(-1, 4, 4),
        width_m=chosen.width_m.double().numpy(),
        contacts=object_frame.contacts[kept].numpy().reshape(-1, 2, 3),
        resting_pose=np.full(len(tested), pose.pose_index, dtype=np.int64),
        verdict=[verdicts[i] for i in tested],
        verdict_reason=[classified.reasons[i] for i in tested],
        held=np.array([o.held for o in simulated], dtype=bool),
        held_fraction=np.array([float(o.held) if o.held_fraction is None else o.held_fraction for o in simulated]),
        decided_by=["simulation" if o.simulated else "geometry" for o in simulated],
        failure_reason=[failure_text(o) for o in simulated],
        motion_closing_linear_m=np.array([_motion(o.object_motion_during_closing_linear) for o in simulated]),
        motion_closing_angular_rad=np.array([_motion(o.object_motion_during_closing_angular) for o in simulated]),
        motion_shaking_linear_m=np.array([_motion(o.object_motion_during_shaking_linear) for o in simulated]),
        motion_shaking_angular_rad=np.array([_motion(o.object_motion_during_shaking_angular) for o in simulated]),
        s_geom=chosen.s_geom.double().numpy(),
        s_reach=chosen.s_reach.double().numpy(),
        zone=zone_names,
        zone_rating=levels,
        **dict(zip(("engine_held", "engine_held_fraction", "engine_failure"), engine_columns(simulated, engines))),
        object_in_hand_after_closing=np.array([_pose_row(o.object_in_hand_after_closing) for o in simulated]).reshape(-1, 7),
        object_in_hand_at_verdict=np.array([_pose_row(o.object_in_hand_at_verdict) for o in simulated]).reshape(-1, 7),
    )
    rejected = UntestedGrasps(transforms[untested].reshape(-1, 4, 4), [f"{verdicts[i]}: {outcomes[i]}" for i in untested])
    return labelled, rejected
