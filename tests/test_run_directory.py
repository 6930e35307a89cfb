"""A run directory never loses, mixes or freezes a record: torn and invalid lines are set aside and
their trials run again, a full disk stops the run with nothing torn, one process writes a directory,
a changed object set is refused, and error trials run again on resume."""
import errno
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from runners import batch
from sagp_batched.config import load_config
from sagp_batched.run_directory import RunDirectoryBusy, RunLock
from sagp_batched.study.experiment import UnitResult
from sagp_batched.study.records import TrialRecord, TrialUnit, record_problem
from sagp_batched.study.study_run import run_study
from sagp_batched.study.trials_file import REJECTED_FILE, TRIALS_FILE, TrialWriteError, TrialWriter, read_records, recover_trials_file
from sagp_batched.world.objects import load_object_set

OBJECTS = load_object_set(None)  # the embedded set: every test here names it the same way
SPEC = OBJECTS.get("005_tomato_soup_can")


def _record(trial=0, method="go", **build):
    config = load_config("ci")
    unit = TrialUnit(SPEC.id, "t1", trial, (method,))
    return TrialRecord.build(SPEC, unit, method, config, **({"failure_reason": "no_candidates"} | build)).to_json()


def _lines(*records):
    return "".join(json.dumps(r, sort_keys=True) + "\n" for r in records)


def test_a_torn_last_line_is_set_aside_and_the_next_record_starts_on_a_line_of_its_own(tmp_path):
    path = tmp_path / TRIALS_FILE
    path.write_text(_lines(_record(0), _record(1)) + json.dumps(_record(2))[:57])
    recovered = recover_trials_file(path)
    assert [r["trial"] for r in recovered.records] == [0, 1]
    assert [line.reason.split(":")[0] for line in recovered.rejected] == ["torn line"]
    writer = TrialWriter(path)
    writer.write(_record(2))
    writer.close()
    assert [r["trial"] for r in read_records(path)] == [0, 1, 2]
    assert path.read_bytes().endswith(b"\n") and path.read_text().count("\n") == 3
    (rejected,) = [json.loads(line) for line in (tmp_path / REJECTED_FILE).read_text().splitlines()]
    assert rejected["line"] == 3 and rejected["text"] == json.dumps(_record(2))[:57]


HOSTILE_LINES = {
    "an object of another shape": '{"foo": 1}',
    "a JSON array": "[1, 2, 3]",
    "a trial that is not a number": json.dumps({**_record(0), "trial": "x"}),
    "a minimal forged success": json.dumps({"object": "005_tomato_soup_can", "trial": 1, "success": True}),
    "a success without a held attempt": json.dumps({**_record(0), "success": True}),
    "an unknown method": json.dumps({**_record(0), "method": "magic"}),
    "a boolean trial": json.dumps({**_record(0), "trial": True}),
    "a negative trial": json.dumps({**_record(0), "trial": -1}),
    "an unknown key": json.dumps({**_record(0), "extra": 1}),
    "attempts that disagree with the log": json.dumps({**_record(0), "attempts": 2}),
    "not JSON": "trial 3 went fine",
    "nested past the parser's depth": "[" * 100_000 + "]" * 100_000,
    "an infinite time": json.dumps({**_record(0), "orientation_change_deg": float("inf")}),
}


@pytest.mark.parametrize("case", sorted(HOSTILE_LINES))
def test_a_line_that_is_not_a_trial_record_is_rejected_with_its_reason_and_never_counted(tmp_path, case):
    path = tmp_path / TRIALS_FILE
    path.write_text(_lines(_record(0)) + HOSTILE_LINES[case] + "\n" + _lines(_record(2)))
    recovered = recover_trials_file(path)
    assert sorted(r["trial"] for r in recovered.records) == [0, 2]
    assert len(recovered.rejected) == 1 and recovered.rejected[0].line_number == 2 and recovered.rejected[0].reason
    assert [r["trial"] for r in read_records(path)] == [0, 2], "the rejected line is moved out of the trials file"
    assert len((tmp_path / REJECTED_FILE).read_text().splitlines()) == 1


