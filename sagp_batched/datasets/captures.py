"""An object's captures planned as one batch: the captures taken first, one reset each, then every
capture's grasps given the planner's verdicts in one batched call (``verdicts.capture_verdicts``), and
each capture's picks drawn, zoned and rated in capture order, a later capture leaving out the grasps an
earlier one took."""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
import torch

from ..config import Config
from ..grasps import Grasp, GraspCandidates, GraspPoses
from ..planning import widest_pair_m
from ..robot.description import robot_of
from ..seeds import labelling_seed
from ..types import PerceivedCloud
from ..world.objects import ObjectSpec
from .protocols import label_protocol
from .verdicts import FEASIBLE, CaptureVerdicts, ClassifiedGrasps, capture_verdicts, classify_grasps

# Captures whose verdicts one batch computes: a batch holds every capture's candidates, covering poses
# and their checks at once (~45 MB more a capture at 50,000 pairs, over ~350 MB for the first), so an
# object of up to a hundred captures is planned a few at a time; the verdicts are the same in any grouping.
CAPTURES_PER_BATCH = 4
# The tasks a dataset's zone ratings are asked for: t3 is t1 among distractors, which a dataset
# of single objects does not place.
DATASET_TASKS: tuple[str, ...] = ("t1", "t2")


@dataclass
class PosePlan:
    """One capture of an object, planned: the grasps picked across the planner's verdicts, with every
    field of their label rows but the simulated outcome, and where the object settled."""

    pose_index: int
    com_position_world: tuple[float, float, float]
    com_quat_xyzw: tuple[float, float, float, float]
    candidates: GraspCandidates  # world frame, zones assigned
    object_from_world: torch.Tensor  # (4, 4)
    classified: ClassifiedGrasps
    ratings: dict  # task -> ZoneRating

    def simulated_grasps(self, mode: str) -> list[Grasp]:
        """The grasps as simulation takes them: in ``arm`` mode a grasp the planner rejected runs
        without its plan, as execution solves it."""
        feasible = (self.classified.verdict == FEASIBLE).tolist()
        grasps = [self.candidates[i] for i in range(len(self.candidates))]
        return grasps if mode == "hand" else [g if ok else dataclasses.replace(g, joint_path=None) for g, ok in zip(grasps, feasible)]


@dataclass
class Capture:
    """One capture of an object, taken: its cloud (the whole object's in the floating protocol), where
    the object settled, and how many grasps to pick from it."""

    pose_index: int
    n_grasps: int
    cloud: PerceivedCloud
    com_position_world: tuple[float, float, float]
    com_quat_xyzw: tuple[float, float, float, float]


def taken_grasps(planned: list[PosePlan | str]) -> GraspPoses:
    """The grasps planned captures picked, in the object's frame: a later capture leaves them out."""
    poses = [pose.candidates.transform(pose.object_from_world, "object").poses() for pose in planned if not isinstance(pose, str)]
    return GraspPoses.cat(poses, "object")


def plan_captures(captures: list[Capture], spec: ObjectSpec, config: Config, rater, earlier: list[PosePlan | str] = ()) -> list[PosePlan | str]:
    """Each capture planned (``PosePlan``), or why it gave no grasp, in the order of ``captures``: their
    verdicts in batches of ``CAPTURES_PER_BATCH``, then each one's picks, zones and ratings (``rater``) in
    turn, none the same grasp as one an ``earlier`` capture picked."""
    batch = []
    for first in range(0, len(captures), CAPTURES_PER_BATCH):
        group = captures[first : first + CAPTURES_PER_BATCH]
        batch += capture_verdicts([capture.cloud for capture in group], config, [labelling_seed(config, capture.pose_index) for capture in group],
                                  n_grasps=max(capture.n_grasps for capture in group))
    planned: list[PosePlan | str] = []
    taken = taken_grasps(list(earlier))  # a later capture offers the same grasps again in the object's frame
    for capture, verdicts in zip(captures, batch):
        pose = _plan_capture(capture, verdicts, spec, config, rater, taken)
        planned.append(pose)
        taken = GraspPoses.cat([taken, taken_grasps([pose])], "object")
    return planned


def _plan_capture(capture: Capture, verdicts: CaptureVerdicts, spec: ObjectSpec, config: Config, rater, taken: GraspPoses) -> PosePlan | str:
    """The capture's grasps picked (not the same as one of ``taken``), zoned and rated; why it gave none instead."""
    from ..semantics.zone_descriptions import describe_zones
    from ..semantics.zone_marks import rating_image
    from ..semantics.zones import assign_zones

    cloud = capture.cloud
    classified = _classified(spec, capture, verdicts, config, taken)
    if not len(classified):
        planner = config.planner
        if not classified.pool_size:
            return (f"capture {capture.pose_index}: no antipodal candidate (opposed contacts "
                    f"{planner.min_width_m * 1000:.0f}-{widest_pair_m(robot_of(config), planner) * 1000:.0f} mm apart) in its cloud")
        return f"capture {capture.pose_index}: each of its {classified.pool_size} candidate poses repeats a grasp of an earlier capture"
    decomposition, zoned = assign_zones(cloud, classified.candidates, config.zones)
    shown = rating_image(cloud, decomposition, config.rating)
    descriptions = describe_zones(decomposition)
    ratings = {task: rater.rate(spec.id, spec.name, task, shown, descriptions) for task in DATASET_TASKS}
    return PosePlan(capture.pose_index, capture.com_position_world, capture.com_quat_xyzw, zoned, cloud.object_from_world, classified, ratings)


def _classified(spec: ObjectSpec, capture: Capture, verdicts: CaptureVerdicts, config: Config, taken: GraspPoses) -> ClassifiedGrasps:
    """A capture's grasps with the planner's verdicts (``classify_grasps``); in the floating protocol
    among the open hands the mesh leaves clear, ``dataset.boundary_fraction`` of them boundary variants."""
    from .boundary_grasps import add_boundary_grasps
    from .grasp_geometry import object_surface

    cloud, n_grasps, seed = capture.cloud, capture.n_grasps, labelling_seed(config, capture.pose_index)
    if label_protocol(config.dataset.protocol).table:
        return classify_grasps(cloud, config, seed, n_grasps, taken_object=taken, verdicts=verdicts)
    boundary = round(config.dataset.boundary_fraction * n_grasps)
    clear = functools.partial(_open_hand_clear_world, spec, cloud.object_from_world, config)
    classified = classify_grasps(cloud, config, seed, n_grasps - boundary, taken_object=taken, open_hand_clear=clear, verdicts=verdicts)
    return add_boundary_grasps(classified, boundary, object_surface(spec), np.asarray(cloud.object_from_world), robot_of(config), config, seed,
                               taken)


def _open_hand_clear_world(spec: ObjectSpec, object_from_world: np.ndarray, config: Config, poses_world: GraspPoses) -> np.ndarray:
    from ..robot.description import robot_of
    from .grasp_geometry import object_surface, open_hand_clear

    poses = poses_world.transform(object_from_world, "object")
    return open_hand_clear(object_surface(spec), poses, robot_of(config), config.labelling.geometry_tolerance_m)
