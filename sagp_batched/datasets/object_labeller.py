"""Labelled grasp datasets: for each object and resting pose, capture once, plan, and label grasps by simulation.

``ObjectLabeller.plan_object`` captures and plans each of an object's captures once for all their
grasps; ``ObjectLabeller.simulate`` labels a chunk of them; ``object_labels`` joins the chunks.
``dataset_run.generate_dataset`` spreads plans and chunks over workers, writes each finished object at
once (``dataset_directory``) and resumes where a stopped run left off.

What a label is: the outcome of simulating the grasp (``labelling``): held after the lift and the
shake, or dropped, with the object's motion during closing and shaking. The grasps are the planner's
antipodal candidates across its verdicts (``verdicts.classify_grasps``): the feasible ones and those it
rejects, so the dataset has both classes and measures the planner's calibration. A grasp whose
simulation could not run (in ``arm`` mode: no arm solution for a grasp the planner rejected) is kept
apart as untested, never written as a failure.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..config import Config
from ..formats.frames import acronym_gripper_transforms_object
from ..formats.object_grasps import LabelledGrasps, UntestedGrasps
from ..grasps import Grasp, GraspCandidates
from ..seeds import capture_trial
from ..types import PerceptionFailure
from ..world.objects import ObjectSet, ObjectSpec
from .cross_engine import combined_labels, engine_columns, failure_text
from .protocols import label_protocol
from .captures import DATASET_TASKS, Capture, PosePlan, plan_captures
@dataclass
class ObjectLabels:
    """One object's labelled and untested grasps, with what making them cost."""

    object_id: str
    grasps: LabelledGrasps
    untested: UntestedGrasps
    rater: str
    neutral_tasks: dict[str, str]  # task -> why its rating is neutral (the rater does not know the object)
    surface_centre: np.ndarray  # (3,) the centre of the object's mesh's bounding box, link frame
    skipped_poses: list[str] = field(default_factory=list)
    times_s: dict[str, float] = field(default_factory=dict)  # reset, capture, plan, simulate (summed over workers)
    engine_seconds: dict[str, float] = field(default_factory=dict)  # the simulate stage's share of each engine


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


def _zone_levels(candidates: GraspCandidates, ratings: dict) -> tuple[list[str], dict[str, list[str]]]:
    names = candidates.primary_zone_names()
    levels = {task: [(rating.level(name) or "") if name else "" for name in names] for task, rating in ratings.items()}
    return names, levels


