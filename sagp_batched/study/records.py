"""A trial's identity and its record: one typed value per (object, task, method, trial).

The record is built in one place (``TrialRecord.build``) from typed results (the planning
summary, the grasps executed with their attempts, the grasp's placement, the task outcome) and
serialised once (``TrialRecord.to_json``) into a line of ``trials.jsonl``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import math

from ..config import Config
from ..grasps import Grasp
from ..seeds import candidate_seed, scene_seed
from ..types import METHODS, TASKS, GraspAttempt
from ..world.objects import ObjectSpec
from .judging import GraspPlacement, TaskOutcome

PLAN_COUNTS: tuple[str, ...] = ("sampled", "antipodal", "collision_free", "ik_feasible")
STAGE_TIMES: tuple[str, ...] = ("perception", "geometry", "rating", "total_plan")


@dataclass(frozen=True)
class TrialUnit:
    """One (object, task, trial) and the methods run on it: they share its scene, cloud and candidates."""

    object_id: str
    task: str
    trial: int
    methods: tuple[str, ...]

    def keys(self) -> list[tuple[str, str, str, int]]:
        return [(self.object_id, self.task, method, self.trial) for method in self.methods]


def record_key(record: dict[str, Any]) -> tuple[str, str, str, int]:
    """The (object, task, method, trial) a serialised record belongs to."""
    return (record["object"], record["task"], record["method"], int(record["trial"]))


@dataclass(frozen=True)
class PlanSummary:
    """What a method's plan cost and found: candidate counts per stage, stage times, the rating used."""

    counts: dict[str, int | None]
    times_s: dict[str, float]  # keys STAGE_TIMES
    rating: dict[str, Any]  # the rating's provenance


@dataclass(frozen=True)
class ExecutedGrasps:
    """The leading grasps of a method's ranking that were executed, each with its attempt, in order."""

    grasps: list[Grasp]
    attempts: list[GraspAttempt]
    placement: GraspPlacement  # of the final (last executed) grasp
    outcome: TaskOutcome
    frames: dict[str, str] | None = None  # saved images of the attempts, paths relative to the run


@dataclass(frozen=True)
class TrialRecord:
    """One method's result on one (object, task, trial): its identity, what planning found and
    cost, and what execution did, or why it never got there (``failure_reason``, ``error``)."""

    object: str
    category: str
    asymmetric: bool
    task: str
    method: str
    trial: int
    seed: int
    candidate_seed: int
    plan: PlanSummary | None = None
    executed: ExecutedGrasps | None = None
    failure_reason: str | None = None
    error: str | None = None
    traceback: str | None = None
    skipped: bool = False

    @classmethod
    def build(
        cls,
        spec: ObjectSpec,
        unit: TrialUnit,
        method: str,
        config: Config,
        plan: PlanSummary | None = None,
        executed: ExecutedGrasps | None = None,
        failure_reason: str | None = None,
        error: str | None = None,
        traceback: str | None = None,
    ) -> "TrialRecord":
        """The record of ``method`` on ``unit``: a failure before execution gives ``failure_reason``
        (or ``error``, for an exception) and no ``executed``."""
        if executed is not None:
            failure_reason = executed.attempts[-1].failure_reason
        return cls(
            object=spec.id, category=spec.category, asymmetric=spec.asymmetric, task=unit.task, method=method,
            trial=unit.trial, seed=scene_seed(config, unit.trial), candidate_seed=candidate_seed(config, unit.trial),
            plan=plan, executed=executed, failure_reason=failure_reason, error=error, traceback=traceback,
        )

    def to_json(self) -> dict[str, Any]:
        """The record as one JSON object of ``trials.jsonl``."""
        record: dict[str, Any] = {
            "object": self.object, "category": self.category, "asymmetric": self.asymmetric, "task": self.task,
            "method": self.method, "trial": self.trial, "seed": self.seed, "candidate_seed": self.candidate_seed,
            "success": False, "task_success": False, "attempts": 0, "attempt_log": [], "grasp": None,
            "failure_reason": self.failure_reason, "in_preferred_zone": None, "in_avoid_zone": None,
            "in_functional_region": None, "in_avoid_region": None, "orientation_change_deg": None,
            "orientation_kept": None, "distractors_max_displacement_m": None,
            "n_candidates": dict.fromkeys(PLAN_COUNTS), "times_s": dict.fromkeys(STAGE_TIMES), "rating": None,
            "skipped": self.skipped, "error": self.error,
        }
        if self.traceback is not None:
            record["traceback"] = self.traceback
        if self.plan is not None:
            record["n_candidates"] = {key: self.plan.counts.get(key) for key in PLAN_COUNTS}
            record["times_s"] = dict(self.plan.times_s)
            record["rating"] = self.plan.rating
        if self.executed is not None:
            record.update(_executed_fields(self.executed))
        return record


