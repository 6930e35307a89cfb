"""A dataset's files read the way grasp-learning loaders read them: ACRONYM's HDF5 keys, shapes and
dtypes (``acronym_tools.load_grasps`` / ``load_mesh``), GraspGen's JSON as boolean masks, its split files."""
import json

import numpy as np
import pytest

from sagp_batched.datasets.dataset_directory import copy_object_mesh, read_progress, split_of, write_splits
from sagp_batched.formats.acronym import write_object_file
from sagp_batched.formats.graspgen import write_graspgen_file
from sagp_batched.formats.object_grasps import LabelledGrasps, ObjectPhysics, UntestedGrasps
from sagp_batched.world.objects import load_object_set
from sagp_batched.robot import load_gripper

FRANKA = load_gripper("franka_panda")

h5py = pytest.importorskip("h5py")

# ACRONYM's keys with the shape after N and the dtype kind each holds ("f" float, "i" integer, "S"/"O" string).
ACRONYM_KEYS = {
    "grasps/transforms": ((4, 4), "f"),
    "grasps/qualities/flex/object_in_gripper": ((), "i"),
    "grasps/qualities/flex/object_motion_during_closing_linear": ((), "f"),
    "grasps/qualities/flex/object_motion_during_closing_angular": ((), "f"),
    "grasps/qualities/flex/object_motion_during_shaking_linear": ((), "f"),
    "grasps/qualities/flex/object_motion_during_shaking_angular": ((), "f"),
}
ACRONYM_OBJECT_KEYS = {"object/file": (), "object/scale": (), "object/mass": (), "object/density": (), "object/friction": (),
                       "object/com": (3,), "object/inertia": (3, 3), "object/volume": (), "gripper/type": ()}


def _labels(n, rng):
    transforms = np.tile(np.eye(4), (n, 1, 1))
    transforms[:, :3, 3] = rng.normal(scale=0.05, size=(n, 3))
    held = np.arange(n) % 3 != 0
    return LabelledGrasps(
        transforms=transforms, width_m=np.full(n, 0.05), contacts=rng.normal(size=(n, 2, 3)), resting_pose=np.zeros(n, dtype=np.int64),
        verdict=["feasible" if h else "volume" for h in held], verdict_reason=["because"] * n, held=held,
        held_fraction=np.where(held, 0.8, 0.0), decided_by=["simulation" if h else "geometry" for h in held],
        failure_reason=["" if h else "slipped@shake" for h in held], motion_closing_linear_m=np.full(n, 0.001),
        motion_closing_angular_rad=np.full(n, 0.01), motion_shaking_linear_m=np.full(n, 0.002), motion_shaking_angular_rad=np.full(n, 0.02),
        s_geom=np.full(n, 0.9), s_reach=np.full(n, 0.5), zone=["middle"] * n, zone_rating={"t1": ["preferred"] * n, "t2": [""] * n},
    )


def test_the_object_file_carries_acronyms_keys_shapes_and_dtypes_and_its_mesh_loads(tmp_path):
    import trimesh

    spec = load_object_set(None).get("025_mug")
    mesh_file, scale, mesh_to_link = copy_object_mesh(spec, tmp_path / "meshes")
    grasps = _labels(9, np.random.default_rng(0))
    physics = ObjectPhysics(0.118, 300.0, 0.9, (0.0, 0.0, 0.03), ((1e-4, 0, 0), (0, 1e-4, 0), (0, 0, 1e-4)), 4e-4)
    path = tmp_path / "025_mug.h5"
    write_object_file(path, "025_mug", mesh_file, scale, mesh_to_link, physics, grasps,
                      UntestedGrasps(np.tile(np.eye(4), (2, 1, 1)), ["unreachable", "unreachable"]), "hand", "tabletop", "prior:zone_priors.json", FRANKA)
    with h5py.File(path, "r") as f:
        for key, (shape, kind) in ACRONYM_KEYS.items():
            assert f[key].shape == (9, *shape) and f[key].dtype.kind == kind, key
        for key, shape in ACRONYM_OBJECT_KEYS.items():
            assert f[key].shape == shape, key
        # As acronym_tools.load_grasps reads it: every row an outcome, held exactly where simulated held.
        success = np.array(f["grasps/qualities/flex/object_in_gripper"])
        assert set(success.tolist()) <= {0, 1} and np.array_equal(success == 1, grasps.held)
        assert f["untested/transforms"].shape == (2, 4, 4), "untested grasps are kept apart, never as labels"
        # Beside each label: the share of its simulations that held, and whether geometry decided it.
        assert np.array_equal(f["grasps/qualities/flex/held_fraction"][()], grasps.held_fraction)
        assert [d.decode() for d in f["grasps/decided_by"][()]] == grasps.decided_by and f["protocol"][()].decode() == "tabletop"
        assert f["grasps/zone_rating/t1"][0].decode() == "preferred" and f["gripper/type"][()].decode() == "franka_panda"
        mesh_name, mesh_scale = f["object/file"][()].decode(), f["object/scale"][()]
    # As acronym_tools.load_mesh reads it, from the dataset's meshes/ folder.
    mesh = trimesh.load(tmp_path / "meshes" / mesh_name, force="mesh").apply_scale(mesh_scale)
    assert mesh_name == "025_mug/textured.obj" and 0.05 < mesh.extents.max() < 0.2, "a mug, in metres"


