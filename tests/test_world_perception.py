"""Three-camera perception: exact back-projection, outward normals, views that agree, clear failures."""
from __future__ import annotations


import numpy as np
import pybullet
import pytest
import torch
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from sagp_batched import Config, PerceptionFailure
from sagp_batched.world.objects import PYBULLET_DATA_SET, load_object_set
from sagp_batched.world.perception import backproject_views, camera_rig, capture
from sagp_batched.world.scene import Scene
from sagp_batched_kernels.camera import backproject_to_world, linearize_depth

from ycb_paths import YCB_DIR


@pytest.fixture(scope="module")
def scene():
    with Scene(Config()) as created:
        yield created


@pytest.fixture(scope="module")
def builtin():
    return load_object_set(PYBULLET_DATA_SET)


def _raw_target_points(scene: Scene, config: Config) -> list[np.ndarray]:
    """Per view, the back-projected (un-downsampled) world points of the target's pixels."""
    lower, upper = pybullet.getAABB(scene.target_id, physicsClientId=scene.client)
    cameras = camera_rig(config, (np.array(lower) + np.array(upper)) / 2.0)
    renders = [scene.render(camera) for camera in cameras]
    points = backproject_views(cameras, np.stack([r[1] for r in renders])).numpy()
    return [points[i][renders[i][2] == scene.target_id] for i in range(len(cameras))]


def test_kernel_inverts_the_depth_buffer_and_the_pinhole_model():
    near, far = 0.01, 3.0
    depth_true = torch.tensor([[[0.5, 1.0], [2.0, 0.25]]], dtype=torch.float64)
    buffer = far * (depth_true - near) / (depth_true * (far - near))  # OpenGL z-buffer of that depth
    depth = linearize_depth(buffer, torch.tensor([near]), torch.tensor([far]))
    assert torch.allclose(depth, depth_true, atol=1e-12)
    intrinsics = torch.tensor([[[100.0, 0.0, 0.5], [0.0, 100.0, 0.5], [0.0, 0.0, 1.0]]], dtype=torch.float64)
    pose = torch.eye(4, dtype=torch.float64).unsqueeze(0)
    pose[0, :3, 3] = torch.tensor([1.0, 2.0, 3.0])
    points = backproject_to_world(depth, intrinsics, pose)
    # pixel (u=1, v=0): x = (1 - 0.5) * 1.0 / 100, y = (0 - 0.5) * 1.0 / 100 (v grows downward), z = 1.0
    assert torch.allclose(points[0, 0, 1], torch.tensor([1.005, 1.995, 4.0], dtype=torch.float64))
    with pytest.raises(ValueError, match="intrinsics"):
        backproject_to_world(depth, intrinsics.repeat(2, 1, 1), pose)


def test_box_points_lie_on_its_faces_within_2mm(scene, builtin):
    config = Config()
    cube = builtin.get("cube_small")
    scene.reset(cube, trial=5)
    half = cube.extents_m[0] / 2.0
    position, quat = pybullet.getBasePositionAndOrientation(scene.target_id, physicsClientId=scene.client)
    to_box = Rotation.from_quat(quat).inv()
    for view_points in _raw_target_points(scene, config):
        assert len(view_points) > 200
        local = to_box.apply(view_points - np.array(position))
        distance_to_surface = np.abs(np.abs(local).max(axis=1) - half)
        assert distance_to_surface.max() < 0.002


def test_sphere_normals_point_outward(scene, builtin):
    config = Config()
    scene.reset(builtin.get("sphere_small"), trial=2)
    cloud = capture(scene, config)
    centre = np.array(pybullet.getBasePositionAndOrientation(scene.target_id, physicsClientId=scene.client)[0])
    radial = cloud.points_world.numpy() - centre
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    cosine = np.einsum("ij,ij->i", radial, cloud.normals_world.numpy())
    assert np.all(cosine > 0.0)
    assert np.median(cosine) > 0.98
    assert torch.allclose(cloud.normals_world.norm(dim=1), torch.ones(cloud.n_points), atol=1e-4)


