"""The ACRONYM export read the way ACRONYM's loaders read it: grasps in its Franka gripper frame, the object's mesh loadable."""
import json

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from sagp_batched.formats.acronym import trial_file_bytes
from sagp_batched.grasps import GraspCandidates
from sagp_batched.types import GraspAttempt, PerceivedCloud
from sagp_batched.world.objects import ObjectSpec
from sagp_batched.robot import load_gripper

FRANKA = load_gripper("franka_panda")

h5py = pytest.importorskip("h5py")

# ACRONYM's Franka gripper model (the gripper Contact-GraspNet and the acronym tools draw and collide):
# z = approach, fingers open along +-x, finger pads from the finger joints 0.0584 m above the base to
# the fingertip control points at 0.10527 m; fully open at 0.04 m per finger.
FINGER_BASE_Z_M = 0.0584
FINGERTIP_Z_M = 0.10527
MAX_OPENING_M = 0.08
TOLERANCE_M = 0.005

BOX_HALF_EXTENTS_M = np.array([0.03, 0.02, 0.05])  # the test object: a 6 x 4 x 10 cm box, link frame at its centre


def _box_obj_text() -> str:
    corners = [[sx, sy, sz] * BOX_HALF_EXTENTS_M for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    faces = ["1 2 4 3", "5 7 8 6", "1 5 6 2", "3 4 8 7", "1 3 7 5", "2 6 8 4"]
    return "".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in corners) + "".join(f"f {face}\n" for face in faces)


def _objects_root(tmp_path):
    """A YCB-layout objects root whose URDF names its visual mesh something other than textured.obj."""
    root = tmp_path / "objects"
    (root / "box" / "meshes").mkdir(parents=True)
    (root / "box" / "meshes" / "box_visual.obj").write_text(_box_obj_text())
    (root / "box" / "collision_hull.obj").write_text(_box_obj_text())
    (root / "box" / "model.urdf").write_text(
        '<?xml version="1.0"?><robot name="box"><link name="base_link">'
        '<visual><origin xyz="0 0 0" rpy="0 0 0"/><geometry><mesh filename="meshes/box_visual.obj" scale="1 1 1"/></geometry></visual>'
        '<collision><origin xyz="0 0 0" rpy="0 0 0"/><geometry><mesh filename="collision_hull.obj" scale="1 1 1"/></geometry></collision>'
        "</link></robot>"
    )
    (root / "objects.json").write_text(json.dumps({"box": {"urdf": "box/model.urdf"}}))
    spec = ObjectSpec("box", "box", root / "box" / "model.urdf", "boxes", False, 0.2, tuple(2 * BOX_HALF_EXTENTS_M))
    return root, spec


def _antipodal_box_grasps(rng, n):
    """(contacts_object (n, 2, 3), approach_object (n, 3)): grasps across the box's x or y faces,
    approaching from any direction perpendicular to the closing axis."""
    contacts, approaches = np.zeros((n, 2, 3)), np.zeros((n, 3))
    for k in range(n):
        axis = k % 2  # close across x (6 cm) or y (4 cm)
        closing = np.eye(3)[axis]
        point = rng.uniform(-0.6, 0.6, 3) * BOX_HALF_EXTENTS_M
        point[axis] = 0.0
        contacts[k] = [point - BOX_HALF_EXTENTS_M[axis] * closing, point + BOX_HALF_EXTENTS_M[axis] * closing]
        direction = rng.normal(size=3)
        direction -= direction.dot(closing) * closing
        approaches[k] = direction / np.linalg.norm(direction)
    return contacts, approaches


def _trial(rng, n):
    """The planner's output for one trial: candidates in world, the object at a random pose."""
    contacts_object, approach_object = _antipodal_box_grasps(rng, n)
    world_from_object = Rotation.random(random_state=rng)
    object_position_world = np.array([0.5, -0.1, 0.7])
    contacts_world = world_from_object.apply(contacts_object.reshape(-1, 3)).reshape(n, 2, 3) + object_position_world
    closing = contacts_world[:, 1] - contacts_world[:, 0]
    width = np.linalg.norm(closing, axis=1)
    closing /= width[:, None]
    approach = world_from_object.apply(approach_object)
    # The planner's grasp frame: columns (closing x approach, closing axis, approach).
    rotation_world = np.stack([np.cross(closing, approach), closing, approach], axis=2)
    f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    zeros = torch.zeros(n)
    candidates = GraspCandidates(
        contacts=f32(contacts_world), closing_axis=f32(closing), width_m=f32(width), s_geom=zeros + 0.5,
        approach=f32(approach), rotation=f32(rotation_world), s_reach=zeros + 1.0, ik_solution=torch.zeros(n, 7),
        zone=torch.zeros(n, dtype=torch.int64), s_afford=zeros, s_avoid=zeros, s_task=zeros,
        score=torch.linspace(0.0, 1.0, n), zone_names=("body",),
    )
    cloud = PerceivedCloud(
        points_world=torch.zeros(0, 3), normals_world=torch.zeros(0, 3), view_index=torch.zeros(0, dtype=torch.int64),
        crop_rgb=np.zeros((1, 1, 3), np.uint8), cameras=[], object_id="box", object_position_world=object_position_world,
        object_quat_xyzw=world_from_object.as_quat(),
    )
    return candidates, cloud, contacts_object, width