def test_the_graspgen_json_loads_into_boolean_masks_that_match_the_hdf5(tmp_path):
    grasps = _labels(7, np.random.default_rng(1))
    path = tmp_path / "obj.json"
    write_graspgen_file(path, "obj/mesh.obj", 1.0, grasps, FRANKA)
    document = json.loads(path.read_text())
    mask = np.array(document["grasps"]["object_in_gripper"])
    assert mask.dtype == bool and np.array_equal(mask, grasps.held)
    assert np.array(document["grasps"]["transforms"]).shape == (7, 4, 4)
    assert document["object"] == {"file": "obj/mesh.obj", "scale": 1.0}


def test_split_files_list_every_object_once_and_the_split_is_stable(tmp_path):
    meshes = {f"object_{k:03d}": f"object_{k:03d}/mesh.obj" for k in range(50)}
    splits = write_splits(tmp_path, meshes, 0.2)
    train = (tmp_path / "splits" / "train.txt").read_text().split()
    valid = (tmp_path / "splits" / "valid.txt").read_text().split()
    assert sorted(train + valid) == sorted(meshes.values()) and splits == {"train": train, "valid": valid}
    assert 0 < len(valid) < 25
    assert all(split_of(object_id, 0.2) == ("valid" if mesh in valid else "train") for object_id, mesh in meshes.items())


def test_a_torn_progress_line_is_skipped_so_its_object_runs_again(tmp_path):
    (tmp_path / "objects.jsonl").write_text('{"object": "a", "labelled": 3}\n{"object": "b", "lab')
    assert list(read_progress(tmp_path)) == ["a"]


def test_a_stray_flat_part_in_a_collision_mesh_adds_no_volume_and_raises_nothing(tmp_path):
    """Scanned meshes carry stray triangles; qhull cannot build their hull, and they hold no volume."""
    import trimesh

    from sagp_batched.datasets.dataset_directory import object_physics
    from sagp_batched.world.objects import ObjectSpec

    box = trimesh.creation.box(extents=(0.1, 0.05, 0.02))
    stray = trimesh.Trimesh(vertices=[[0.3, 0, 0], [0.31, 0, 0], [0.3, 0.01, 0]], faces=[[0, 1, 2]])
    trimesh.util.concatenate([box, stray]).export(tmp_path / "collision.obj")
    (tmp_path / "model.urdf").write_text(
        '<robot name="o"><link name="base"><inertial><mass value="0.2"/><origin xyz="0 0 0"/>'
        '<inertia ixx="1e-4" iyy="1e-4" izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial>'
        '<collision><geometry><mesh filename="collision.obj"/></geometry></collision></link></robot>')
    spec = ObjectSpec("o", "o", tmp_path / "model.urdf", "box", False, 0.2, (0.1, 0.05, 0.02))
    physics = object_physics(spec)
    assert physics.volume_m3 == pytest.approx(1e-4, rel=1e-6)
    assert physics.density_kg_m3 == pytest.approx(2000.0, rel=1e-6)
