"""The study summary's markdown tables: FAS beside GSR, failed attempts by reason@stage, per-object rows."""
from sagp_batched.study.metrics import per_object, summarise
from sagp_batched.study.study_report import summary_markdown


def _attempt(success, reason=None, at=None, feasible=True):
    return {"candidate": 0, "success": success, "failure_reason": reason, "failed_at": at,
            "predicted": {"reachable": feasible, "collision_free": True, "clearance_m": 0.01}}


def _trial(method, obj, attempts):
    return {"object": obj, "category": "containers", "asymmetric": True, "task": "t1", "method": method, "trial": 0,
            "success": attempts[-1]["success"], "task_success": attempts[-1]["success"], "failure_reason": attempts[-1]["failure_reason"],
            "error": None, "skipped": False, "attempts": len(attempts), "attempt_log": attempts}


RECORDS = [
    _trial("sagp", "025_mug", [_attempt(False, "collision", "descent"), _attempt(True)]),
    _trial("sagp", "003_cracker_box", [_attempt(False, "collision", "descent"), _attempt(False, "unreachable", "plan", feasible=False)]),
    _trial("go", "025_mug", [_attempt(True)]),
]


def _table_after(markdown, heading):
    lines = markdown.splitlines()
    start = lines.index(heading) + 2
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    return lines[start:end]


def test_main_table_puts_fas_next_to_gsr_with_counts_and_interval():
    table = _table_after(summary_markdown(summarise(RECORDS), {}), "## Task t1")
    assert table[0].startswith("| method | trials | errors | GSR | FAS | TSR |")
    sagp = next(row for row in table if row.startswith("| SAGP |")).split(" | ")
    assert sagp[1:3] == ["2", "0"]
    assert sagp[3].startswith("1/2 (50.0 %, ") and sagp[4].startswith("0/2 (0.0 %, 0.0-")


def test_failure_table_has_a_column_per_reason_at_stage_and_counts_per_method():
    table = _table_after(summary_markdown(summarise(RECORDS), {}), "### Task t1 failed attempts")
    assert table[0] == "| method | collision@descent | unreachable@plan | prediction mismatches | attempts |"
    assert "| Geometry-Only | 0 | 0 | 0 | 1 |" in table
    assert "| SAGP | 2 | 1 | 2 | 4 |" in table


def test_per_object_table_lists_fas_gsr_and_failed_attempts_per_method():
    markdown = summary_markdown(summarise(RECORDS), {}, by_object=per_object(RECORDS))
    table = _table_after(markdown, "### Task t1 by object (FAS / GSR / failed attempts)")
    assert table[0] == ("| object | Geometry-Only FAS | Geometry-Only GSR | Geometry-Only failed attempts "
                        "| SAGP FAS | SAGP GSR | SAGP failed attempts |")
    rows = {row.split(" | ")[0]: row.split(" | ") for row in table[2:]}
    assert list(rows) == ["| 003_cracker_box", "| 025_mug"]
    box, mug = rows["| 003_cracker_box"], rows["| 025_mug"]
    assert box[1:4] == ["-", "-", "-"]
    assert box[4].startswith("0/1 ") and box[5].startswith("0/1 ") and box[6] == "collision@descent×1, unreachable@plan×1 |"
    assert mug[1].startswith("1/1 ") and mug[3] == "-"
    assert mug[4].startswith("0/1 ") and mug[5].startswith("1/1 ") and mug[6] == "collision@descent×1 |"


def test_per_object_tables_are_left_out_without_by_object():
    assert "by object" not in summary_markdown(summarise(RECORDS), {})
