"""Every output of a run is written by the driver: a unit's files before its records, workers' memory beside them."""
from __future__ import annotations

import json
import os

import pytest

import sagp_batched.study.study_run as study
from sagp_batched.config import load_config
from sagp_batched.run_directory import WORKERS_FILE, RunDirectoryError
from sagp_batched.runtime import resident_memory_bytes
from sagp_batched.study.experiment import UnitResult, grasps_file
from sagp_batched.study.records import TrialRecord
from sagp_batched.study.trials_file import TRIALS_FILE, TrialWriter
from sagp_batched.world.objects import load_object_set
from sagp_batched.workers import Recipe, ReportingWorker

OBJECTS = load_object_set()
SPEC = OBJECTS.get("005_tomato_soup_can")


def _frame(unit, method):
    return f"frames/{unit.object_id}_{unit.task}_{method}_{unit.trial:04d}_contact.png"


class _FileMakingRunner:
    """Stands in for the PyBullet trial runner: each unit returns a grasp export and one image per method,
    as bytes, the way a worker's TrialRunner does."""

    def __init__(self, config, objects):
        self.config = config

    def run_unit(self, unit):
        files = {grasps_file(unit.object_id, unit.task, unit.trial): f"h5 of trial {unit.trial}".encode()}
        records = []
        for method in unit.methods:
            files[_frame(unit, method)] = f"png {method} {unit.trial}".encode()
            records.append(TrialRecord.build(SPEC, unit, method, self.config, failure_reason="no_candidates"))
        return UnitResult(records, files)


def _config(out, **run):
    # One worker, so the units run in this process, where the test's runner is patched in.
    return load_config("ci", overrides={"run": {"objects": [SPEC.id], "tasks": ["t1"], "methods": ["go", "sagp"], "n_trials": 3,
                                                 "workers": 1, "out": str(out), **run}})


def test_the_driver_writes_each_units_files_before_the_records_that_name_them(tmp_path, monkeypatch):
    monkeypatch.setattr(study, "TrialRunner", _FileMakingRunner)
    written_before_record = []
    original_write = TrialWriter.write

    def checking_write(self, record):
        unit_files = [grasps_file(record["object"], record["task"], record["trial"]),
                      f"frames/{record['object']}_{record['task']}_{record['method']}_{record['trial']:04d}_contact.png"]
        written_before_record.append(all((tmp_path / name).is_file() for name in unit_files))
        original_write(self, record)

    monkeypatch.setattr(TrialWriter, "write", checking_write)
    result = study.run_study(_config(tmp_path), OBJECTS, ["go", "sagp"], progress=False)
    assert result.new_records == 6 and written_before_record == [True] * 6
    assert sorted(p.name for p in (tmp_path / "grasps").iterdir()) == [f"{SPEC.id}_t1_{t:04d}.h5" for t in range(3)]
    assert (tmp_path / "grasps" / f"{SPEC.id}_t1_0002.h5").read_bytes() == b"h5 of trial 2"
    assert (tmp_path / "frames" / f"{SPEC.id}_t1_sagp_0001_contact.png").read_bytes() == b"png sagp 1"
    leftovers = [p.name for p in tmp_path.rglob("*") if p.name.endswith(".tmp")]
    assert leftovers == [], "every file is renamed into place whole"
    assert not (tmp_path / WORKERS_FILE).exists(), "an inline run has no worker processes to report"


def test_a_worker_file_that_would_leave_the_run_directory_is_refused(tmp_path, monkeypatch):
    class EscapingRunner(_FileMakingRunner):
        def run_unit(self, unit):
            result = super().run_unit(unit)
            result.files["../outside.h5"] = b"x"
            return result

    monkeypatch.setattr(study, "TrialRunner", EscapingRunner)
    with pytest.raises(RunDirectoryError, match="not a path inside"):
        study.run_study(_config(tmp_path / "run", n_trials=1), OBJECTS, ["go", "sagp"], progress=False)
    assert not (tmp_path / "outside.h5").exists()
    assert not (tmp_path / "run" / TRIALS_FILE).read_text(), "no record is written without its files"


def test_a_worker_reports_its_memory_after_every_unit_and_the_driver_logs_one_line_each(tmp_path, monkeypatch):
    monkeypatch.setattr(study, "TrialRunner", _FileMakingRunner)
    config = _config(tmp_path)
    worker = ReportingWorker(Recipe(study._Worker, (config, OBJECTS, "/objects/here")))
    units = study.plan_units(config, OBJECTS, ["go", "sagp"])
    reports = [worker.run(unit)[1] for unit in units]
    assert [r.units_done for r in reports] == [1, 2, 3] and {r.pid for r in reports} == {os.getpid()}
    assert all(r.rss_bytes > 10_000_000 and r.unit_s >= 0 and r.objects_dir == "/objects/here" for r in reports)

    class ReportingPool:  # a pool of that one worker, run in this process
        def __init__(self, *args, **kwargs):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *exc_info):
            pass

        def as_finished(self, units):
            for unit in units:
                yield (unit, *worker.run(unit))

    monkeypatch.setattr(study, "WorkerPool", ReportingPool)
    study.run_study(config, OBJECTS, ["go", "sagp"], progress=False)
    lines = [json.loads(line) for line in (tmp_path / WORKERS_FILE).read_text().splitlines()]
    assert [line["units_done"] for line in lines] == [4, 5, 6]
    assert all({"pid", "node", "units_done", "rss_bytes", "unit_s", "objects_dir", "time"} <= set(line) for line in lines)
    assert all("units_done" not in line for line in (tmp_path / TRIALS_FILE).read_text().splitlines())


def test_resident_memory_is_this_processes_rss():
    with open("/proc/self/status") as status:
        vm_rss_kb = next(int(line.split()[1]) for line in status if line.startswith("VmRSS:"))
    assert abs(resident_memory_bytes() - vm_rss_kb * 1024) < 0.1 * vm_rss_kb * 1024
