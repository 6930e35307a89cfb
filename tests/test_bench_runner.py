"""The benchmark runner end to end on a small real YCB slice: every figure the issue asks for is written."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def test_bench_writes_planner_ik_and_world_figures(tmp_path, ycb_dir):
    out = tmp_path / "bench.json"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(out), "--objects", "005_tomato_soup_can", "--pairs", "2000",
         "--repeats", "1", "--reference-max-pairs", "2000", "--ik-targets", "64", "--ik-unreachable", "16", "--world-runs", "2",
         "--objects-dir", str(ycb_dir), "--cache-dir", str(tmp_path / "clouds")],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(out.read_text())
    (row,) = report["results"]
    assert row["pairs"] == 2000 and row["batched_plan_s"] > 0 and row["reference_plan_s"] > 0
    assert row["stage_median_s"]["ik"] > 0 and row["counts_last_repeat"]["sampled"] == 2000
    (ik,) = report["ik"]
    assert ik["threads"] == 1 and report["provenance"]["threads"] == [1]
    assert ik["reachable_targets"] == 64 and ik["unreachable_targets"] == 16
    assert [solver["solver"] for solver in ik["solvers"]] == ["PandaIK", "pk.PseudoInverseIK 10x30"]
    planner_ik = ik["solvers"][0]
    assert 0.5 < planner_ik["success_rate"] <= 1 and planner_ik["false_reachable_rate"] == 0.0
    assert report["world"]["runs"] == 2 and report["world"]["capture_s"] > 0 and report["world"]["attempt_s"] > 0
    assert report["provenance"]["torch"]
    assert "pairs/s" in done.stdout and "PandaIK: " in done.stdout and "capture (3 views)" in done.stdout


def test_bench_times_each_thread_count_in_one_run(tmp_path, ycb_dir):
    out = tmp_path / "bench.json"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(out), "--objects", "005_tomato_soup_can", "--pairs", "500",
         "--repeats", "1", "--reference-max-pairs", "0", "--ik-targets", "16", "--ik-unreachable", "4", "--world-runs", "0",
         "--threads", "2,1", "--objects-dir", str(ycb_dir), "--cache-dir", str(tmp_path / "clouds")],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(out.read_text())
    assert [(row["threads"], row["pairs"]) for row in report["results"]] == [(2, 500), (1, 500)]
    assert [ik["threads"] for ik in report["ik"]] == [2, 1]
    assert "threads=2 plan=" in done.stdout and "threads=1 plan=" in done.stdout


def test_bench_rejects_a_bad_thread_count(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(tmp_path / "bench.json"), "--threads", "1,0"],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    assert done.returncode == 2 and "--threads takes positive whole numbers" in done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "bench.json").exists()


def test_dataset_bench_writes_rates_breakdown_projection_and_shared_world_cost(tmp_path):
    out = tmp_path / "dataset_bench.json"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench_dataset", "--json", str(out), "--object", "005_tomato_soup_can", "--hand-grasps", "4",
         "--label-engines", "pybullet,mujoco", "--protocols", "floating", "--arm-grasps", "0", "--workers", "1", "--repeats", "1",
         "--pairs", "2000", "--shared-world-pairs", "1,2"],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(out.read_text())
    assert [(case["engine"], case["protocol"]) for case in report["cases"]] == [("pybullet", "floating"), ("mujoco", "floating")]
    for case in report["cases"]:
        assert case["mode"] == "hand" and case["workers"] == 1 and case["labelled"] + case["untested"] == 4
        assert case["wall_s"] > 0 and case["labels_per_s_per_core"] > 0 and case["simulated_labels_per_s_per_core"] > 0
        assert case["busy_labels_per_s_per_core"] >= case["labels_per_s_per_core"]
        assert set(case["stage_s"]) == {"reset", "capture", "plan", "simulate", "write"} and case["stage_s"]["simulate"] > 0
    assert [p["case"] for p in report["projection"]] == ["hand pybullet floating", "hand mujoco floating"]
    assert all(set(p["hours_by_cores"]) == {"2", "64"} for p in report["projection"])
    assert [row["pairs"] for row in report["shared_world"]] == [1, 2] and all(row["step_ms"] > 0 for row in report["shared_world"])
    assert report["provenance"]["git"] and report["provenance"]["config"]["dataset"]["mode"] == "hand"


def test_dataset_bench_labels_with_the_gripper_named(tmp_path):
    out = tmp_path / "dataset_bench.json"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench_dataset", "--json", str(out), "--object", "005_tomato_soup_can", "--hand-grasps", "2",
         "--label-engines", "pybullet", "--protocols", "floating", "--arm-grasps", "0", "--workers", "1", "--repeats", "1",
         "--pairs", "1000", "--shared-world-pairs", "", "--gripper", "robotiq_2f85"],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(out.read_text())
    assert report["provenance"]["config"]["planner"]["gripper"] == "robotiq_2f85" and report["cases"][0]["labelled"] > 0


@pytest.mark.parametrize("flags, named", [(["--object", "no_such"], "no_such"), (["--label-engines", "pybullet,flex"], "flex"),
                                          (["--protocols", "upside_down"], "upside_down"), (["--gripper", "no_hand"], "no_hand"),
                                          (["--gripper", "robotiq_2f85", "--shared-world-pairs", "1"], "shared-world-pairs")])
def test_dataset_bench_refuses_an_unknown_object_engine_protocol_or_gripper_in_one_line(tmp_path, flags, named):
    done = subprocess.run([sys.executable, "-m", "runners.bench_dataset", "--json", str(tmp_path / "x.json"), *flags],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stderr.strip().splitlines()[-1].startswith("error:") and named in done.stderr


def test_dataset_bench_labels_the_analytic_grasps_and_writes_their_table(tmp_path):
    done = subprocess.run([sys.executable, "-m", "runners.bench_dataset", "--analytic", "--out", str(tmp_path / "out"),
                           "--json", str(tmp_path / "analytic.json"), "--protocols", "floating"],
                          cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    report = json.loads((tmp_path / "analytic.json").read_text())
    assert len(report["cases"]) == 8 and report["of"] == 16
    assert all(set(row["outcomes"]) == {"pybullet/floating", "mujoco/floating"} for row in report["cases"])
    assert "| bar distance x1.2 |" in (tmp_path / "out" / "analytic_grasps.md").read_text()


@pytest.mark.parametrize("flags, named", [(["--gripper", "no_hand"], "no_hand"), (["--label-engines", "flex"], "flex"),
                                          (["--protocols", "upside_down"], "upside_down")])
def test_dataset_bench_analytic_refuses_an_unknown_gripper_engine_or_protocol_in_one_line(tmp_path, flags, named):
    done = subprocess.run([sys.executable, "-m", "runners.bench_dataset", "--analytic", "--out", str(tmp_path), *flags],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stderr.strip().splitlines()[-1].count("\n") == 0 and named in done.stderr


def test_bench_compares_single_plans_with_one_plan_batch_per_batch_size(tmp_path, ycb_dir):
    out = tmp_path / "bench.json"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(out), "--objects", "005_tomato_soup_can", "--pairs", "200",
         "--repeats", "1", "--reference-max-pairs", "0", "--ik-targets", "0", "--world-runs", "0", "--batch-sizes", "1,2",
         "--batch-objects", "003_cracker_box,005_tomato_soup_can", "--batch-pairs", "200",
         "--objects-dir", str(ycb_dir), "--cache-dir", str(tmp_path / "clouds")],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    section = json.loads(out.read_text())["plan_batch"]
    assert section["threads"] == [1] and section["modes"] == [{"device": "cpu", "search": "lookahead", "compile": False}]
    assert [row["batch_size"] for row in section["rows"]] == [1, 2]
    assert section["rows"][1]["objects"] == ["003_cracker_box", "005_tomato_soup_can"] and section["rows"][1]["pairs"] == 200
    for row in section["rows"]:
        assert row["singles_per_cloud_s"] > 0 and row["batch_per_cloud_s"] > 0 and row["ratio"] > 0
        for stages in (row["singles_stage_per_cloud_s"], row["batch_stage_per_cloud_s"]):
            assert set(stages) == {"sampling", "antipodal", "frames_volume", "hand_sweep", "ik", "motion"}
            assert all(seconds > 0 for seconds in stages.values())
    assert "plan_batch B= 1 pairs=200" in done.stdout and "plan_batch B= 2 pairs=200" in done.stdout


def test_bench_profiles_each_stage_with_its_operators_and_work(tmp_path, ycb_dir):
    out = tmp_path / "bench.json"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(out), "--objects", "005_tomato_soup_can", "--pairs", "300",
         "--repeats", "1", "--reference-max-pairs", "0", "--ik-targets", "0", "--world-runs", "0", "--profile-stages",
         "--batch-sizes", "2", "--batch-objects", "003_cracker_box,005_tomato_soup_can", "--batch-pairs", "300",
         "--objects-dir", str(ycb_dir), "--cache-dir", str(tmp_path / "clouds")],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(out.read_text())
    (row,) = report["results"]
    stages = ("sampling", "antipodal", "frames_volume", "hand_sweep", "ik", "motion", "search")
    assert row["compile"] is False and row["device"] == "cpu" and row["first_plan_s"] > 0 and tuple(row["stage_profile"]) == stages
    assert all(row["stage_profile"][stage]["ops"] > 0 and row["stage_profile"][stage]["op_s"] > 0 for stage in stages)
    assert row["stage_items_last_repeat"]["sampling"] == 300 and row["stage_items_last_repeat"]["frames_volume"] > 0
    # The stage table ends with the whole plan: its milliseconds and every stage's operators summed.
    plan_line = next(line.split() for line in done.stdout.splitlines() if line.split()[:1] == ["plan"])
    assert int(plan_line[2]) == sum(row["stage_profile"][stage]["ops"] for stage in stages)
    assert report["provenance"]["devices"]["cpu"]
    (batch,) = report["plan_batch"]["rows"]
    assert tuple(batch["singles_profile"]) == stages and tuple(batch["batch_profile"]) == stages
    # One batch calls fewer operators than its clouds planned one by one.
    assert sum(p["ops"] for p in batch["batch_profile"].values()) < sum(p["ops"] for p in batch["singles_profile"].values())
    assert "in ops ms" in done.stdout and "compile=off" in done.stdout


def test_bench_rejects_a_bad_compile_mode(tmp_path):
    done = subprocess.run([sys.executable, "-m", "runners.bench", "--json", str(tmp_path / "bench.json"), "--compile", "false,maybe"],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "--compile takes false and/or true" in done.stderr and not (tmp_path / "bench.json").exists()


def test_bench_skips_the_batch_comparison_by_default_and_rejects_a_bad_batch_size(tmp_path, ycb_dir):
    out = tmp_path / "bench.json"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(out), "--objects", "005_tomato_soup_can", "--pairs", "200",
         "--repeats", "1", "--reference-max-pairs", "0", "--ik-targets", "0", "--world-runs", "0", "--batch-sizes", "0",
         "--objects-dir", str(ycb_dir), "--cache-dir", str(tmp_path / "clouds")],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(out.read_text())["plan_batch"] is None and "plan_batch B=" not in done.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(tmp_path / "bad.json"), "--batch-sizes", "4,x"],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    assert bad.returncode == 2 and "--batch-sizes takes positive whole numbers" in bad.stderr


def test_bench_names_an_unreachable_ray_address_in_one_line(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(tmp_path / "bench.json"), "--ray-address", "127.0.0.1:9"],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert done.returncode == 2 and len(errors) == 1 and "--ray-address 127.0.0.1:9: cannot reach the Ray cluster" in errors[0]
    assert "Traceback" not in done.stderr and not (tmp_path / "bench.json").exists()


@pytest.mark.slow
def test_bench_measures_the_collision_designs_each_deciding_every_pose_as_the_reference(tmp_path, ycb_dir):
    """Compiles each design's query (about a minute from a cold inductor cache: slow)."""
    out = tmp_path / "designs.json"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench", "--json", str(out), "--collision-designs", "--objects", "005_tomato_soup_can",
         "--pairs", "300", "--repeats", "1", "--threads", "1", "--objects-dir", str(ycb_dir), "--cache-dir", str(tmp_path / "clouds")],
        cwd=REPO, capture_output=True, text=True, timeout=900,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads(out.read_text())
    rows = report["collision_designs"]
    assert report["pairs"] == 300 and report["provenance"]["git"]
    assert {(row["check"], row["design"].split()[0]) for row in rows} >= {("volume", "exact:"), ("volume", "cell"), ("hand", "exact:"),
                                                                          ("hand", "field"), ("hand", "fused")}
    for row in rows:
        assert row["poses"] > 0 and row["query_eager_s"] > 0 and row["decided_disagreements"] == 0 and row["agreement_after_exact"] == 1.0
    assert "collision designs, 300 pairs" in done.stdout


