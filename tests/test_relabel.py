"""``runners.relabel`` over ``sagp_batched.datasets.relabelling``: its inputs refused in one line before any work, and,
with the labeller stood in for, the grasps reaching it in the imported object's link frame, the agreement computed from the labels it gave, and a
resumed run labelling only what is missing."""
import json

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from runners import relabel
from sagp_batched.config import Config
from sagp_batched.datasets import labelling
from sagp_batched.datasets import relabelling
from sagp_batched.datasets.agreement import grasp_regions, label_agreement
from sagp_batched.datasets.protocols import GraspLabel
from sagp_batched.formats.grasp_file import read_grasp_file
from sagp_batched.world.objects import CACHE_DIR_ENV, load_object_set
from sagp_batched.robot import load_gripper

FRANKA = load_gripper("franka_panda")

h5py = pytest.importorskip("h5py")

N_GRASPS = 10
SCALE = 0.01  # the mesh is in centimetres, as ACRONYM's are in their own units


def _grasps_around_the_box(n):
    """ACRONYM gripper poses whose contacts' midpoint lies on a 4 x 4 x 10 cm box centred at the origin (metres)."""
    rng = np.random.default_rng(7)
    transforms = np.tile(np.eye(4), (n, 1, 1))
    for k in range(n):
        yaw = rng.uniform(0, 2 * np.pi)
        approach = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        closing = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        centre = np.array([0.0, 0.0, rng.uniform(-0.045, 0.045)]) - 0.02 * approach
        transforms[k, :3, :3] = np.column_stack([closing, np.cross(approach, closing), approach])
        transforms[k, :3, 3] = centre - 0.105 * approach
    return transforms


@pytest.fixture
def acronym_file(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path / "cache"))
    mesh_root = tmp_path / "acronym"
    (mesh_root / "meshes" / "Box").mkdir(parents=True)
    trimesh.creation.box(extents=[4.0, 4.0, 10.0]).export(mesh_root / "meshes" / "Box" / "box.obj")
    path = mesh_root / "Box_abc_0.01.h5"
    with h5py.File(path, "w") as f:
        f["grasps/transforms"] = _grasps_around_the_box(N_GRASPS)
        f["grasps/qualities/flex/object_in_gripper"] = (np.arange(N_GRASPS) % 3 != 0).astype(np.int64)
        f["object/file"] = np.bytes_(b"meshes/Box/box.obj")
        f["object/scale"] = SCALE
        f["object/mass"] = 0.25
        f["object/friction"] = 0.7
    return path, mesh_root


class _Labeller:
    """Stands in for ``label_object_grasps``: held where the grasp centre lies on the link frame's +x side."""

    def __init__(self):
        self.centres = []

    def __call__(self, spec, poses, widths_m, protocol, config, engine="pybullet"):
        assert poses.frame == "object" and protocol == "floating" and widths_m is None and engine == "pybullet"
        centres = poses.position.numpy()
        self.centres.append(centres.copy())
        return [GraspLabel("hand", held=bool(x > 0), failure_reason=None if x > 0 else "slipped", failed_at=None if x > 0 else "shake",
                           protocol=protocol, held_fraction=0.8 if x > 0 else 0.2) for x in centres[:, 0]]


def _run(path, mesh_root, out, *extra):
    # --workers 1: the grasps are labelled in this process, where the tests patch the labeller in.
    return relabel.main([str(path), "--mesh-root", str(mesh_root), "--protocol", "floating", "--out", str(out),
                         "--grasps-per-chunk", "4", "--workers", "1", *extra])