def test_a_line_that_is_not_utf8_is_rejected(tmp_path):
    path = tmp_path / TRIALS_FILE
    path.write_bytes(_lines(_record(0)).encode() + b"\xff\xfe{}\n")
    assert recover_trials_file(path).rejected[0].reason == "not UTF-8"


def test_every_record_a_trial_builds_passes_the_schema():
    assert record_problem(_record(0)) is None
    assert record_problem(_record(0, error="TrialTimeout: 1 s")) is None


def test_a_failed_write_is_cut_back_to_the_last_whole_line_and_stops_with_one_line(tmp_path, monkeypatch):
    path = tmp_path / TRIALS_FILE
    writer = TrialWriter(path)
    writer.write(_record(0))
    real_fsync = os.fsync

    def full_disk(descriptor):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(TrialWriteError, match="No space left on device") as raised:
        writer.write(_record(1))
    assert "\n" not in str(raised.value)
    writer.close()
    monkeypatch.setattr(os, "fsync", real_fsync)
    resumed = TrialWriter(path)  # once the disk has room again, the run resumes onto whole lines
    resumed.write(_record(2))
    resumed.close()
    assert [r["trial"] for r in read_records(path)] == [0, 2] and not recover_trials_file(path).rejected


@pytest.fixture
def tiny_disk(tmp_path):
    """A 16 KiB tmpfs, where the machine lets this process mount one (root on Linux)."""
    mount_point = tmp_path / "tiny"
    mount_point.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16k", "tmpfs", str(mount_point)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    yield mount_point
    subprocess.run(["umount", str(mount_point)], check=True)


def test_a_full_disk_stops_the_writer_with_every_written_record_whole(tiny_disk):
    path = tiny_disk / TRIALS_FILE
    writer = TrialWriter(path)
    written = 0
    with pytest.raises(TrialWriteError, match="No space left on device"):
        for trial in range(1000):
            writer.write(_record(trial, error="x" * 500))
            written += 1
    writer.close()
    assert written > 0
    assert [r["trial"] for r in read_records(path)] == list(range(written))
    assert path.read_bytes().endswith(b"\n")


def test_a_second_lock_on_a_run_directory_is_refused_while_the_first_is_held(tmp_path):
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import sys, time
        from pathlib import Path
        from sagp_batched.run_directory import RunLock
        with RunLock(Path({str(tmp_path)!r})):
            print("locked", flush=True)
            time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(RunDirectoryBusy, match=f"in use by another run \\(pid {holder.pid}\\)"):
            with RunLock(tmp_path):
                pass
    finally:
        holder.kill()
        holder.wait()
    with RunLock(tmp_path):  # the kernel released the killed holder's lock
        pass


class _ScriptedRunner:
    """Stands in for the PyBullet trial runner: each unit's record is an error while ``failing`` holds
    its trial, else a plain no-candidates result, so resume logic runs without simulation."""

    failing: set[int] = set()
    ran: list[int] = []

    def __init__(self, config, objects):
        self.config = config

    def run_unit(self, unit):
        _ScriptedRunner.ran.append(unit.trial)
        outcome = {"error": "RuntimeError: mesh missing"} if unit.trial in self.failing else {"failure_reason": "no_candidates"}
        return UnitResult([TrialRecord.build(SPEC, unit, method, self.config, **outcome) for method in unit.methods])


@pytest.fixture
def scripted_runner(monkeypatch):
    import sagp_batched.study.study_run as study

    monkeypatch.setattr(study, "TrialRunner", _ScriptedRunner)
    _ScriptedRunner.failing, _ScriptedRunner.ran = set(), []
    return _ScriptedRunner


def _study_config(out, **run):
    # One worker, so the trials run in this process, where the scripted runner is patched in.
    return load_config("ci", overrides={"run": {"objects": [SPEC.id], "tasks": ["t1"], "methods": ["go"], "n_trials": 3,
                                                 "workers": 1, "out": str(out), **run}})


