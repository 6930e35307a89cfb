"""Whether a trial achieved its task, by the published task definitions, with thresholds from ``config.tasks``.

t1 (stable pickup) needs the grasp to succeed; t2 (functional grasp) also needs the grasp in a
zone the rating prefers and the object kept within ``orientation_tolerance_deg`` of its resting
orientation; t3 (cluttered grasp) also needs every distractor moved at most ``distractor_tolerance_m``.
"""
from __future__ import annotations

from dataclasses import dataclass

from .config import TaskConfig
from .types import TASKS


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
