"""Grasp files read as the projects that publish them write them: ACRONYM's HDF5 (what ``acronym_tools.load_grasps``
and ``load_mesh`` read: byte-string paths, int64 outcomes, the object's physics), ACRONYM's JSON, GraspGen's JSON
(``object.file``/``scale``, ``grasps.transforms``/``object_in_gripper``) and ours; bad files refused in one line."""
import json

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from sagp_batched.formats.acronym import write_object_file
from sagp_batched.formats.grasp_file import GraspFileError, read_grasp_file
from sagp_batched.formats.graspgen import write_graspgen_file
from sagp_batched.formats.object_grasps import LabelledGrasps, ObjectPhysics, UntestedGrasps
from sagp_batched.grasps import GraspCandidates, GraspPoses
from sagp_batched.robot import load_gripper

FRANKA = load_gripper("franka_panda")

h5py = pytest.importorskip("h5py")


def _transforms(n, seed=0):
    rng = np.random.default_rng(seed)
    transforms = np.tile(np.eye(4), (n, 1, 1))
    transforms[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    transforms[:, :3, 3] = rng.normal(scale=0.05, size=(n, 3))
    return transforms


def _write_acronym(path, transforms, held, **extra):
    """A file laid out as ACRONYM's published ones are (their example Mug file's keys and dtypes)."""
    with h5py.File(path, "w") as f:
        f["grasps/transforms"] = transforms
        f["grasps/qualities/flex/object_in_gripper"] = np.asarray(held, dtype=np.int64)
        f["object/file"] = np.bytes_(b"meshes/Mug/10f6e09036350e92b3f21f1137c3c347.obj")
        f["object/scale"] = 0.0002682458
        f["object/mass"] = 0.0130879738
        f["object/friction"] = 1.0
        f["object/density"] = 150.0
        f["object/com"] = np.array([6.9e-06, -2.1e-03, 9.4e-02])
        f["gripper/type"] = np.bytes_(b"panda")
        for key, value in extra.items():
            if key in f:
                del f[key]
            if value is not None:
                f[key] = value


def _ours(n, transforms, held):
    return LabelledGrasps(
        transforms=transforms, width_m=np.linspace(0.01, 0.07, n), contacts=np.zeros((n, 2, 3)), resting_pose=np.zeros(n, dtype=np.int64),
        verdict=["feasible"] * n, verdict_reason=[""] * n, held=held, held_fraction=held.astype(float), decided_by=["simulation"] * n,
        failure_reason=["" if h else "slipped@shake" for h in held],
        motion_closing_linear_m=np.zeros(n), motion_closing_angular_rad=np.zeros(n), motion_shaking_linear_m=np.zeros(n),
        motion_shaking_angular_rad=np.zeros(n), s_geom=np.zeros(n), s_reach=np.zeros(n), zone=[""] * n, zone_rating={},
    )


def test_an_acronym_file_reads_with_its_grasps_outcomes_mesh_and_physics(tmp_path):
    transforms, held = _transforms(6), np.array([1, 0, 1, 1, 0, 0])
    _write_acronym(tmp_path / "Mug.h5", transforms, held)
    grasps = read_grasp_file(tmp_path / "Mug.h5")
    assert grasps.format == "acronym" and len(grasps) == 6
    assert grasps.mesh_file == "meshes/Mug/10f6e09036350e92b3f21f1137c3c347.obj" and grasps.scale == pytest.approx(0.0002682458)
    assert np.array_equal(grasps.transforms, transforms) and grasps.transforms.dtype == np.float64
    assert grasps.labels.dtype == bool and np.array_equal(grasps.labels, held == 1)
    assert (grasps.mass_kg, grasps.friction, grasps.density_kg_m3) == (0.0130879738, 1.0, 150.0)
    assert np.allclose(grasps.com_m, [6.9e-06, -2.1e-03, 9.4e-02]) and grasps.width_m is None and grasps.mesh_to_link is None


def test_our_file_reads_back_in_the_scaled_meshs_frame_with_its_widths(tmp_path):
    # A mesh in centimetres, turned and moved into its link frame: mesh_to_link = rigid @ scale.
    scale = 0.01
    rigid = np.eye(4)
    rigid[:3, :3] = Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix()
    rigid[:3, 3] = [0.01, -0.02, 0.03]
    mesh_to_link = rigid @ np.diag([scale] * 3 + [1.0])
    link_transforms, held = _transforms(5, seed=3), np.array([True, False, True, False, True])
    physics = ObjectPhysics(0.2, 150.0, 0.8, (0.0, 0.0, 0.04), ((1e-4, 0, 0), (0, 1e-4, 0), (0, 0, 1e-4)), 1e-4)
    path = tmp_path / "ours.h5"
    write_object_file(path, "box", "box/box.obj", scale, mesh_to_link, physics, _ours(5, link_transforms, held),
                      UntestedGrasps(np.zeros((0, 4, 4)), []), "hand", "floating", "prior", FRANKA)
    grasps = read_grasp_file(path)
    assert np.allclose(rigid @ grasps.transforms, link_transforms), "the grasps, moved back by the rigid part, are the link-frame ones"
    assert np.allclose(rigid @ np.append(grasps.com_m, 1.0), [0.0, 0.0, 0.04, 1.0])
    assert np.array_equal(grasps.labels, held) and np.allclose(grasps.width_m, np.linspace(0.01, 0.07, 5))
    assert (grasps.mass_kg, grasps.friction, grasps.scale, grasps.mesh_file) == (0.2, 0.8, scale, "box/box.obj")


def test_graspgen_and_acronym_json_read_the_same_grasps(tmp_path):
    transforms, held = _transforms(4), np.array([True, True, False, True])
    write_graspgen_file(tmp_path / "gg.json", "objects/a.obj", 0.5, _ours(4, transforms, held), FRANKA)
    (tmp_path / "acr.json").write_text(json.dumps({"object": "objects/a.obj", "object_scale": 0.5, "transforms": transforms.tolist(),
                                                   "quality_flex_object_in_gripper": held.astype(int).tolist()}))
    graspgen, acronym = read_grasp_file(tmp_path / "gg.json"), read_grasp_file(tmp_path / "acr.json")
    assert (graspgen.format, acronym.format) == ("graspgen", "acronym")
    for grasps in (graspgen, acronym):
        assert grasps.mesh_file == "objects/a.obj" and grasps.scale == 0.5
        assert np.allclose(grasps.transforms, transforms) and np.array_equal(grasps.labels, held)


def _h5(tmp_path, **extra):
    _write_acronym(tmp_path / "bad.h5", _transforms(3), [1, 0, 1], **extra)
    return tmp_path / "bad.h5"


def _bytes(tmp_path, name, contents):
    (tmp_path / name).write_bytes(contents)
    return tmp_path / name


def _json(tmp_path, document):
    path = tmp_path / "bad.json"
    path.write_text(document if isinstance(document, str) else json.dumps(document))
    return path


GOOD_GRASPGEN = {"object": {"file": "a.obj", "scale": 1.0}, "grasps": {"transforms": _transforms(2).tolist(), "object_in_gripper": [True, False]}}
NAN_TRANSFORMS = _transforms(3)
NAN_TRANSFORMS[1, 0, 3] = np.nan
SHEARED = _transforms(3)
SHEARED[2, 0, 1] += 0.1


@pytest.mark.parametrize("make, expected", [
    (lambda p: p / "absent.h5", "no such file"),
    (lambda p: _h5(p, **{"grasps/transforms": None}), "missing grasps/transforms"),
    (lambda p: _h5(p, **{"grasps/qualities/flex/object_in_gripper": None}), "missing grasps/qualities/flex/object_in_gripper"),
    (lambda p: _h5(p, **{"object/file": None}), "missing object/file"),
    (lambda p: _h5(p, **{"grasps/transforms": np.zeros((3, 3, 4))}), "shape (3, 3, 4), expected (N, 4, 4)"),
    (lambda p: _h5(p, **{"grasps/transforms": NAN_TRANSFORMS}), "non-finite values (1 grasp(s), first row 1)"),
    (lambda p: _h5(p, **{"grasps/transforms": SHEARED}), "row 2 is not a rigid transform"),
    (lambda p: _h5(p, **{"grasps/qualities/flex/object_in_gripper": np.array([1, 0])}), "shape (2,), expected (3,)"),
    (lambda p: _h5(p, **{"grasps/qualities/flex/object_in_gripper": np.array([1, 2, 0])}), "values other than 0/1"),
    (lambda p: _h5(p, **{"object/scale": 0.0}), "object/scale must be a finite number > 0"),
    (lambda p: _h5(p, **{"object/mass": np.nan}), "object/mass must be a finite number > 0"),
    (lambda p: _h5(p, **{"object/com": np.zeros(2)}), "object/com must hold (3,) finite numbers"),
    (lambda p: _h5(p, **{"object/mesh_to_link": np.diag([1.0, 2.0, 1.0, 1.0])}), "not a rigid transform times object/scale"),
    (lambda p: _json(p, "{not json"), "neither HDF5 nor valid JSON"),
    (lambda p: _bytes(p, "bin.h5", b"\x00\xff" * 64), "neither HDF5 nor JSON (not UTF-8 text)"),
    (lambda p: _bytes(p, "cut.h5", _h5(p).read_bytes()[:600]), "unreadable HDF5"),
    (lambda p: _json(p, [1, 2]), "JSON is not an object"),
    (lambda p: _json(p, {**GOOD_GRASPGEN, "grasps": {"transforms": []}}), "missing grasps.object_in_gripper"),
    (lambda p: _json(p, {**GOOD_GRASPGEN, "object": {"file": "a.obj"}}), "missing object.scale"),
    (lambda p: _json(p, {**GOOD_GRASPGEN, "object": {"file": "", "scale": 1.0}}), "object.file must be a non-empty string"),
    (lambda p: _json(p, {**GOOD_GRASPGEN, "grasps": {"transforms": [["a"]], "object_in_gripper": [True]}}), "not an array of numbers"),
    (lambda p: _json(p, {"transforms": []}), "missing object"),
])
def test_a_bad_file_is_refused_in_one_line_naming_it_and_what_is_wrong(tmp_path, make, expected):
    path = make(tmp_path)
    with pytest.raises(GraspFileError) as raised:
        read_grasp_file(path)
    message = str(raised.value)
    assert "\n" not in message and message.startswith(f"{path}: ") and expected in message, message


# -- GraspPoses.transform --------------------------------------------------------------------------------------------
def _rigid(seed):
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    matrix[:3, 3] = np.random.default_rng(seed).normal(size=3)
    return matrix


def test_grasp_poses_move_between_frames_and_back():
    poses = GraspPoses.from_matrices(_transforms(7, seed=5), "object")
    world_from_object = _rigid(11)
    world = poses.transform(world_from_object, "world")
    assert world.frame == "world" and np.allclose(world.matrices(), world_from_object @ poses.matrices())
    back = world.transform(np.linalg.inv(world_from_object), "object")
    assert back.frame == "object" and np.allclose(back.matrices(), poses.matrices(), atol=1e-12)


def test_grasp_poses_move_as_a_candidate_batch_of_the_same_grasps_does():
    poses = GraspPoses.from_matrices(_transforms(4, seed=2), "world")
    half_width = 0.02 * poses.rotation[:, :, 1]
    n = len(poses)
    zeros = torch.zeros(n, dtype=torch.float64)
    batch = GraspCandidates(
        contacts=torch.stack([poses.position - half_width, poses.position + half_width], dim=1), closing_axis=poses.rotation[:, :, 1],
        width_m=torch.full((n,), 0.04, dtype=torch.float64), s_geom=zeros, approach=poses.approach, rotation=poses.rotation, s_reach=zeros,
        ik_solution=torch.zeros(n, 7), zone=torch.full((n,), -1), s_afford=zeros, s_avoid=zeros, s_task=zeros, score=zeros,
    )
    object_from_world = _rigid(4)
    expected = batch.transform(object_from_world, "object").poses()
    moved = poses.transform(object_from_world, "object")
    assert torch.allclose(moved.position, expected.position) and torch.allclose(moved.rotation, expected.rotation)


def test_grasp_poses_refuse_a_transform_that_is_not_rigid():
    poses = GraspPoses.from_matrices(_transforms(2), "object")
    with pytest.raises(ValueError, match="rigid"):
        poses.transform(np.diag([2.0, 1.0, 1.0, 1.0]), "world")
    with pytest.raises(ValueError, match="frame must be one of"):
        poses.transform(np.eye(4), "camera")