def _executed_fields(executed: ExecutedGrasps) -> dict[str, Any]:
    final = executed.attempts[-1]
    placement, outcome = executed.placement, executed.outcome
    fields = {
        "attempts": len(executed.attempts),
        "attempt_log": [attempt.record(grasp.candidate_id) for grasp, attempt in zip(executed.grasps, executed.attempts)],
        "grasp": {**executed.grasps[len(executed.attempts) - 1].record(), "midpoint_object": placement.midpoint_object},
        "success": bool(final.success),
        "in_preferred_zone": placement.in_preferred_zone,
        "in_avoid_zone": placement.in_avoid_zone,
        "in_functional_region": placement.in_functional_region,
        "in_avoid_region": placement.in_avoid_region,
        "orientation_change_deg": outcome.orientation_change_deg,
        "orientation_kept": outcome.orientation_kept,
        "distractors_max_displacement_m": outcome.distractors_max_displacement_m,
        "task_success": outcome.task_success,
    }
    if executed.frames is not None:
        fields["frames"] = executed.frames
    return fields


# --- the record's schema: what ``TrialRecord.to_json`` writes, checked on every line read back -----

_OPTIONAL_BOOL = (bool, type(None))
_OPTIONAL_NUMBER = (int, float, type(None))
_OPTIONAL_TEXT = (str, type(None))
# Every key of a record and the JSON types its value may take (bool is not accepted as an int).
RECORD_FIELDS: dict[str, tuple[type, ...]] = {
    "object": (str,), "category": (str,), "asymmetric": (bool,), "task": (str,), "method": (str,),
    "trial": (int,), "seed": (int,), "candidate_seed": (int,), "success": (bool,), "task_success": (bool,),
    "attempts": (int,), "attempt_log": (list,), "grasp": (dict, type(None)), "failure_reason": _OPTIONAL_TEXT,
    "in_preferred_zone": _OPTIONAL_BOOL, "in_avoid_zone": _OPTIONAL_BOOL, "in_functional_region": _OPTIONAL_BOOL,
    "in_avoid_region": _OPTIONAL_BOOL, "orientation_change_deg": _OPTIONAL_NUMBER, "orientation_kept": _OPTIONAL_BOOL,
    "distractors_max_displacement_m": _OPTIONAL_NUMBER, "n_candidates": (dict,), "times_s": (dict,),
    "rating": (dict, type(None)), "skipped": (bool,), "error": _OPTIONAL_TEXT,
}
OPTIONAL_RECORD_FIELDS: dict[str, tuple[type, ...]] = {"traceback": (str,), "frames": (dict,)}
ATTEMPT_FIELDS: dict[str, tuple[type, ...]] = {"candidate": (int,), "success": (bool,), "failure_reason": _OPTIONAL_TEXT}


def _type_problem(where: str, value: Any, allowed: tuple[type, ...]) -> str | None:
    if isinstance(value, bool) and bool not in allowed:
        return f"{where} is a boolean"
    if not isinstance(value, allowed):
        return f"{where} is {type(value).__name__}, not {' or '.join('null' if t is type(None) else t.__name__ for t in allowed)}"
    if isinstance(value, float) and not math.isfinite(value):
        return f"{where} is not finite"
    return None


def record_problem(record: Any) -> str | None:
    """Why ``record`` (a parsed line of ``trials.jsonl``) is not a trial record, or None if it is one.

    A record has exactly the keys ``to_json`` writes with their types, names a known task and method,
    and is consistent with itself: a success is a held final attempt, an error executed nothing."""
    if not isinstance(record, dict):
        return f"a JSON {type(record).__name__}, not an object"
    missing = [key for key in RECORD_FIELDS if key not in record]
    if missing:
        return f"missing {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}"
    unknown = [key for key in record if key not in RECORD_FIELDS and key not in OPTIONAL_RECORD_FIELDS]
    if unknown:
        return f"unknown key {unknown[0]!r}"
    for key, value in record.items():
        problem = _type_problem(key, value, RECORD_FIELDS.get(key) or OPTIONAL_RECORD_FIELDS[key])
        if problem:
            return problem
    if record["task"] not in TASKS or record["method"] not in METHODS:
        return f"unknown task {record['task']!r} or method {record['method']!r}"
    if record["trial"] < 0:
        return "trial is negative"
    if set(record["n_candidates"]) != set(PLAN_COUNTS) or set(record["times_s"]) != set(STAGE_TIMES):
        return "n_candidates or times_s does not hold the stage keys"
    attempt_log = record["attempt_log"]
    for number, attempt in enumerate(attempt_log):
        if not isinstance(attempt, dict):
            return f"attempt {number} is not an object"
        for key, allowed in ATTEMPT_FIELDS.items():
            if key not in attempt:
                return f"attempt {number} has no {key}"
            problem = _type_problem(f"attempt {number} {key}", attempt[key], allowed)
            if problem:
                return problem
    if record["attempts"] != len(attempt_log):
        return f"attempts is {record['attempts']} but the attempt log holds {len(attempt_log)}"
    if record["success"] and not (attempt_log and attempt_log[-1]["success"] and record["grasp"] is not None):
        return "success without a held final attempt and its grasp"
    if record["task_success"] and not record["success"]:
        return "task success without grasp success"
    if record["error"] is not None and (attempt_log or record["success"]):
        return "an error record with executed attempts"
    return None
