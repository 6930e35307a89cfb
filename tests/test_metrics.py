"""Study metrics and their 95 % Wilson intervals."""
import pytest

from sagp_batched.statistics import wilson_interval
from sagp_batched.study.metrics import per_object, summarise


def test_wilson_interval_matches_the_textbook_values():
    low, high = wilson_interval(17, 20)
    assert low == pytest.approx(0.6396, abs=1e-4) and high == pytest.approx(0.9476, abs=1e-4)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0
    assert wilson_interval(0, 0) is None


def _record(method, success, zone, avoid, kept, category="containers", asymmetric=True, task="t2"):
    return {"object": "025_mug", "category": category, "asymmetric": asymmetric, "task": task, "method": method, "trial": 0,
            "success": success, "task_success": success and zone and kept, "in_preferred_zone": zone, "in_avoid_zone": avoid,
            "orientation_kept": kept, "times_s": {"total_plan": 0.2, "geometry": 0.15, "rating": 0.05}}


def test_zone_rates_count_only_successful_grasps_and_groups_split():
    records = [
        _record("sagp", True, True, False, True),
        _record("sagp", True, False, True, False),
        _record("sagp", False, True, False, True),
        _record("sagp", True, True, False, True, category="boxes", asymmetric=False),
    ]
    summary = summarise(records)["sagp"]["t2"]
    assert summary["all"]["n"] == 4 and summary["all"]["counts"]["GSR"] == [3, 4]
    assert summary["all"]["counts"]["PZA"] == [2, 3] and summary["all"]["counts"]["AC"] == [2, 3]
    assert summary["all"]["counts"]["OP"] == [2, 3] and summary["all"]["counts"]["TSR"] == [2, 4]
    assert summary["asymmetric"]["n"] == 3 and summary["near_symmetric"]["n"] == 1
    assert summary["boxes"]["GSR"] == 1.0 and summary["all"]["MPT_s"] == pytest.approx(0.2)


def test_skipped_records_are_left_out():
    records = [_record("go", True, True, False, True), {**_record("go", False, False, False, False), "skipped": True}]
    assert summarise(records)["go"]["t2"]["all"]["n"] == 1


def _attempt(success, reason=None, at=None, reachable=True, collision_free=True):
    return {"candidate": 0, "success": success, "failure_reason": reason, "failed_at": at,
            "predicted": {"reachable": reachable, "collision_free": collision_free, "clearance_m": 0.01}}


def _trial(attempts, method="sagp", obj="025_mug", task="t1", **extra):
    return {"object": obj, "category": "containers", "asymmetric": True, "task": task, "method": method, "trial": 0,
            "success": bool(attempts) and attempts[-1]["success"], "task_success": bool(attempts) and attempts[-1]["success"],
            "failure_reason": None if attempts and attempts[-1]["success"] else "no_candidates", "error": None,
            "skipped": False, "attempts": len(attempts), "attempt_log": attempts, **extra}


def test_fas_counts_only_the_first_attempt_while_gsr_counts_a_later_success():
    records = [_trial([_attempt(False, "collision", "descent"), _attempt(True)]), _trial([_attempt(True)])]
    metrics = summarise(records)["sagp"]["t1"]["all"]
    assert metrics["counts"]["GSR"] == [2, 2] and metrics["counts"]["FAS"] == [1, 2]
    assert metrics["FAS"] == 0.5 and metrics["ci95"]["FAS"] == pytest.approx(wilson_interval(1, 2))


def test_trials_without_attempts_are_left_out_of_the_fas_denominator_but_not_gsr():
    no_attempt_trial = {k: v for k, v in _trial([]).items() if k != "attempt_log"}
    records = [_trial([_attempt(True)]), _trial([]), no_attempt_trial]
    metrics = summarise(records)["sagp"]["t1"]["all"]
    assert metrics["counts"]["GSR"] == [1, 3] and metrics["counts"]["FAS"] == [1, 1]


def test_error_trials_are_counted_apart_from_failed_grasps_and_left_out_of_every_rate():
    records = [_trial([_attempt(True)]), _trial([], error="TrialTimeout: 300 s"), _trial([_attempt(False, "slipped", "lift")])]
    metrics = summarise(records)["sagp"]["t1"]["all"]
    assert metrics["n"] == 2 and metrics["errors"] == 1
    assert metrics["counts"]["GSR"] == [1, 2] and metrics["counts"]["TSR"] == [1, 2] and metrics["counts"]["FAS"] == [1, 2]


def test_neutral_ratings_are_counted_per_method_and_task_with_their_reasons():
    neutral = {"backend": "openai", "outcome": "neutral", "issues": ["no JSON object in the answer"]}
    rated = {"backend": "openai", "outcome": "ok", "issues": []}
    records = [_trial([_attempt(True)], rating=neutral), _trial([_attempt(True)], rating=neutral),
               _trial([_attempt(True)], rating=rated), _trial([_attempt(True)], method="go", rating=rated)]
    summary = summarise(records)
    assert summary["sagp"]["t1"]["all"]["neutral_ratings"] == 2
    assert summary["sagp"]["t1"]["all"]["neutral_rating_reasons"] == {"no JSON object in the answer": 2}
    assert summary["go"]["t1"]["all"]["neutral_ratings"] == 0


def test_attempt_failures_count_reason_at_stage_across_records_and_unknown_stage_for_old_records():
    old_attempt = {"candidate": 3, "success": False, "failure_reason": "slipped"}
    records = [
        _trial([_attempt(False, "collision", "descent"), _attempt(False, "unreachable", "plan"), _attempt(True)]),
        _trial([_attempt(False, "collision", "descent"), old_attempt]),
    ]
    metrics = summarise(records)["sagp"]["t1"]["all"]
    assert metrics["attempt_failures"] == {"collision@descent": 2, "slipped@unknown": 1, "unreachable@plan": 1}
    assert metrics["n_attempts"] == 5


def test_prediction_mismatches_count_only_failed_attempts_the_planner_predicted_feasible():
    records = [_trial([
        _attempt(False, "collision", "descent"),
        _attempt(False, "unreachable", "plan", reachable=False),
        _attempt(False, "collision", "pregrasp", collision_free=False),
        {"candidate": 4, "success": False, "failure_reason": "slipped"},
        _attempt(True),
    ])]
    assert summarise(records)["sagp"]["t1"]["all"]["prediction_mismatches"] == 1


def test_per_object_splits_method_task_by_object_and_leaves_out_skipped_records():
    records = [
        _trial([_attempt(True)], obj="025_mug"),
        _trial([_attempt(False, "slipped", "lift")], obj="003_cracker_box"),
        {**_trial([_attempt(True)], obj="003_cracker_box"), "skipped": True},
        _trial([_attempt(True)], obj="025_mug", method="go", task="t2"),
    ]
    by_object = per_object(records)
    assert sorted(by_object["sagp"]["t1"]) == ["003_cracker_box", "025_mug"]
    assert by_object["sagp"]["t1"]["003_cracker_box"]["n"] == 1
    assert by_object["sagp"]["t1"]["003_cracker_box"]["attempt_failures"] == {"slipped@lift": 1}
    assert by_object["go"]["t2"]["025_mug"]["counts"]["FAS"] == [1, 1]