def test_the_labels_and_the_agreement_come_from_the_grasps_in_the_link_frame(acronym_file, tmp_path, monkeypatch):
    path, mesh_root = acronym_file
    fake = _Labeller()
    monkeypatch.setattr(relabelling, "label_object_grasps", fake)
    out = tmp_path / "out"
    assert _run(path, mesh_root, out) == 0
    assert len(fake.centres) == 3, "10 grasps in chunks of 4"
    centres = np.concatenate(fake.centres)
    spec = load_object_set(out / "objects" / "Box_abc_0_01").get("Box_abc_0_01")
    # The file's 0.7 is its contacts' coefficient: PyBullet multiplies our finger's into the object's.
    finger = Config().execution.finger_lateral_friction
    assert json.loads((out / "objects" / "Box_abc_0_01" / "objects.json").read_text()) == {
        "Box_abc_0_01": {"scale": SCALE, "mass_kg": 0.25, "friction": pytest.approx(0.7 / finger)}}
    assert spec.mass_kg == pytest.approx(0.25) and max(spec.extents_m) == pytest.approx(0.10, abs=1e-6), "imported at the file's scale"
    # The link frame sits at the bottom centre of the resting box: every grasp centre is on the box there.
    half = np.array(spec.extents_m) / 2
    assert np.all(np.abs(centres[:, :2]) <= half[:2] + 1e-6) and np.all((centres[:, 2] >= -1e-6) & (centres[:, 2] <= 2 * half[2] + 1e-6))
    file_centres = read_grasp_file(path).transforms[:, :3, 3] + 0.105 * read_grasp_file(path).transforms[:, :3, 2]
    assert np.allclose(np.linalg.norm(centres[:, None] - centres[None], axis=2),
                       np.linalg.norm(file_centres[:, None] - file_centres[None], axis=2)), "moved rigidly"

    reference, ours = np.arange(N_GRASPS) % 3 != 0, centres[:, 0] > 0
    result = json.loads((out / "agreement.json").read_text())
    expected = label_agreement(reference, ours, ["" if h else "shake" for h in ours],
                               grasp_regions(centres, np.array([[-half[0], -half[1], 0.0], [half[0], half[1], 2 * half[2]]])))
    assert {key: result[key] for key in expected} == json.loads(json.dumps(expected))
    assert result["confusion"]["reference_held"]["ours_dropped"] == int((reference & ~ours).sum())
    assert "| reference \\ ours | held | dropped |" in (out / "report.md").read_text()
    with h5py.File(out / "relabel.h5", "r") as f:
        assert np.array_equal(f["grasps/qualities/flex/object_in_gripper"][()], ours.astype(int))
        assert np.array_equal(f["grasps/reference/object_in_gripper"][()], reference.astype(int))
        assert np.allclose(f["grasps/held_fraction"][()], np.where(ours, 0.8, 0.2))
        assert [v.decode() for v in f["grasps/failed_at"][()]] == ["" if h else "shake" for h in ours]
    again = read_grasp_file(out / "relabel.h5")
    assert np.allclose(again.transforms, read_grasp_file(path).transforms) and np.array_equal(again.labels, ours)
    assert json.loads((out / "provenance.json").read_text())["relabel"]["protocol"] == "floating"


def test_a_rerun_resumes_labelling_only_the_missing_chunks(acronym_file, tmp_path, monkeypatch):
    path, mesh_root = acronym_file
    fake = _Labeller()
    monkeypatch.setattr(relabelling, "label_object_grasps", fake)
    out = tmp_path / "out"
    assert _run(path, mesh_root, out) == 0
    first = (out / "agreement.json").read_text()
    assert _run(path, mesh_root, out) == 0 and len(fake.centres) == 3, "every chunk kept: nothing labelled again"
    (out / "chunks" / "00000004.json").write_text('{"start": 4, "sto')  # as a killed run might have left it
    assert _run(path, mesh_root, out) == 0 and len(fake.centres) == 4 and len(fake.centres[-1]) == 4
    assert (out / "agreement.json").read_text() == first


def test_a_rerun_with_other_inputs_is_refused(acronym_file, tmp_path, monkeypatch, capsys):
    path, mesh_root = acronym_file
    monkeypatch.setattr(relabelling, "label_object_grasps", _Labeller())
    out = tmp_path / "out"
    assert _run(path, mesh_root, out, "--max-grasps", "5") == 0
    with h5py.File(out / "relabel.h5", "r") as f:
        assert len(f["grasps/source_index"][()]) == 5
    capsys.readouterr()
    assert _run(path, mesh_root, out) == 2
    assert "holds a relabel of other inputs (selection differ)" in capsys.readouterr().err