class ObjectLabeller:
    """Plans and simulates grasps of objects in one PyBullet client: a scene, a rater, the object set.

    ``plan_object`` captures and plans each of an object's captures once for all their grasps;
    ``simulate`` labels a chunk of them. Each grasp's simulation starts from its capture's settled
    state alone, so a label is the same whichever labeller simulates it and with whichever others.
    """

    def __init__(self, config: Config, objects: ObjectSet):
        from ..rating import get_rater
        from ..world.scene import Scene

        self.config, self.objects = config, objects
        self.scene = Scene(config)
        self.rater = get_rater(config.rating)

    def close(self) -> None:
        self.scene.close()

    def _reset_to_pose(self, spec: ObjectSpec, pose_index: int) -> None:
        """Capture ``pose_index`` places the object at a fresh seeded position and yaw, in its k-th
        stable resting pose where it lists several."""
        self.scene.reset(spec, trial=capture_trial(self.config, pose_index), resting_pose=pose_index % max(1, len(spec.resting_poses)))

    def plan_object(self, object_id: str, n_grasps: int) -> ObjectPlan:
        """Plan ``n_grasps`` grasps of the object, split over its captures."""
        n_poses = self.config.dataset.captures_per_object
        shares = [n_grasps // n_poses + (1 if k < n_grasps % n_poses else 0) for k in range(n_poses)]
        from .grasp_geometry import object_surface

        spec = self.objects.get(object_id)
        planned, times = self._plan_poses(spec, shares)
        poses = [pose for pose in planned if not isinstance(pose, str)]
        neutral = {}
        for pose in poses:
            neutral.update({task: (r.issues[0] if r.issues else "neutral") for task, r in pose.ratings.items() if r.is_neutral})
        rater = f"{self.rater.backend}:{getattr(self.rater, 'model', '')}"
        return ObjectPlan(object_id, poses, [pose for pose in planned if isinstance(pose, str)], rater, neutral,
                          object_surface(spec).box_centre, times)

    def _plan_poses(self, spec: ObjectSpec, shares: list[int]) -> tuple[list[PosePlan | str], dict[str, float]]:
        """Captures 0, 1, ... taking ``shares`` grasps each, planned (``captures.plan_captures``), or why each
        gave none, in capture order; with the seconds their resets, captures and planning took."""
        spent = dict.fromkeys(("reset", "capture", "plan"), 0.0)
        captured: list[Capture | str] = [self._capture(spec, pose_index, share, spent) for pose_index, share in enumerate(shares)]
        clock = time.perf_counter()
        planned = iter(plan_captures([c for c in captured if not isinstance(c, str)], spec, self.config, self.rater))
        spent["plan"] = time.perf_counter() - clock
        return [c if isinstance(c, str) else next(planned) for c in captured], spent

    def _capture(self, spec: ObjectSpec, pose_index: int, n_grasps: int, spent: dict[str, float]) -> Capture | str:
        """Capture ``pose_index`` taken (the whole object's cloud in the floating protocol), or why it
        failed; its reset and capture seconds added to ``spent``."""
        from .grasp_geometry import object_surface, whole_object_cloud
        from .labelling import ObjectPlacement
        from ..world.perception import capture

        clock = time.perf_counter()
        self._reset_to_pose(spec, pose_index)
        spent["reset"] += time.perf_counter() - clock
        clock = time.perf_counter()
        try:
            cloud = capture(self.scene, self.config)
        except PerceptionFailure as failure:
            spent["capture"] += time.perf_counter() - clock
            return f"capture {pose_index}: {failure.reason}"
        if not label_protocol(self.config.dataset.protocol).table:
            cloud = whole_object_cloud(cloud, object_surface(spec), self.config.perception.voxel_size_m)
        spent["capture"] += time.perf_counter() - clock
        placement = ObjectPlacement.from_scene(self.scene)
        return Capture(pose_index, n_grasps, cloud, placement.com_position_world, placement.com_quat_xyzw)

    def simulate(self, chunk: SimulationChunk, mode: str | None = None) -> ChunkOutcome:
        """Label ``chunk`` in ``mode`` (default ``dataset.mode``): ``hand``, the hand alone, each grasp in a
        world of its own with the object where it settled (``labelling.label_grasps_hand``); ``arm``,
        the Panda from the capture's settled state, restored before each grasp (``labelling.label_grasps_arm``;
        a grasp the arm cannot reach is untested)."""
        from .labelling import ObjectPlacement, label_grasps_arm, label_grasps_hand

        clock = time.perf_counter()
        spec = self.objects.get(chunk.object_id)
        if (mode or self.config.dataset.mode) == "arm":
            self._reset_to_pose(spec, chunk.pose_index)
            labels = label_grasps_arm(self.scene, chunk.grasps, self.config)
            outcomes = [label if label is not None else "untested: the arm found no motion that reaches it" for label in labels]
            seconds = time.perf_counter() - clock
            return ChunkOutcome(chunk, outcomes, seconds, {"pybullet": seconds})
        placement = ObjectPlacement(spec, chunk.com_position_world, chunk.com_quat_xyzw)
        by_engine, seconds = {}, {}
        for engine in self.config.dataset.engines:
            started = time.perf_counter()
            by_engine[engine] = label_grasps_hand(placement, chunk.grasps, self.config, self.config.dataset.protocol, engine)
            seconds[engine] = time.perf_counter() - started
        return ChunkOutcome(chunk, combined_labels(by_engine), time.perf_counter() - clock, seconds)

    def label(self, object_id: str, n_grasps: int) -> ObjectLabels:
        """``n_grasps`` grasps of the object planned and simulated here, one chunk a capture."""
        plan = self.plan_object(object_id, n_grasps)
        chunks = plan.chunks(self.config.dataset.mode, n_grasps)
        return object_labels(plan, [self.simulate(chunk) for chunk in chunks], self.config.dataset.engines)

    def compare_modes(self, object_id: str, n_grasps: int) -> dict[str, int]:
        """The same ``n_grasps`` grasps of the object's first capture simulated in hand and in arm mode:
        how many were compared, executed in both, agreed, and held in each."""
        pose = self._plan_poses(self.objects.get(object_id), [n_grasps])[0][0]
        if isinstance(pose, str):
            return {"compared": 0, "both_tested": 0, "agree": 0, "hand_held": 0, "arm_held": 0, "skipped": pose}
        hand, arm = ([o for chunk in pose_chunks(object_id, pose, mode, max(1, n_grasps)) for o in self.simulate(chunk, mode).outcomes]
                     for mode in ("hand", "arm"))
        both = [(h, a) for h, a in zip(hand, arm) if not isinstance(h, str) and not isinstance(a, str)]
        return {"compared": len(hand), "both_tested": len(both), "agree": sum(h.held == a.held for h, a in both),
                "hand_held": sum(h.held for h, _ in both), "arm_held": sum(a.held for _, a in both)}


def mode_agreement(config: Config, objects: ObjectSet, object_ids: list[str], n_grasps: int) -> dict:
    """Hand-vs-arm agreement on ``n_grasps`` grasps of each object of ``object_ids`` (``ObjectLabeller.compare_modes``)."""
    labeller = ObjectLabeller(config, objects)
    try:
        by_object = {object_id: labeller.compare_modes(object_id, n_grasps) for object_id in object_ids}
    finally:
        labeller.close()
    totals = {key: sum(row[key] for row in by_object.values()) for key in ("compared", "both_tested", "agree", "hand_held", "arm_held")}
    return {**totals, "grasps_per_object": n_grasps, "by_object": by_object}

def object_labels(plan: ObjectPlan, outcomes: list[ChunkOutcome], engines: tuple[str, ...] = ("pybullet",)) -> ObjectLabels:
    """An object's labels from its plan and the outcomes of every chunk of it (in any order), labelled by ``engines``."""
    by_pose: dict[int, list] = {pose.pose_index: [None] * len(pose.candidates) for pose in plan.poses}
    for outcome in outcomes:
        by_pose[outcome.chunk.pose_index][outcome.chunk.first:outcome.chunk.first + len(outcome.outcomes)] = outcome.outcomes
    parts = [_pose_labels(pose, by_pose[pose.pose_index], engines) for pose in plan.poses]
    labelled = [p[0] for p in parts]
    grasps = LabelledGrasps.concatenate(labelled) if labelled else LabelledGrasps.empty(DATASET_TASKS, engines)
    untested = UntestedGrasps(np.concatenate([p[1].transforms for p in parts] + [np.zeros((0, 4, 4))]), sum((p[1].reason for p in parts), []))
    times = {**plan.times_s, "simulate": sum(o.seconds for o in outcomes)}
    engine_seconds = {engine: sum(o.engine_seconds.get(engine, 0.0) for o in outcomes) for engine in engines}
    return ObjectLabels(plan.object_id, grasps, untested, plan.rater, plan.neutral_tasks, plan.surface_centre, plan.skipped_poses,
                        times, engine_seconds)


def _pose_labels(pose: PosePlan, outcomes: list, engines: tuple[str, ...]) -> tuple[LabelledGrasps, UntestedGrasps]:
    """The capture's simulated grasps as labels in the object frame, and the grasps whose simulation could not run."""
    zoned, classified = pose.candidates, pose.classified
    tested = [i for i, outcome in enumerate(outcomes) if not isinstance(outcome, str)]
    object_frame = zoned.transform(pose.object_from_world, "object")
    transforms = acronym_gripper_transforms_object(object_frame.poses())
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
    )
    rejected = UntestedGrasps(transforms[untested].reshape(-1, 4, 4), [f"{verdicts[i]}: {outcomes[i]}" for i in untested])
    return labelled, rejected