def _obj_vertices(path):
    return np.array([line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")], dtype=float)


def test_exported_grasps_hold_both_contacts_between_the_fingers_of_acronyms_franka_gripper(tmp_path):
    rng = np.random.default_rng(0)
    root, spec = _objects_root(tmp_path)
    candidates, cloud, contacts_object, width = _trial(rng, 40)
    ranked = candidates.ranked_by(candidates.score)
    path = tmp_path / "box_t1_0000.h5"
    path.write_bytes(trial_file_bytes(spec, cloud, candidates, {"go": ranked},
                                      {"go": [GraspAttempt(False, "slipped", 0.0), GraspAttempt(True, None, 2.0)]}, FRANKA))

    # Every candidate's pose is under candidates/; the simulated ones are read as acronym's load_grasps and load_mesh do.
    with h5py.File(path, "r") as f:
        transforms = np.array(f["candidates/transforms"])
        panda_hand = np.array(f["candidates/base_link_transforms"])
        tested = np.array(f["candidates/tested"])
        labelled = np.array(f["grasps/transforms"])
        success = np.array(f["grasps/qualities/flex/object_in_gripper"])
        labelled_index = np.array(f["grasps/candidate_index"])
        executed_go = np.array(f["grasps/executed/go"])
        mesh_file = f["object/file"][()].decode()
        mesh_scale = f["object/scale"][()]

    assert transforms.shape == (40, 4, 4) and np.allclose(transforms[:, 3], [0, 0, 0, 1])
    rotations = transforms[:, :3, :3]
    assert np.allclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-5)
    assert np.allclose(np.linalg.det(rotations), 1.0, atol=1e-5)
    assert width.max() <= MAX_OPENING_M

    # Both contacts, in each grasp's gripper frame: on the pads, one each side of the centre line along x.
    gripper_from_object = np.linalg.inv(transforms)
    contacts_gripper = np.einsum("nij,nkj->nki", gripper_from_object[:, :3, :3], contacts_object) + gripper_from_object[:, None, :3, 3]
    x, y, z = contacts_gripper[..., 0], contacts_gripper[..., 1], contacts_gripper[..., 2]
    assert np.all(np.abs(x) <= width[:, None] / 2 + TOLERANCE_M)
    assert np.all(np.abs(np.abs(x) - width[:, None] / 2) <= TOLERANCE_M), "each contact touches a finger pad"
    assert np.all(x[:, 0] < 0) and np.all(x[:, 1] > 0), "the contacts lie on opposite fingers"
    assert np.all(np.abs(y) <= 1e-4)
    assert np.all((z >= FINGER_BASE_Z_M - TOLERANCE_M) & (z <= FINGERTIP_Z_M + TOLERANCE_M))
    # The PyBullet hand pose kept beside it closes along its y axis instead.
    hand_from_object = np.linalg.inv(panda_hand)
    contacts_hand = np.einsum("nij,nkj->nki", hand_from_object[:, :3, :3], contacts_object) + hand_from_object[:, None, :3, 3]
    assert np.allclose(np.abs(contacts_hand[..., 1]), width[:, None] / 2, atol=1e-4)

    # Only the two simulated grasps are labelled: the go ranking's second choice (candidate 38) held, its first
    # (candidate 39) did not; the 38 untested candidates are no label, only candidates marked -1.
    assert labelled_index.tolist() == [38, 39] and success.tolist() == [1, 0] and executed_go.tolist() == [1, 0]
    assert np.array_equal(labelled, transforms[[38, 39]])
    assert tested.tolist() == [-1] * 38 + [1, 0]

    # root/object/file is the URDF's visual mesh, in metres at its scale, and holds every contact.
    assert mesh_file == "box/meshes/box_visual.obj" and mesh_scale == 1.0
    mesh_path = root / mesh_file
    try:
        import trimesh

        vertices = np.asarray(trimesh.load(mesh_path).vertices) * mesh_scale
    except ImportError:
        vertices = _obj_vertices(mesh_path) * mesh_scale
    lower, upper = vertices.min(axis=0), vertices.max(axis=0)
    assert np.all((contacts_object >= lower - 1e-6) & (contacts_object <= upper + 1e-6))


def test_exported_ycb_mug_names_its_textured_mesh_relative_to_the_objects_root(tmp_path, ycb_dir):
    index = json.loads((ycb_dir / "objects.json").read_text())
    spec = ObjectSpec("025_mug", "mug", ycb_dir / index["025_mug"]["urdf"], "containers", True, 0.118, (0.117, 0.0931, 0.0813))
    candidates, cloud, _, _ = _trial(np.random.default_rng(1), 4)
    path = tmp_path / "mug.h5"
    path.write_bytes(trial_file_bytes(spec, cloud, candidates, {}, {}, FRANKA))
    with h5py.File(path, "r") as f:
        mesh_file, mesh_scale = f["object/file"][()].decode(), f["object/scale"][()]
    assert mesh_file == "025_mug/textured.obj" and mesh_scale == 1.0
    vertices = _obj_vertices(ycb_dir / mesh_file)
    assert len(vertices) > 100 and np.all(vertices.max(axis=0) - vertices.min(axis=0) < 0.2), "a mug, in metres"


def test_acronym_poses_map_back_to_the_planners_grasp_frames():
    from sagp_batched.formats.frames import acronym_gripper_transforms_object, grasp_poses_from_acronym

    candidates, cloud, _, _ = _trial(np.random.default_rng(2), 12)
    in_object = candidates.transform(cloud.object_from_world, "object")
    back = grasp_poses_from_acronym(acronym_gripper_transforms_object(in_object.poses(), FRANKA), FRANKA)
    assert back.frame == "object"
    assert np.allclose(back.position.numpy(), in_object.position.numpy(), atol=1e-6)
    assert np.allclose(back.rotation.numpy(), in_object.rotation.numpy(), atol=1e-6)
    with pytest.raises(ValueError, match="object frame, got poses in the world frame"):
        acronym_gripper_transforms_object(candidates.poses(), FRANKA)
