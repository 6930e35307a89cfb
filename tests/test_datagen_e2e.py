"""Your objects in, a labelled grasp dataset out: a folder of meshes (one broken) becomes ACRONYM / GraspGen
files with both classes, every row simulated, a report, and a run that resumes per object."""
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from runners import datagen

h5py = pytest.importorskip("h5py")

SMALL_RUN = ["--grasps-per-object", "16", "--captures", "1", "--pairs", "3000", "--no-progress"]


def _mesh_folder(tmp_path):
    folder = tmp_path / "meshes"
    folder.mkdir()
    trimesh.creation.box((0.05, 0.04, 0.08)).export(folder / "box.stl")
    handle = trimesh.creation.box((0.05, 0.012, 0.05))
    handle.apply_translation((0.05, 0.0, 0.05))
    mug = trimesh.util.concatenate([trimesh.creation.cylinder(0.035, 0.1, sections=32, transform=trimesh.transformations.translation_matrix((0, 0, 0.05))), handle])
    mug.export(folder / "mug_like.obj")
    (folder / "broken.obj").write_text("v 0 0 0\nthis is not a mesh\n")
    return folder


def _errors(capsys):
    return [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]


@pytest.mark.slow
def test_a_folder_of_meshes_becomes_a_labelled_dataset_that_resumes_per_object(tmp_path, capsys):
    folder, out = _mesh_folder(tmp_path), tmp_path / "dataset"
    argv = ["--objects-dir", str(folder), "--out", str(out), *SMALL_RUN]
    assert datagen.main(argv) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert sorted(o["id"] for o in manifest["objects"]) == ["box", "mug_like"]
    assert [Path(p).name for p, _ in manifest["skipped_objects"]] == ["broken.obj"]
    assert "broken.obj" in (out / "report.md").read_text()
    held_total, labelled_total = 0, 0
    for entry in manifest["objects"]:
        with h5py.File(out / entry["grasps"], "r") as f:
            held = f["grasps/qualities/flex/object_in_gripper"][()]
            assert f["grasps/transforms"].shape == (len(held), 4, 4) and set(held.tolist()) <= {0, 1}
            assert len(held) + len(f["untested/reason"]) == 16, "every chosen grasp is labelled or kept apart as untested"
            verdicts = {v.decode() for v in f["grasps/verdict"][()]}
            assert "feasible" in verdicts and len(verdicts) >= 2
            assert f["object/density"][()] == pytest.approx(150.0)
        graspgen = json.loads((out / entry["graspgen"]).read_text())
        assert np.array_equal(np.array(graspgen["grasps"]["object_in_gripper"]), held.astype(bool))
        held_total, labelled_total = held_total + int(held.sum()), labelled_total + len(held)
    assert 0 < held_total < labelled_total, "both classes are present"
    listed = (out / "splits" / "train.txt").read_text().split() + (out / "splits" / "valid.txt").read_text().split()
    assert sorted(listed) == sorted(o["mesh"] for o in manifest["objects"])
    assert (out / "pictures" / "box.png").stat().st_size > 0

    # A run stopped after the box: the mug's line is gone, so only the mug is labelled again.
    lines = (out / "objects.jsonl").read_text().splitlines()
    (out / "objects.jsonl").write_text("".join(line + "\n" for line in lines if json.loads(line)["object"] == "box"))
    box_file = (out / "grasps" / "box.h5").read_bytes()
    capsys.readouterr()
    assert datagen.main(argv) == 0
    assert "1 object(s) already in" in capsys.readouterr().err
    assert (out / "grasps" / "box.h5").read_bytes() == box_file
    assert len((out / "objects.jsonl").read_text().splitlines()) == 2


@pytest.mark.slow
def test_arm_mode_executes_the_plan_and_agreement_compares_both_modes(tmp_path):
    out = tmp_path / "arm"
    assert datagen.main(["--objects", "005_tomato_soup_can", "--mode", "arm", "--out", str(out), "--agreement", "6", *SMALL_RUN]) == 0
    with h5py.File(out / "grasps" / "005_tomato_soup_can.h5", "r") as f:
        assert f["mode"][()].decode() == "arm"
        held = f["grasps/qualities/flex/object_in_gripper"][()]
        feasible = np.array([v.decode() == "feasible" for v in f["grasps/verdict"][()]])
        assert feasible.any() and held[feasible].mean() >= 0.5
    agreement = json.loads((out / "agreement.json").read_text())
    assert agreement["compared"] == 6 and agreement["both_tested"] <= 6 and agreement["agree"] <= agreement["both_tested"]
    assert "Hand-vs-arm agreement" in (out / "report.md").read_text()


def _labels(out, object_id):
    with h5py.File(out / "grasps" / f"{object_id}.h5", "r") as f:
        flex = f["grasps/qualities/flex"]
        return {key: flex[key][()] for key in flex} | {"transforms": f["grasps/transforms"][()]}


