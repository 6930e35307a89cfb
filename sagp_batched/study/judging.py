"""How a trial's executed grasp is judged: where it lies, and whether the trial achieved its task.

Where: the grasp's zones against the rating (preferred zone for PZA, avoid zones for AC) and its
contact midpoint against the object's annotated functional and avoid regions (FRA, FAR), which are
independent of the pipeline's own zones. Whether: the published task definitions, with
thresholds from ``config.tasks``.

t1 (stable pickup) needs the grasp to succeed; t2 (functional grasp) also needs the grasp in a
zone the rating prefers and the object kept within ``orientation_tolerance_deg`` of its resting
orientation; t3 (cluttered grasp) also needs every distractor moved at most ``distractor_tolerance_m``.
"""
from __future__ import annotations

from dataclasses import dataclass


import numpy as np

from ..config import TaskConfig
from ..grasps import Grasp
from ..rating.zone_rating import ZoneRating
from ..types import TASKS
from ..world.functional_regions import region_membership


@dataclass(frozen=True)
class GraspPlacement:
    midpoint_object: list[float]  # (3,) contact midpoint in the object's link frame, metres
    in_preferred_zone: bool  # its primary zone is one the rating prefers
    in_avoid_zone: bool  # any zone it is rated by is avoided
    in_functional_region: bool | None  # None for an object without annotated regions
    in_avoid_region: bool | None


def place_grasp(object_id: str, grasp: Grasp, grasp_object: Grasp, rating: ZoneRating) -> GraspPlacement:
    """Where ``grasp`` (world frame; ``grasp_object`` is the same grasp in the object frame) lies:
    in the rating's zones, and in the object's annotated regions."""
    if grasp.frame != "world" or grasp_object.frame != "object":
        raise ValueError(f"place_grasp takes a world-frame and an object-frame grasp, got {grasp.frame} and {grasp_object.frame}")
    midpoint_object = grasp_object.position.tolist()
    regions = region_membership(object_id, np.asarray(midpoint_object))
    return GraspPlacement(
        midpoint_object=midpoint_object,
        in_preferred_zone=grasp.zone is not None and rating.prefers(grasp.zone),
        in_avoid_zone=any(rating.avoids(name) for name in grasp.zones),
        **regions,
    )


@dataclass(frozen=True)
class TaskOutcome:
    orientation_change_deg: float  # rotation of the object from its resting orientation after the lift
    orientation_kept: bool  # within the orientation tolerance (counted by OP for every task)
    distractors_max_displacement_m: float  # largest distractor movement (0 without distractors)
    task_success: bool


def judge_task(
    task: str,
    grasp_success: bool,
    in_preferred_zone: bool,
    orientation_change_deg: float,
    distractors_max_displacement_m: float,
    config: TaskConfig,
) -> TaskOutcome:
    """The ``TaskOutcome`` of one executed trial of ``task``."""
    if task not in TASKS:
        raise ValueError(f"unknown task '{task}' (known: {', '.join(TASKS)})")
    orientation_kept = orientation_change_deg <= config.orientation_tolerance_deg
    task_success = grasp_success
    if task == "t2":
        task_success = task_success and in_preferred_zone and orientation_kept
    if task == "t3":
        task_success = task_success and distractors_max_displacement_m <= config.distractor_tolerance_m
    return TaskOutcome(
        orientation_change_deg=float(orientation_change_deg),
        orientation_kept=bool(orientation_kept),
        distractors_max_displacement_m=float(distractors_max_displacement_m),
        task_success=bool(task_success),
    )
