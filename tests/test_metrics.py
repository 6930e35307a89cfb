"""Study metrics and their 95 % Wilson intervals."""
import pytest

from sagp_batched.metrics import summarise, wilson_interval


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