@pytest.mark.slow
def test_labels_do_not_depend_on_the_workers_or_on_how_grasps_are_chunked(tmp_path):
    """One object's grasps spread over two workers in chunks of 5 give the labels one worker gives
    simulating each capture in one piece, bit for bit (motions included)."""
    common = ["--objects", "025_mug,003_cracker_box", "--grasps-per-object", "24", "--captures", "2", "--pairs", "3000", "--no-progress"]
    assert datagen.main([*common, "--workers", "1", "--grasps-per-chunk", "1000", "--out", str(tmp_path / "one")]) == 0
    assert datagen.main([*common, "--workers", "2", "--grasps-per-chunk", "5", "--out", str(tmp_path / "two")]) == 0
    for object_id in ("025_mug", "003_cracker_box"):
        one, two = _labels(tmp_path / "one", object_id), _labels(tmp_path / "two", object_id)
        assert one.keys() == two.keys() and len(one["transforms"]) == 24
        for key in one:
            assert np.array_equal(one[key], two[key], equal_nan=True), key
        assert 0 < one["object_in_gripper"].sum() < 24


def test_two_engines_label_every_grasp_keep_each_label_and_report_their_agreement(tmp_path, capsys):
    folder, out = tmp_path / "meshes", tmp_path / "dataset"
    folder.mkdir()
    trimesh.creation.box((0.05, 0.04, 0.08)).export(folder / "box.stl")
    argv = ["--objects-dir", str(folder), "--out", str(out), "--protocol", "floating", "--engines", "pybullet,mujoco",
            "--grasps-per-object", "8", "--captures", "1", "--pairs", "3000", "--no-progress"]
    assert datagen.main(argv) == 0
    assert "labels: floating protocol in pybullet, mujoco (held where every engine held" in capsys.readouterr().err
    with h5py.File(out / "grasps" / "box.h5", "r") as f:
        assert [e.decode() for e in f["engines"][()]] == ["pybullet", "mujoco"]
        pybullet, mujoco = (f[f"grasps/qualities/{e}/object_in_gripper"][()].astype(bool) for e in ("pybullet", "mujoco"))
        flex = f["grasps/qualities/flex/object_in_gripper"][()].astype(bool)
        assert len(flex) == 8 and (flex == (pybullet & mujoco)).all()
        assert len(f["grasps/qualities/mujoco/failure_reason"]) == 8
    graspgen = json.loads((out / "graspgen" / "box.json").read_text())
    assert graspgen["grasps"]["object_in_gripper"] == flex.tolist()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["engines"] == ["pybullet", "mujoco"] and "held in every engine" in manifest["conventions"]["object_in_gripper"]
    row = json.loads((out / "objects.jsonl").read_text().splitlines()[0])["engine_agreement"]
    simulated = row["both_held"] + row["first_only"] + row["second_only"] + row["both_dropped"]
    assert 0 < simulated <= 8 and row["first_only"] + row["both_held"] <= int(pybullet.sum())
    report = (out / "report.md").read_text()
    assert f"On the {simulated} grasps the engines simulated" in report
    assert (out / "pictures" / "box_engines.png").exists() == bool(row["first_only"] + row["second_only"])


@pytest.mark.parametrize("argv, named", [
    (["--grasps-per-object", "0"], "--grasps-per-object"),
    (["--captures", "0"], "--captures"),
    (["--grasps-per-chunk", "0"], "--grasps-per-chunk"),
    (["--agreement", "-1"], "--agreement"),
    (["--objects-dir", "/no/such/folder"], "/no/such/folder"),
    (["--objects", "no_such_object"], "no_such_object"),
    (["--engines", "pybullet,flex"], "flex"),
    (["--engines", "mujoco", "--mode", "arm"], "--engines"),
])
def test_bad_dataset_input_is_one_error_line_and_writes_nothing(tmp_path, capsys, argv, named):
    out = tmp_path / "dataset"
    assert datagen.main([*argv, "--out", str(out), "--no-progress"]) == 2
    errors = _errors(capsys)
    assert len(errors) == 1 and named in errors[0]
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow
def test_the_ray_backend_writes_the_labels_the_local_run_writes(tmp_path):
    pytest.importorskip("ray")
    runs = {}
    for backend in ("local", "ray"):
        out = tmp_path / backend
        assert datagen.main(["--objects", "003_cracker_box", "--backend", backend, "--workers", "1", "--out", str(out),
                             "--grasps-per-object", "8", "--captures", "1", "--pairs", "2000", "--no-progress"]) == 0
        with h5py.File(out / "grasps" / "003_cracker_box.h5", "r") as f:
            runs[backend] = (f["grasps/transforms"][()], f["grasps/qualities/flex/object_in_gripper"][()])
    assert np.array_equal(runs["local"][0], runs["ray"][0]) and np.array_equal(runs["local"][1], runs["ray"][1])
