"""The label-fidelity benchmark on a cube: every section with sane values, the runner's files, its refusals, and
the collision hulls read from a URDF into the link frame."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sagp_batched.benchmarks.label_fidelity import collision_hulls_link, fidelity_markdown, label_fidelity
from sagp_batched.config import load_config
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.objects import ObjectSpec, load_object_set

REPO = Path(__file__).resolve().parent.parent
# Few candidate pairs and one simulation a label: the benchmark's logic, not its statistics.
FAST = {"planner": {"n_pairs": 2000}, "labelling": {"perturbed_simulations": 1}}


@pytest.fixture(scope="module")
def cube_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("cube")
    trimesh.creation.box((0.05, 0.05, 0.05)).export(folder / "cube.obj")
    return folder


def test_every_section_is_measured_with_sane_values(cube_folder, tmp_path):
    # One resting pose: the two tabletop placements differ in position and yaw only, so the grasps simulated in
    # one are simulated in the other too and the comparison has grasps to compare.
    settings = MeshImportSettings(max_resting_poses=1, cache_dir=tmp_path)
    objects = load_object_set(cube_folder, settings)
    report = label_fidelity(load_config("dataset", FAST), objects, ["cube"], 16, settings, note=lambda line: None)
    (row,) = report["objects"]
    hull = row["hull_fidelity"]
    assert hull["source"] == "import" and hull["ok"] and hull["volume_ratio"] == pytest.approx(1.0, abs=0.02)
    assert hull["max_distance_m"] < 1e-3
    assert row["grasps"] == 16
    resting = row["resting_stability"]
    assert resting["placements"].startswith("trials") and 0 < resting["n"] <= 16 and resting["agreement"] >= 0.5
    assert row["resimulation"]["differing"] == 0 and row["resimulation"]["held_differing"] == 0
    # One simulation a label: no perturbed simulations to be unanimous.
    assert row["resimulation"]["unanimous"]["tabletop"]["share"] is None
    protocols = row["protocol_agreement"]
    assert 0 < protocols["n"] <= 16 and 0.0 <= protocols["agreement"] <= 1.0
    for speed in row["speed"].values():
        assert speed["simulated"] > 0 and speed["labels_per_s_per_core"] > 0 and 0.0 <= speed["geometry_share"] < 1.0
    assert {protocol: result["correct"] for protocol, result in report["designed"].items()} == {"tabletop": 4, "floating": 4}
    markdown = fidelity_markdown(report)
    assert "| cube | 1.00 (import) |" in markdown and "tabletop 4/4, floating 4/4" in markdown


def test_the_runner_writes_the_json_the_table_and_provenance(cube_folder, tmp_path):
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench_dataset", "--fidelity", "--objects-dir", str(cube_folder), "--grasps", "4",
         "--pairs", "2000", "--perturbed-simulations", "1", "--out", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=300, env={**os.environ, "SAGP_CACHE_DIR": str(tmp_path / "cache")},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads((out / "label_fidelity.json").read_text())
    assert [row["object"] for row in report["objects"]] == ["cube"] and report["settings"]["perturbed_simulations"] == 1
    assert report["objects"][0]["resting_stability"]["placements"] == "resting poses 0 and 1"
    assert (out / "label_fidelity.md").read_text() in done.stdout
    provenance = json.loads((out / "provenance.json").read_text())
    assert provenance["git"] and provenance["objects"] == ["cube"] and provenance["config"]["labelling"]["perturbed_simulations"] == 1


@pytest.mark.parametrize("flags, message", [
    (["--objects", "no_such"], "no_such"),
    (["--grasps", "0"], "--grasps must be >= 1"),
    (["--perturbed-simulations", "0"], "perturbed_simulations"),
])
def test_the_runner_refuses_bad_input_in_one_line_before_any_work(tmp_path, flags, message):
    done = subprocess.run([sys.executable, "-m", "runners.bench_dataset", "--fidelity", "--out", str(tmp_path / "out"), *flags],
                          cwd=REPO, capture_output=True, text=True, timeout=120)
    last = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 2 and "error:" in last and message in last and "Traceback" not in done.stderr
    assert not (tmp_path / "out").exists()


def test_fidelity_needs_an_out_folder(tmp_path):
    done = subprocess.run([sys.executable, "-m", "runners.bench_dataset", "--fidelity"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "--fidelity needs --out" in done.stderr


def test_collision_hulls_are_the_urdf_meshs_bodies_moved_into_the_link_frame(tmp_path):
    # Two disjoint unit boxes in one file, at half scale and moved up 1 m: two hulls of 0.125 volume each.
    first, second = trimesh.creation.box((1, 1, 1)), trimesh.creation.box((1, 1, 1))
    second.apply_translation((3, 0, 0))
    trimesh.util.concatenate([first, second]).export(tmp_path / "collision.obj")
    (tmp_path / "model.urdf").write_text(
        '<robot name="two"><link name="base_link"><collision><origin xyz="0 0 1" rpy="0 0 1.5707963267948966"/>'
        '<geometry><mesh filename="collision.obj" scale="0.5 0.5 0.5"/></geometry></collision></link></robot>')
    spec = ObjectSpec("two", "two", tmp_path / "model.urdf", "test", False, 1.0, (1.0, 1.0, 1.0))
    hulls = sorted(collision_hulls_link(spec), key=lambda hull: hull.centroid[1])
    assert [hull.volume for hull in hulls] == pytest.approx([0.125, 0.125])
    # Scaled first (the second box's centre to x = 1.5), then turned a quarter about z (to y = 1.5) and lifted.
    assert np.allclose(hulls[0].centroid, (0, 0, 1), atol=1e-9) and np.allclose(hulls[1].centroid, (0, 1.5, 1), atol=1e-9)
