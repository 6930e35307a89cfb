"""The study runner end to end in PyBullet: records, resume, workers, Ray, failures, CI slice."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sagp_batched.config import load_config
from sagp_batched.study.study_run import run_study
from sagp_batched.study.trials_file import REJECTED_FILE, read_records
from sagp_batched.world.objects import load_object_set

REPO = Path(__file__).resolve().parent.parent
# Fields that depend on wall-clock time or the machine, not on the seeds.
UNSTABLE = {"times_s", "traceback", "rating"}


def _stable(records):
    return sorted(
        (json.dumps({k: v for k, v in r.items() if k not in UNSTABLE}, sort_keys=True) for r in records),
    )


def _config(tmp_path, ycb_dir, name, **run):
    settings = {"objects": ["005_tomato_soup_can"], "tasks": ["t1"], "methods": ["go"], "n_trials": 2,
                "out": str(tmp_path / name), "objects_dir": str(ycb_dir), **run}
    return load_config("ci", overrides={"run": settings})


def _run(config):
    return run_study(config, load_object_set(config.run.objects_dir), config.run.methods,
                     objects_dir=config.run.objects_dir, progress=False)


@pytest.mark.slow
def test_end_to_end_trial_records_hold_every_field(tmp_path, ycb_dir):
    result = _run(_config(tmp_path, ycb_dir, "fields", n_trials=1))
    (record,) = result.records
    for key in ("object", "category", "asymmetric", "task", "method", "trial", "seed", "success", "attempts",
                "grasp", "failure_reason", "n_candidates", "times_s", "error", "in_functional_region", "in_avoid_region"):
        assert key in record
    # The soup can has no functional-region annotation, so its grasp is measured against none.
    assert record["in_functional_region"] is None and record["in_avoid_region"] is None
    assert record["error"] is None and record["seed"] == 42
    assert record["n_candidates"]["sampled"] == 5000 and record["n_candidates"]["ik_feasible"] > 0
    assert set(record["grasp"]["terms"]) == {"geom", "reach", "afford", "avoid", "task"}
    assert len(record["grasp"]["midpoint_object"]) == 3
    summary = json.loads((result.out_dir / "summary.json").read_text())
    assert summary["go"]["t1"]["all"]["n"] == 1
    provenance = json.loads((result.out_dir / "provenance.json").read_text())
    assert provenance["packages"]["torch"] and provenance["objects"]["checksum"] and provenance["scene_seeds"] == [42]


@pytest.mark.slow
def test_end_to_end_a_failing_trial_is_recorded_and_the_run_completes(tmp_path, ycb_dir):
    config = _config(tmp_path, ycb_dir, "timeout", trial_timeout_s=0.05)
    result = _run(config)
    assert len(result.records) == 2
    assert all("TrialTimeout" in r["error"] for r in result.records)
    assert (result.out_dir / "summary.md").exists()


@pytest.mark.slow
def test_end_to_end_resume_after_a_kill_equals_an_uninterrupted_run(tmp_path, ycb_dir):
    reference = _run(_config(tmp_path, ycb_dir, "reference", n_trials=3))
    out = tmp_path / "killed"
    command = [sys.executable, "-m", "runners.batch", "--profile", "ci", "--objects", "005_tomato_soup_can",
               "--tasks", "t1", "--methods", "go", "--n-trials", "3", "--objects-dir", str(ycb_dir),
               "--out", str(out), "--no-progress"]
    process = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    trials = out / "trials.jsonl"
    deadline = time.time() + 600
    while time.time() < deadline and not (trials.exists() and trials.read_text().count("\n") >= 1):
        time.sleep(0.2)
    process.send_signal(signal.SIGKILL)
    process.wait()
    partial = len(read_records(trials))
    assert 1 <= partial < 3, "the kill should land mid-run"
    resumed = subprocess.run([*command, "--resume"], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr
    lines = [line for line in trials.read_text().splitlines() if line.strip()]
    assert len(lines) == 3, "no trial lost or duplicated"
    assert _stable(read_records(trials)) == _stable(reference.records)


def _batch_command(ycb_dir, out, n_trials=3):
    return [sys.executable, "-m", "runners.batch", "--profile", "ci", "--objects", "005_tomato_soup_can", "--tasks", "t1",
            "--methods", "go", "--n-trials", str(n_trials), "--objects-dir", str(ycb_dir), "--out", str(out), "--no-progress"]


@pytest.mark.slow
def test_end_to_end_a_torn_last_line_resumes_to_records_equal_to_an_uninterrupted_run(tmp_path, ycb_dir):
    reference = _run(_config(tmp_path, ycb_dir, "reference", n_trials=3))
    out = tmp_path / "torn"
    assert subprocess.run(_batch_command(ycb_dir, out), cwd=REPO, capture_output=True).returncode == 0
    trials = out / "trials.jsonl"
    text = trials.read_text()
    trials.write_text(text[: len(text) - len(text.splitlines()[-1]) // 2 - 1])  # half of the last record, no newline
    resumed = subprocess.run(_batch_command(ycb_dir, out), cwd=REPO, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr
    assert "1 line(s) of" in resumed.stderr and "torn line" in resumed.stderr
    assert len(trials.read_text().splitlines()) == 3 and len((out / REJECTED_FILE).read_text().splitlines()) == 1
    assert _stable(read_records(trials)) == _stable(reference.records)


@pytest.mark.slow
def test_end_to_end_a_full_disk_stops_with_one_error_line_and_resumes_to_an_uninterrupted_run(tmp_path, ycb_dir):
    import shutil

    reference = _run(_config(tmp_path, ycb_dir, "reference", n_trials=3))
    tiny = tmp_path / "tiny"
    tiny.mkdir()
    # Room for the lock (a page), config.json and provenance.json (as the reference wrote them, a little longer
    # for the other path) and one page of records: the second record does not fit. Sized from the files, which
    # grow with the config.
    page = 4096
    pages = sum(-(-((reference.out_dir / name).stat().st_size + 256) // page) for name in ("config.json", "provenance.json"))
    size = f"size={(pages + 2) * page // 1024}k"
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", size, "tmpfs", str(tiny)], capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        full = subprocess.run(_batch_command(ycb_dir, tiny / "run"), cwd=REPO, capture_output=True, text=True, timeout=900)
        errors = [line for line in full.stderr.splitlines() if line.startswith("error:")]
        assert full.returncode == 2 and len(errors) == 1 and "No space left on device" in errors[0], full.stderr
        assert "Traceback" not in full.stderr
        kept = read_records(tiny / "run" / "trials.jsonl")
        assert 1 <= len(kept) < 3 and (tiny / "run" / "trials.jsonl").read_bytes().endswith(b"\n")
        shutil.copytree(tiny / "run", tmp_path / "roomy")
    finally:
        subprocess.run(["umount", str(tiny)], check=True)
    resumed = subprocess.run(_batch_command(ycb_dir, tmp_path / "roomy"), cwd=REPO, capture_output=True, text=True, timeout=900)
    assert resumed.returncode == 0, resumed.stderr
    assert "line(s) of" not in resumed.stderr, "nothing was torn"
    assert _stable(read_records(tmp_path / "roomy" / "trials.jsonl")) == _stable(reference.records)


@pytest.mark.slow
def test_end_to_end_two_workers_equal_one(tmp_path, ycb_dir):
    one = _run(_config(tmp_path, ycb_dir, "one", n_trials=2, workers=1))
    two = _run(_config(tmp_path, ycb_dir, "two", n_trials=2, workers=2))
    assert _stable(one.records) == _stable(two.records)
    # Each worker process reported its memory after each unit; the driver kept them apart from the records.
    reports = [json.loads(line) for line in (two.out_dir / "workers.jsonl").read_text().splitlines()]
    assert len(reports) == 2 and all(r["rss_bytes"] > 0 and r["units_done"] >= 1 for r in reports)
    assert {r["pid"] for r in reports}.isdisjoint({os.getpid()})


@pytest.mark.slow
def test_end_to_end_local_ray_returns_the_same_records(tmp_path, ycb_dir):
    pytest.importorskip("ray")
    one = _run(_config(tmp_path, ycb_dir, "inline", n_trials=1))
    ray_run = _run(_config(tmp_path, ycb_dir, "ray", n_trials=1, backend="ray", workers=1))
    assert _stable(one.records) == _stable(ray_run.records)


@pytest.mark.slow
def test_ci_slice_runs_the_ci_profile_end_to_end(tmp_path, ycb_dir):
    out = tmp_path / "ci"
    done = subprocess.run([sys.executable, "-m", "runners.batch", "--profile", "ci", "--objects-dir", str(ycb_dir),
                           "--out", str(out), "--no-progress"], cwd=REPO, capture_output=True, text=True, timeout=3000)
    assert done.returncode == 0, done.stderr[-3000:]
    config = load_config("ci")
    expected = len(config.run.objects) * len(config.run.tasks) * len(config.run.methods) * config.run.n_trials
    records = read_records(out / "trials.jsonl")
    assert len(records) == expected
    assert not [r for r in records if r["error"]], "no trial may crash"
    assert sum(r["success"] for r in records) >= expected // 2, "most CI-slice grasps should hold"
    assert "## Task t1" in (out / "summary.md").read_text()


@pytest.mark.slow
def test_end_to_end_grasp_export_and_frames(tmp_path, ycb_dir):
    import h5py
    import numpy as np
    from PIL import Image

    config = _config(tmp_path, ycb_dir, "export", n_trials=1, methods=["go", "sagp"], export_grasps=True, save_frames=True)
    result = _run(config)
    (path,) = sorted((result.out_dir / "grasps").glob("*.h5"))
    with h5py.File(path) as f:
        candidates = f["candidates/transforms"][()]
        n = len(candidates)
        assert candidates.shape == (n, 4, 4) and n == result.records[0]["n_candidates"]["ik_feasible"]
        assert np.allclose(candidates[:, 3], [0, 0, 0, 1])
        rotations = candidates[:, :3, :3]
        assert np.allclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-5)
        # grasps/ holds the simulated candidates only, each with its outcome: no untested row reads as a failure.
        labelled = f["grasps/candidate_index"][()]
        executed_anywhere = {a["candidate"] for r in result.records for a in r["attempt_log"]}
        assert sorted(labelled.tolist()) == sorted(executed_anywhere)
        assert np.array_equal(f["grasps/transforms"][()], candidates[labelled])
        held = f["grasps/qualities/flex/object_in_gripper"][()]
        assert set(held.tolist()) <= {0, 1} and np.array_equal(f["candidates/tested"][()][labelled], held)
        for method in ("go", "sagp"):
            executed = f[f"grasps/executed/{method}"][()]
            record = next(r for r in result.records if r["method"] == method)
            assert (executed >= 0).sum() == record["attempts"]
            assert (executed == 1).any() == record["success"]
            assert f[f"candidates/qualities/{method}/score"].shape == (n,)
        # Each method's executed grasp, by its planner id, puts the hand's grasp target at the
        # recorded midpoint in the object frame, and carries that method's recorded score.
        for record in result.records:
            index = record["attempt_log"][-1]["candidate"]
            grasp_target = candidates[index, :3, 3] + 0.105 * candidates[index, :3, 2]
            assert np.allclose(grasp_target, record["grasp"]["midpoint_object"], atol=1e-4)
            assert f[f"candidates/qualities/{record['method']}/score"][index] == pytest.approx(record["grasp"]["score"], abs=1e-6)
    for record in result.records:
        for moment in ("contact", "lifted"):
            image = Image.open(result.out_dir / record["frames"][moment])
            assert image.size[0] > 0 and np.asarray(image).std() > 0