@pytest.mark.parametrize("change, expected", [
    (lambda p, m, o: (m / "none.h5", m, o), "none.h5: no such file"),
    (lambda p, m, o: ((m / "bad.json").write_text("{}") and m / "bad.json", m, o), "missing object"),
    (lambda p, m, o: (p, m / "absent", o), "--mesh-root"),
    (lambda p, m, o: (p, o.parent, o), "mesh meshes/Box/box.obj not found under --mesh-root"),
    (lambda p, m, o: (p, m, p), "--out"),
])
def test_a_bad_input_is_one_error_line_before_any_work(acronym_file, tmp_path, monkeypatch, capsys, change, expected):
    path, mesh_root = acronym_file
    monkeypatch.setattr(relabelling, "label_object_grasps", lambda *args: pytest.fail("labelled despite a bad input"))
    out = tmp_path / "out"
    grasp_file, root, out = change(path, mesh_root, out)
    assert _run(grasp_file, root, out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and expected in err and "Traceback" not in err, err


def test_a_mesh_format_that_cannot_be_imported_and_a_bad_count_are_refused(acronym_file, tmp_path, capsys):
    path, mesh_root = acronym_file
    with h5py.File(path, "a") as f:
        del f["object/file"]
        f["object/file"] = "meshes/Box/box.dae"
    (mesh_root / "meshes" / "Box" / "box.dae").write_text("<COLLADA/>")
    assert _run(path, mesh_root, tmp_path / "out") == 2
    assert "mesh " in capsys.readouterr().err
    assert _run(acronym_file[0], mesh_root, tmp_path / "out", "--max-grasps", "0") == 2


def test_the_library_entry_relabels_as_the_command_does(acronym_file, tmp_path, monkeypatch):
    from sagp_batched.config import load_config
    from sagp_batched.datasets import RelabelInputError, check_relabel_inputs, relabel_grasp_file

    path, mesh_root = acronym_file
    monkeypatch.setattr(relabelling, "label_object_grasps", _Labeller())
    assert _run(path, mesh_root, tmp_path / "command") == 0
    out = tmp_path / "library"
    config = load_config("dataset", overrides={"run": {"out": str(out), "workers": 1},  # the patched labeller is this process's
                                               "dataset": {"protocol": "floating", "grasps_per_chunk": 4}})
    with pytest.raises(RelabelInputError, match="^--max-grasps must be at least 1, got 0$"):
        check_relabel_inputs(path, mesh_root, config, max_grasps=0)
    notes = []
    result = relabel_grasp_file(check_relabel_inputs(path, mesh_root, config), config, out, notes.append)
    assert result == json.loads((tmp_path / "command" / "agreement.json").read_text())
    assert notes[-1] == "chunk 3/3 labelled"


def test_a_relabel_by_the_mujoco_engine_runs_and_records_its_engine(acronym_file, tmp_path):
    pytest.importorskip("mujoco")
    path, mesh_root = acronym_file
    out = tmp_path / "out"
    assert _run(path, mesh_root, out, "--engine", "mujoco", "--max-grasps", "3") == 0
    result = json.loads((out / "agreement.json").read_text())
    assert result["engine"] == "mujoco" and result["n"] == 3
    assert json.loads((out / "provenance.json").read_text())["relabel"]["engine"] == "mujoco"
    with h5py.File(out / "relabel.h5", "r") as f:
        assert len(f["grasps/held_fraction"][()]) == 3


@pytest.mark.parametrize("engines", ["bullet", "pybullet,flex", "mujoco,mujoco", ","])
def test_an_unknown_or_repeated_engine_is_one_error_line(acronym_file, tmp_path, capsys, engines):
    path, mesh_root = acronym_file
    assert _run(path, mesh_root, tmp_path / "out", "--engine", engines) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "--engine" in errors[0] and repr(engines) in errors[0]
    assert not (tmp_path / "out" / "relabel.h5").exists()


def test_two_engines_relabel_each_grasp_keep_each_label_and_measure_each_against_the_file_and_each_other(acronym_file, tmp_path, monkeypatch):
    path, mesh_root = acronym_file
    calls = []

    def by_engine(spec, poses, widths_m, protocol, config, engine="pybullet"):
        calls.append(engine)
        x = poses.position.numpy()[:, 0]
        held = x > (0.0 if engine == "pybullet" else 0.01)  # MuJoCo drops the grasps just past the middle
        # MuJoCo's drops slide straight down the pads (a slip); PyBullet's carry no record (other).
        slid = {"object_in_hand_after_closing": (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0), "object_in_hand_at_verdict": (0.0, 0.0, -0.3, 0.0, 0.0, 0.0, 1.0)}
        return [GraspLabel("hand", held=bool(h), failure_reason=None if h else "slipped", failed_at=None if h else ("shake" if engine == "pybullet" else "lift"),
                           protocol=protocol, engine=engine, **({} if engine == "pybullet" else slid)) for h in held]

    monkeypatch.setattr(relabelling, "label_object_grasps", by_engine)
    out = tmp_path / "out"
    assert _run(path, mesh_root, out, "--engine", "pybullet,mujoco") == 0
    assert set(calls) == {"pybullet", "mujoco"}
    result = json.loads((out / "agreement.json").read_text())
    assert result["engine"] == "pybullet,mujoco" and set(result["by_engine"]) == {"pybullet", "mujoco"}
    with h5py.File(out / "relabel.h5", "r") as f:
        pybullet, mujoco = (f[f"grasps/qualities/{e}/object_in_gripper"][()].astype(bool) for e in ("pybullet", "mujoco"))
        flex = f["grasps/qualities/flex/object_in_gripper"][()].astype(bool)
        reference = f["grasps/reference/object_in_gripper"][()].astype(bool)
        assert (flex == (pybullet & mujoco)).all() and (pybullet & ~mujoco).any() and not (mujoco & ~pybullet).any()
        assert {v.decode() for v in f["grasps/qualities/mujoco/failed_at"][()]} <= {"", "lift"}
        assert f["engine"][()].decode() == "pybullet,mujoco", "the file names every engine that labelled it"
    assert result["agree"] == int((flex == reference).sum())
    assert result["by_engine"]["mujoco"]["agree"] == int((mujoco == reference).sum())
    between = result["between_engines"]
    assert (between["reference"], between["ours"]) == ("pybullet", "mujoco") and between["agree"] == int((pybullet == mujoco).sum())
    assert between["disagreements_by_phase"] == {"lift": int((pybullet & ~mujoco).sum())}
    report = (out / "report.md").read_text()
    assert "vs mujoco alone" in report and "Between the engines: mujoco against pybullet as the reference" in report
    # The disagreement causes, as a dataset's report counts them: MuJoCo's drops PyBullet held are slips.
    assert result["disagreement_causes"]["slip"] == {"pybullet": 0, "mujoco": int((pybullet & ~mujoco).sum())}
    assert sum(sum(by_engine.values()) for by_engine in result["disagreement_causes"].values()) == int((pybullet != mujoco).sum())
    assert f"| slip | 0 | {int((pybullet & ~mujoco).sum())} |" in report
    with h5py.File(out / "relabel.h5", "r") as f:
        causes = [v.decode() for v in f["grasps/qualities/mujoco/failure_cause"][()]]
    assert [c == "slip" for c in causes] == list(~mujoco)


def test_a_graspgen_uuid_is_found_through_the_roots_map(tmp_path):
    (tmp_path / "objs").mkdir()
    (tmp_path / "objs" / "a.obj").write_text("v 0 0 0\n")
    (tmp_path / "map_uuid_to_path.json").write_text(json.dumps({"1234abcd": "objs/a.obj"}))
    assert relabelling.mesh_file_path(tmp_path, "1234abcd") == tmp_path / "objs" / "a.obj"
    with pytest.raises(relabelling.InputError, match="not found under --mesh-root"):
        relabelling.mesh_file_path(tmp_path, "5678")


def test_the_link_frame_map_is_the_imports_own_at_the_files_scale():
    from sagp_batched.world.objects import ObjectImport

    rigid = np.eye(4)
    rigid[:3, :3] = Rotation.from_euler("z", 0.4).as_matrix()
    rigid[:3, 3] = [0.01, 0.02, 0.03]

    class Spec:
        id = "box"
        import_record = ObjectImport(source_to_link=tuple(map(tuple, rigid)), scale=SCALE, com_m=(0.0, 0.0, 0.0), hull_volume_ratio=1.0,
                                     hull_max_distance_m=0.0, decomposer="coacd", collision_hulls=1, fidelity_ok=True)

    assert np.allclose(relabelling.link_from_imported_mesh(Spec(), SCALE), rigid)
    with pytest.raises(relabelling.InputError, match="imported at scale 0.01, the file's is 0.5"):
        relabelling.link_from_imported_mesh(Spec(), 0.5)


@pytest.mark.slow
def test_our_own_file_relabelled_for_real_gets_its_own_labels_back(tmp_path, monkeypatch):
    """A file written by this project's writer, labelled by this project's labeller, relabelled: every label returns."""
    import torch

    from sagp_batched.config import load_config
    from sagp_batched.datasets.dataset_directory import copy_object_mesh, object_physics
    from sagp_batched.formats.acronym import write_object_file
    from sagp_batched.formats.frames import acronym_gripper_transforms_object
    from sagp_batched.formats.object_grasps import LabelledGrasps, UntestedGrasps
    from sagp_batched.grasps import GraspPoses

    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path / "cache"))
    (tmp_path / "objects").mkdir()
    trimesh.creation.box(extents=[0.03, 0.03, 0.08]).export(tmp_path / "objects" / "box.obj")
    spec = load_object_set(tmp_path / "objects").get("box")
    # Four grasps across the lying box's middle (held), two closing on air beside it (dropped).
    heights = np.array([0.3, 0.5, 0.7, 0.5, 0.5, 0.5]) * spec.extents_m[2]
    x = np.array([-0.01, 0.0, 0.01, 0.005, 0.2, -0.2])
    rotation = torch.tensor(np.tile(Rotation.from_euler("x", 180, degrees=True).as_matrix(), (6, 1, 1)))  # approach straight down
    poses = GraspPoses(torch.tensor(np.column_stack([x, np.zeros(6), heights])), rotation, "object")
    config = load_config("dataset", overrides={"labelling": {"perturbed_simulations": 1}})
    labels = labelling.label_object_grasps(spec, poses, None, "floating", config)
    held = np.array([label.held for label in labels])
    assert held.tolist() == [True] * 4 + [False] * 2, [label.failure_reason for label in labels]

    mesh_file, scale, mesh_to_link = copy_object_mesh(spec, tmp_path / "meshes")
    n = len(poses)
    grasps = LabelledGrasps(
        transforms=acronym_gripper_transforms_object(poses, FRANKA), width_m=np.full(n, 0.03), contacts=np.zeros((n, 2, 3)),
        resting_pose=np.zeros(n, dtype=np.int64), verdict=["feasible"] * n, verdict_reason=[""] * n, held=held,
        held_fraction=held.astype(float), decided_by=["simulation"] * n,
        failure_reason=[label.failure_reason or "" for label in labels], motion_closing_linear_m=np.zeros(n),
        motion_closing_angular_rad=np.zeros(n), motion_shaking_linear_m=np.zeros(n), motion_shaking_angular_rad=np.zeros(n),
        s_geom=np.zeros(n), s_reach=np.zeros(n), zone=[""] * n, zone_rating={},
    )
    path = tmp_path / "box.h5"
    write_object_file(path, "box", mesh_file, scale, mesh_to_link, object_physics(spec), grasps, UntestedGrasps(np.zeros((0, 4, 4)), []), "hand", "floating", "prior", FRANKA)
    profile = tmp_path / "one_simulation.toml"
    profile.write_text('[labelling]\nperturbed_simulations = 1\n')
    out = tmp_path / "out"
    assert relabel.main([str(path), "--mesh-root", str(tmp_path / "meshes"), "--protocol", "floating", "--out", str(out),
                         "--profile", str(profile)]) == 0
    result = json.loads((out / "agreement.json").read_text())
    assert result["agreement"] == 1.0 and result["kappa"] == 1.0, result