def test_error_trials_run_again_on_resume_unless_kept(tmp_path, scripted_runner):
    scripted_runner.failing = {1}
    first = run_study(_study_config(tmp_path), OBJECTS, ["go"], progress=False)
    assert [r["error"] is not None for r in first.records] == [False, True, False]
    notes = []
    kept = run_study(_study_config(tmp_path, keep_errors=True), OBJECTS, ["go"], progress=False, on_note=notes.append)
    assert kept.new_records == 0 and notes == []
    scripted_runner.failing, scripted_runner.ran = set(), []
    resumed = run_study(_study_config(tmp_path), OBJECTS, ["go"], progress=False, on_note=notes.append)
    assert scripted_runner.ran == [1] and resumed.new_records == 1
    assert [r["error"] for r in resumed.records] == [None, None, None]
    assert notes == ["1 trial(s) that ended in an error run again (--keep-errors keeps them)"]
    assert "| Geometry-Only | 3 | 0 |" in (tmp_path / "summary.md").read_text()


def test_resume_reruns_exactly_the_trials_whose_lines_were_torn_or_invalid(tmp_path, scripted_runner):
    run_study(_study_config(tmp_path), OBJECTS, ["go"], progress=False)
    path = tmp_path / TRIALS_FILE
    lines = path.read_text().splitlines(keepends=True)
    path.write_text(lines[0] + '{"foo": 1}\n' + lines[2][:40])  # trial 1 replaced by junk, trial 2 torn
    scripted_runner.ran = []
    notes = []
    resumed = run_study(_study_config(tmp_path), OBJECTS, ["go"], progress=False, on_note=notes.append)
    assert sorted(scripted_runner.ran) == [1, 2] and resumed.rejected_lines == 2
    assert len(notes) == 1 and notes[0].startswith("2 line(s) of ")
    assert [r["trial"] for r in resumed.records] == [0, 1, 2]
    assert len((tmp_path / REJECTED_FILE).read_text().splitlines()) == 2


def test_the_summary_reports_error_trials_apart_from_failed_grasps(tmp_path, scripted_runner):
    scripted_runner.failing = {0, 2}
    result = run_study(_study_config(tmp_path), OBJECTS, ["go"], progress=False)
    metrics = result.summary["go"]["t1"]["all"]
    assert metrics["n"] == 1 and metrics["errors"] == 2 and metrics["counts"]["GSR"] == [0, 1]
    assert "| Geometry-Only | 1 | 2 |" in (tmp_path / "summary.md").read_text()


def _main_exit(argv, capsys):
    """The exit code and the error lines; a traceback would fail the caller's one-line check too."""
    code = batch.main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, [line for line in err.splitlines() if line.startswith("error:")]


def test_a_run_directory_made_with_another_object_set_is_refused_in_one_line(tmp_path, scripted_runner, capsys):
    # --workers 1: the trial runs in this process, where the scripted runner is patched in.
    argv = ["--profile", "ci", "--objects", SPEC.id, "--tasks", "t1", "--methods", "go", "--n-trials", "1",
            "--workers", "1", "--out", str(tmp_path), "--no-progress"]
    assert batch.main(argv) == 0
    provenance_path = tmp_path / "provenance.json"
    provenance = json.loads(provenance_path.read_text())
    provenance["objects"] = {"source": "ycb:/elsewhere", "checksum": "0" * 64}
    provenance_path.write_text(json.dumps(provenance))
    before = (tmp_path / TRIALS_FILE).read_bytes()
    capsys.readouterr()
    code, err = _main_exit(argv, capsys)
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and "another object set (ycb:/elsewhere" in err[0]
    assert (tmp_path / TRIALS_FILE).read_bytes() == before


def test_a_second_process_into_a_directory_in_use_is_refused_in_one_line(tmp_path, scripted_runner, capsys):
    with RunLock(Path(tmp_path)):
        code, err = _main_exit(["--profile", "ci", "--objects", SPEC.id, "--tasks", "t1", "--methods", "go", "--n-trials", "1",
                                "--out", str(tmp_path), "--no-progress"], capsys)
    assert code == 2 and len(err) == 1 and "is in use by another run" in err[0]
    assert not (tmp_path / TRIALS_FILE).exists()
