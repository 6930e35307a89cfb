"""What an executed grasp measured on its way, and the one place its ``trials.jsonl`` entry is made.

An entry of a record's ``attempt_log`` is the attempt's ``candidate``, ``success`` and
``failure_reason`` followed by the fields of ``AttemptDiagnostics`` in their declared order, which is
the order execution measures them in; README.md ("Attempt log") lists them with their units.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

# The fields every attempt-log entry opens with, ahead of the diagnostics.
ATTEMPT_OUTCOME_FIELDS: tuple[str, ...] = ("candidate", "success", "failure_reason")
# A diagnostic that is None was never measured and is left out of the entry; ``failed_at`` is
# written even when None, since there None means the attempt succeeded.
_WRITTEN_WHEN_NONE = frozenset({"failed_at"})


@dataclass(frozen=True)
class PlannerPrediction:
    """What the planner claimed for a grasp before it was executed."""

    reachable: bool  # always True: only grasps with an IK solution are ranked
    collision_free: bool  # the planner checked the whole motion and the swept hand (the grasp has a joint path)
    clearance_m: float | None  # swept hand's clearance to the cloud (m); None where not checked


@dataclass
class AttemptDiagnostics:
    """Measurements of one executed grasp, in the order execution takes them. None: not measured,
    because the attempt ended before that step or the step belongs to labelling (``shake``)."""

    ik_fallback: str | None = None  # why the planner's joints were not executed ("no planned path" | "planned joints miss a waypoint in PyBullet"); None when they were
    ik_source: str | None = None  # whose joints were executed: "planner" | "pybullet" | "panda_ik"
    descent_tracking_error_rad: float | None = None  # largest arm-joint deviation from a descent waypoint when its steps ended (rad)
    fingers_touching_after_close: bool | None = None  # both finger pads touched the object when the close ended
    finger_width_after_close_m: float | None = None  # distance between the fingers after the close (m)
    planned_width_m: float | None = None  # the grasp's planned contact width (m), against which the closed width tells a squeeze from a blocked finger
    object_motion_during_closing_linear: float | None = None  # labelling: object's world displacement over the close (m)
    object_motion_during_closing_angular: float | None = None  # labelling: object's world rotation over the close (rad)
    lift_tracking_error_rad: float | None = None  # largest arm-joint deviation from a lift waypoint when its steps ended (rad)
    object_motion_during_shaking_linear: float | None = None  # labelling: object's displacement relative to the hand over the shake (m)
    object_motion_during_shaking_angular: float | None = None  # labelling: object's rotation relative to the hand over the shake (rad)
    shake_achieved_peak_accelerations: tuple[float, ...] | None = None  # labelling: peaks the hand reached along x, y, z (m/s^2) then about them (rad/s^2)
    failed_at: str | None = None  # phase it failed in: "plan" | "pregrasp" | "descent" | "close" | "lift" | "shake"; None on success
    distractors_max_displacement_m: float | None = None  # largest distractor movement over the attempt (m; 0 without distractors)
    object_height_above_table_m: float | None = None  # object's centre of mass above the table top when the attempt ended (m)
    collision_links: list[str] | None = None  # on a collision only: "robot link->body" of every contact (body: table, target, distractor_<i>)
    candidate_index: int | None = None  # rank of the grasp in the method's ranking (0 = best), set by execute_ranked
    predicted: PlannerPrediction | None = None  # the planner's claim for the grasp, set by execute_ranked

    def record(self) -> dict[str, Any]:
        """The diagnostics as an attempt-log entry writes them: declared order, unmeasured ones left out."""
        return {name: value for name, value in dataclasses.asdict(self).items() if value is not None or name in _WRITTEN_WHEN_NONE}


# Every field an attempt-log entry can hold, in order.
ATTEMPT_RECORD_FIELDS: tuple[str, ...] = ATTEMPT_OUTCOME_FIELDS + tuple(field.name for field in dataclasses.fields(AttemptDiagnostics))