def test_the_fixed_set_is_labelled_and_its_labels_changed_counted_against_a_reference(tmp_path, capsys):
    import numpy as np
    import trimesh

    from runners.bench_dataset import main
    from sagp_batched.benchmarks.designed_grasps import DESIGNED_BOX_M, designed_box_grasps
    from sagp_batched.benchmarks.fixed_labels import changed_labels
    from sagp_batched.robot.description import load_robot
    from sagp_batched.world.mesh_settings import MeshImportSettings
    from sagp_batched.world.objects import load_object_set

    folder = tmp_path / "objects"
    folder.mkdir()
    trimesh.creation.box(DESIGNED_BOX_M).export(folder / "box.obj")
    poses = designed_box_grasps(load_object_set(folder, MeshImportSettings()).get("box"), load_robot())
    grasp_set = tmp_path / "set.npz"
    np.savez(grasp_set, object_ids=np.array(["box"] * 3), positions=poses.position.numpy(), rotations=poses.rotation.numpy())
    common = ["--fixed-set", str(grasp_set), "--objects-dir", str(folder), "--label-engines", "mujoco"]
    assert main([*common, "--out", str(tmp_path / "reference"), "--labelling-overrides", '{"perturb_only_thin_margins": false}']) == 0
    assert main([*common, "--out", str(tmp_path / "once"), "--reference", str(tmp_path / "reference"),
                 "--labelling-overrides", '{"thin_margin_slip_m": 0.05, "thin_margin_rotation_deg": 90}']) == 0
    reference, once = (json.loads((tmp_path / name / "fixed_labels.json").read_text())["engines"]["mujoco"] for name in ("reference", "once"))
    assert [r["held_fraction"] for r in reference["records"]] == [1.0, 0.0, None]  # the collision is geometry's
    assert [r["held_fraction"] for r in once["records"]] == [None, None, None] and [r["held"] for r in once["records"]] == [True, False, False]
    assert once["changed"] == {"grasps": 3, "simulated": 2, "held_changed": 0, "now_held": 0, "now_dropped": 0, "failure_changed": 0}
    assert "0 held/dropped changed" in capsys.readouterr().out
    flipped = [dict(once["records"][0], held=False, failure_reason="slipped", failed_at="shake"), *once["records"][1:]]
    assert changed_labels(once["records"], flipped)["now_dropped"] == 1 and changed_labels(flipped, once["records"])["now_held"] == 1
    with pytest.raises(SystemExit):
        main([*common, "--out", str(tmp_path / "bad"), "--labelling-overrides", "[1]"])
    assert "--labelling-overrides takes a JSON table" in capsys.readouterr().err