def test_views_agree_where_they_overlap(scene):
    if not (YCB_DIR / "objects.json").is_file():
        pytest.skip(f"YCB models not found at {YCB_DIR}")
    config = Config()
    scene.reset(load_object_set(YCB_DIR).get("005_tomato_soup_can"), trial=0)
    views = _raw_target_points(scene, config)
    for a in range(len(views)):
        for b in range(a + 1, len(views)):
            distances, _ = cKDTree(views[b]).query(views[a])
            overlap = distances < 0.01
            assert overlap.mean() > 0.1, f"views {a} and {b} barely overlap"
            assert np.median(distances[overlap]) < 0.0015, f"views {a} and {b} disagree"


def test_capture_returns_a_downsampled_cloud_with_crop_and_obstacles(scene):
    if not (YCB_DIR / "objects.json").is_file():
        pytest.skip(f"YCB models not found at {YCB_DIR}")
    config = Config()
    ycb = load_object_set(YCB_DIR)
    scene.reset(ycb.get("025_mug"), trial=0, distractors=ycb.distractors())
    cloud = capture(scene, config)
    assert cloud.object_id == "025_mug" and cloud.n_points >= config.perception.min_points
    assert set(cloud.view_index.tolist()) == {0, 1, 2}
    nearest, _ = cKDTree(cloud.points_world.numpy()).query(cloud.points_world.numpy(), k=2)
    assert np.median(nearest[:, 1]) > config.perception.voxel_size_m * 0.5  # thinned to the voxel grid
    extent = cloud.points_world.max(0).values - cloud.points_world.min(0).values
    assert torch.all(extent < 0.14) and torch.all(extent > 0.07)  # a 12 x 9 x 8 cm mug
    assert cloud.crop_rgb.dtype == np.uint8 and cloud.crop_rgb.ndim == 3 and min(cloud.crop_rgb.shape[:2]) > 30
    assert cloud.obstacle_points_world.shape[0] > 100
    # Obstacles are the distractors, not the target: none lies inside the target cloud.
    gap, _ = cKDTree(cloud.points_world.numpy()).query(cloud.obstacle_points_world.numpy())
    assert np.min(gap) > 0.002


def test_too_few_points_and_hidden_object_raise_perception_failure(scene, builtin):
    config = Config()
    scene.reset(builtin.get("lego"), trial=0)
    strict = config.override("perception", min_points=100_000)
    with pytest.raises(PerceptionFailure) as failure:
        capture(scene, strict)
    assert failure.value.reason == "too_few_points"
    assert "lego" in str(failure.value)
    # Cameras aim at the object's pose; below the opaque table no camera sees it.
    pybullet.resetBasePositionAndOrientation(scene.target_id, [0.5, 0.0, 0.2], [0, 0, 0, 1], physicsClientId=scene.client)
    with pytest.raises(PerceptionFailure) as hidden:
        capture(scene, config)
    assert hidden.value.reason == "not_visible"


def test_normals_of_a_concave_surface_face_the_camera_that_saw_it():
    """The inner wall of a cup, each part seen over the rim by a camera above the opposite side: its
    outward side faces the cavity and the camera; the published rule (away from the centroid)
    turns those normals into the wall."""
    from sagp_batched.world.perception import outward_normals

    angle = np.linspace(0.0, 2.0 * np.pi, 180, endpoint=False)
    height = np.linspace(0.0, 0.08, 27)
    ring = np.stack([0.04 * np.cos(angle), 0.04 * np.sin(angle)], axis=1)
    inner_wall = np.concatenate([np.c_[ring, np.full(len(ring), z)] for z in height])
    outer_wall = inner_wall * [1.2, 1.2, 1.0]
    points = np.concatenate([inner_wall, outer_wall])
    over_the_rim = np.c_[-inner_wall[:, :2] / 0.04 * 0.3, np.full(len(inner_wall), 0.3)]
    seen_from = np.concatenate([over_the_rim, outer_wall * [3.0, 3.0, 1.0]])
    normals = outward_normals(points, 0.01, 30, "camera", seen_from, 0.1)
    inward = -inner_wall * [1.0, 1.0, 0.0] / 0.04
    assert (np.einsum("ij,ij->i", normals[: len(inner_wall)], inward) > 0.9).mean() > 0.95
    published = outward_normals(points, 0.01, 30, "centroid")
    assert (np.einsum("ij,ij->i", published[: len(inner_wall)], inward) < 0.0).mean() > 0.95
