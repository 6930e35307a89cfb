"""Study metrics (the published protocol) over trial records, with 95 % Wilson intervals.

Definitions, per method x task x group:
- n: trials that ran to an outcome; ``errors``: trials whose record is an error (an exception or the
  time limit), counted apart and left out of every rate, since they say nothing of a grasp.
- GSR: grasp success rate, the object lifted and held (the T1 criterion) over the trials that ran.
- FAS: first-attempt success, trials whose first executed attempt lifted the object, over the trials
  that executed at least one attempt (errors, perception failures and "no_candidates" trials are
  left out of its denominator, unlike GSR's), so it measures the ranking's top choice, not the retries.
- TSR: task success rate, GSR plus the task's own conditions (t2: preferred zone and orientation
  kept; t3: no distractor moved more than 5 cm). Reported beside GSR so t2/t3 stay comparable to t1.
- PZA, AC, OP: over successful grasps, the fraction in a preferred zone, outside every avoid zone,
  and keeping the object within 15 deg of its resting orientation. PZA and AC judge a grasp by the
  pipeline's own zones (and its rater's choice of them).
- FRA, FAR: the same question asked of the object itself (``functional_regions.json``): over successful
  grasps on annotated objects (``in_functional_region`` not None), the fraction whose contact midpoint
  lies in the object's functional region (FRA: mug handle, drill grip, ...) and in its avoid region
  (FAR: mug rim, drill chuck, ...; lower is better). Grasps on objects without an annotation are left
  out of both denominators.
- MPT_s: mean planning time per trial (perception excluded), with the rating model's mean time
  reported separately as ``rating_s`` and geometry as ``geometry_s``.
- n_attempts: executed attempts over the group's trials; attempt_failures: failed attempts by
  "reason@stage" (e.g. "collision@descent"; "unknown" where a record predates the field);
  prediction_mismatches: failed attempts the planner had predicted reachable and collision-free,
  where planner and robot disagree.
"""
from __future__ import annotations

from collections import Counter, defaultdict
from typing import Any, Callable, Iterable

from ..statistics import wilson_interval


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


def groups_of(record: dict[str, Any]) -> list[str]:
    groups = ["all"]
    if record.get("category"):
        groups.append(record["category"])
    groups.append("asymmetric" if record.get("asymmetric") else "near_symmetric")
    return groups


def failure_key(attempt: dict[str, Any]) -> str:
    """'reason@stage' of a failed attempt, 'unknown' for what an older record did not log."""
    return f"{attempt.get('failure_reason') or 'unknown'}@{attempt.get('failed_at') or 'unknown'}"


def _predicted_feasible(attempt: dict[str, Any]) -> bool:
    predicted = attempt.get("predicted") or {}
    return predicted.get("reachable") is True and predicted.get("collision_free") is True


def attempt_metrics(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per-attempt outcomes, so a failure's stage and the planner's prediction are visible beside the rates."""
    attempts = [a for r in records for a in r.get("attempt_log") or []]
    failed = [a for a in attempts if not a.get("success")]
    return {
        "n_attempts": len(attempts),
        "attempt_failures": dict(sorted(Counter(failure_key(a) for a in failed).items())),
        "prediction_mismatches": sum(1 for a in failed if _predicted_feasible(a)),
    }


# A neutral rating's reason is kept to this many characters in summaries (it may quote a model's answer).
NEUTRAL_REASON_MAX_CHARS = 120


def neutral_rating_reasons(records: list[dict[str, Any]]) -> dict[str, int]:
    """Reason -> count over the records whose zone rating was neutral (the rater gave no usable answer)."""
    reasons = Counter()
    for record in records:
        rating = record.get("rating") or {}
        if rating.get("outcome") == "neutral":
            issues = rating.get("issues") or ["no reason given"]
            reasons[str(issues[0])[:NEUTRAL_REASON_MAX_CHARS]] += 1
    return dict(sorted(reasons.items()))


def group_metrics(group: list[dict[str, Any]]) -> dict[str, Any]:
    """Metrics of one group of trial records; error records are counted apart, not as failed trials."""
    records = [r for r in group if not r.get("error")]
    n = len(records)
    lifted = [r for r in records if r.get("success")]
    attempted = [r for r in records if r.get("attempt_log")]
    first_lifted = [r for r in attempted if r["attempt_log"][0].get("success")]
    in_zone = [r for r in lifted if r.get("in_preferred_zone")]
    clear_of_avoid = [r for r in lifted if r.get("in_avoid_zone") is False]
    orientation_kept = [r for r in lifted if r.get("orientation_kept")]
    annotated = [r for r in lifted if r.get("in_functional_region") is not None]
    in_functional = [r for r in annotated if r["in_functional_region"]]
    in_avoid_region = [r for r in annotated if r.get("in_avoid_region")]
    task_done = [r for r in records if r.get("task_success")]
    times = [r.get("times_s") or {} for r in records]
    counts = {
        "GSR": (len(lifted), n),
        "FAS": (len(first_lifted), len(attempted)),
        "TSR": (len(task_done), n),
        "PZA": (len(in_zone), len(lifted)),
        "AC": (len(clear_of_avoid), len(lifted)),
        "OP": (len(orientation_kept), len(lifted)),
        "FRA": (len(in_functional), len(annotated)),
        "FAR": (len(in_avoid_region), len(annotated)),
    }
    return {
        "n": n,
        "errors": len(group) - n,
        "neutral_ratings": sum(neutral_rating_reasons(group).values()),
        "neutral_rating_reasons": neutral_rating_reasons(group),
        **{name: (k / total if total else None) for name, (k, total) in counts.items()},
        "counts": {name: list(kn) for name, kn in counts.items()},
        "ci95": {name: wilson_interval(k, total) for name, (k, total) in counts.items()},
        "MPT_s": _mean([t["total_plan"] for t in times if t.get("total_plan") is not None]),
        "geometry_s": _mean([t["geometry"] for t in times if t.get("geometry") is not None]),
        "rating_s": _mean([t["rating"] for t in times if t.get("rating") is not None]),
        **attempt_metrics(records),
    }


def _by_method_and_task(records: Iterable[dict[str, Any]], keys_of: Callable[[dict[str, Any]], list[str]]) -> dict[str, Any]:
    """method -> task -> key -> metrics over records that were actually run (not skipped); a record
    counts under every key that ``keys_of`` gives it."""
    buckets: dict[str, dict[str, dict[str, list]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for record in records:
        if record.get("skipped"):
            continue
        for key in keys_of(record):
            buckets[record["method"]][record["task"]][key].append(record)
    return {
        method: {task: {key: group_metrics(rs) for key, rs in sorted(by_key.items())} for task, by_key in sorted(by_task.items())}
        for method, by_task in sorted(buckets.items())
    }


def summarise(records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """method -> task -> group -> metrics, over records that were actually run (not skipped)."""
    return _by_method_and_task(records, groups_of)


def per_object(records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """method -> task -> object id -> metrics, over records that were actually run (not skipped)."""
    return _by_method_and_task(records, lambda record: [record["object"]])