def test_grasps_a_diverged_simulation_left_untested_are_kept_apart_and_compared_with_nothing(acronym_file, tmp_path, monkeypatch, capsys):
    path, mesh_root = acronym_file

    def diverging_in_mujoco(spec, poses, widths_m, protocol, config, engine="pybullet"):
        x = poses.position.numpy()[:, 0]
        # MuJoCo diverges on the grasps on the -x side; PyBullet labels them all.
        return [GraspLabel("hand", held=False, failure_reason="diverged", failed_at="close", protocol=protocol, engine=engine,
                           untested="diverged: QACC warning") if engine == "mujoco" and value < 0 else
                GraspLabel("hand", held=True, failure_reason=None, failed_at=None, protocol=protocol, engine=engine) for value in x]

    monkeypatch.setattr(relabelling, "label_object_grasps", diverging_in_mujoco)
    out = tmp_path / "out"
    assert _run(path, mesh_root, out, "--engine", "pybullet,mujoco") == 0
    result = json.loads((out / "agreement.json").read_text())
    with h5py.File(out / "relabel.h5", "r") as f:
        rows, untested_rows = f["grasps/source_index"][()], f["untested/source_index"][()]
        reasons = {reason.decode() for reason in f["untested/reason"][()]}
        labels = f["grasps/qualities/flex/object_in_gripper"][()]
        transforms = f["untested/transforms"][()]
    assert len(untested_rows) > 0 and sorted([*rows, *untested_rows]) == list(range(N_GRASPS)), "every row labelled or kept apart"
    assert reasons == {"mujoco diverged: QACC warning"} and labels.all() and len(labels) == len(rows)
    assert np.allclose(transforms, _grasps_around_the_box(N_GRASPS)[untested_rows])
    assert result["n"] == len(rows) and result["untested"] == {"pybullet": 0, "mujoco": len(untested_rows)}
    assert f"untested (a simulation diverged, so not compared): pybullet 0, mujoco {len(untested_rows)}" in capsys.readouterr().err
