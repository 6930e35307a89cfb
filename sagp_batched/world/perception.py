"""Three-camera perception of the target: RGB-D + segmentation to a merged, normal-carrying point cloud."""
from __future__ import annotations

from typing import Sequence

import numpy as np
import pybullet
import torch

from sagp_batched_kernels.camera import backproject_to_world, linearize_depth

from .._open3d import o3d
from ..config import Config
from ..types import CameraData, PerceivedCloud, PerceptionFailure
from .scene import BACKGROUND, Scene, make_camera


def camera_rig(config: Config, look_at_world: Sequence[float]) -> list[CameraData]:
    """One overhead and two side cameras, placed by ``config.camera`` offsets around ``look_at_world``."""
    look_at = np.asarray(look_at_world, dtype=float)
    cameras = [make_camera("overhead", config, look_at + config.camera.overhead_offset_m, look_at, config.camera.overhead_up_axis)]
    for index, offset in enumerate(config.camera.side_offsets_m):
        cameras.append(make_camera(f"side_{index}", config, look_at + np.asarray(offset), look_at, (0.0, 0.0, 1.0)))
    return cameras


def backproject_views(cameras: list[CameraData], depth_buffers: np.ndarray) -> torch.Tensor:
    """(V, H, W, 3) world points of every pixel of V depth buffers (V, H, W)."""
    depth_m = linearize_depth(
        torch.from_numpy(depth_buffers),
        torch.tensor([c.near_m for c in cameras], dtype=torch.float64),
        torch.tensor([c.far_m for c in cameras], dtype=torch.float64),
    )
    intrinsics = torch.from_numpy(np.stack([c.intrinsics for c in cameras]))
    poses = torch.from_numpy(np.stack([c.camera_to_world for c in cameras]))
    return backproject_to_world(depth_m, intrinsics, poses)


def padded_box(mask: np.ndarray, padding_fraction: float) -> tuple[int, int, int, int]:
    """Pixel box (u0, v0, u1, v1), end-exclusive, around ``mask`` grown by ``padding_fraction`` of its size on every side, clipped to the image."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    top, bottom, left, right = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    pad_v = int(round((bottom - top) * padding_fraction))
    pad_u = int(round((right - left) * padding_fraction))
    height, width = mask.shape
    return (int(max(0, left - pad_u)), int(max(0, top - pad_v)), int(min(width, right + pad_u)), int(min(height, bottom + pad_v)))


def voxel_downsample(points: np.ndarray, labels: np.ndarray, voxel_size_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Voxel-grid downsampling (Open3D) that keeps, per voxel, the label of one of its source points."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    down, _, traced = cloud.voxel_down_sample_and_trace(voxel_size_m, cloud.get_min_bound(), cloud.get_max_bound())
    first_source = np.array([np.asarray(indices)[0] for indices in traced], dtype=np.int64)
    return np.asarray(down.points), labels[first_source]


def outward_normals(
    points_world: np.ndarray,
    radius_m: float,
    max_neighbours: int,
    orientation: str,
    viewpoints_world: np.ndarray | None = None,
    grazing_cosine: float = 0.0,
) -> np.ndarray:
    """Open3D normals (hybrid radius/kNN search), oriented outward from the surface.

    ``orientation`` "camera": each normal is turned toward the camera that saw its point
    (``viewpoints_world`` (N, 3)), which is the outward side of any visible surface, concave ones
    included: the inside of a handle or a mug's inner wall; points seen edge-on (|cos| under
    ``grazing_cosine``) fall back to the centroid. "centroid" (the published rule): away from the
    cloud centroid, which is outward only where the surface faces away from the centroid.
    """
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_world))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius_m, max_nn=max_neighbours))
    normals = np.asarray(cloud.normals)
    away_from_centroid = points_world - points_world.mean(axis=0)
    outward = away_from_centroid
    if orientation == "camera":
        toward_camera = viewpoints_world - points_world
        toward_camera /= np.linalg.norm(toward_camera, axis=1, keepdims=True)
        # On the silhouette the camera sees the surface edge-on and cannot tell its sides apart.
        edge_on = np.abs(np.einsum("ij,ij->i", normals, toward_camera)) < grazing_cosine
        outward = np.where(edge_on[:, None], away_from_centroid, toward_camera)
    flip = np.einsum("ij,ij->i", normals, outward) < 0.0
    normals[flip] *= -1.0
    return normals


def capture(scene: Scene, config: Config) -> PerceivedCloud:
    """Render the three views, segment the target, merge, downsample, estimate normals, crop the image.

    Raises ``PerceptionFailure`` ("not_visible" / "too_few_points") instead of returning a cloud
    the planner cannot use. The RGB crop comes from the view with the most target pixels: it shows
    the object largest and least occluded, which is what the rating model needs to see parts.
    """
    if scene.target_spec is None:
        raise RuntimeError("capture needs a scene that was reset with a target")
    object_position, object_quat = scene.object_link_pose(scene.target_id)
    lower, upper = pybullet.getAABB(scene.target_id, physicsClientId=scene.client)
    cameras = camera_rig(config, (np.asarray(lower) + np.asarray(upper)) / 2.0)
    renders = [scene.render(camera) for camera in cameras]
    body_ids = np.stack([r[2] for r in renders])
    target_masks = body_ids == scene.target_id
    pixels_per_view = target_masks.reshape(len(cameras), -1).sum(axis=1)
    if pixels_per_view.sum() == 0:
        raise PerceptionFailure("not_visible", f"object '{scene.target_spec.id}' is hidden from all {len(cameras)} cameras")

    points_all = backproject_views(cameras, np.stack([r[1] for r in renders])).numpy()
    view_of_pixel = np.broadcast_to(np.arange(len(cameras)).reshape(-1, 1, 1), target_masks.shape)
    voxel = config.perception.voxel_size_m
    points_world, view_index = voxel_downsample(points_all[target_masks], view_of_pixel[target_masks], voxel)
    if points_world.shape[0] < config.perception.min_points:
        raise PerceptionFailure(
            "too_few_points",
            f"object '{scene.target_spec.id}': {points_world.shape[0]} points after {voxel} m voxels "
            f"(need {config.perception.min_points}; target pixels per view {pixels_per_view.tolist()})",
        )
    viewpoints = np.stack([camera.camera_to_world[:3, 3] for camera in cameras])[view_index]
    normals_world = outward_normals(
        points_world, config.perception.normal_radius_m, config.perception.normal_max_neighbours,
        config.perception.normal_orientation, viewpoints, config.perception.normal_grazing_cosine,
    )

    non_obstacles = {scene.target_id, scene.table_id, scene.robot_id, BACKGROUND}
    obstacle_masks = ~np.isin(body_ids, list(non_obstacles))
    obstacles_world = np.zeros((0, 3))
    if obstacle_masks.any():
        obstacles_world, _ = voxel_downsample(points_all[obstacle_masks], np.zeros(int(obstacle_masks.sum()), dtype=np.int64), voxel)

    best_view = int(np.argmax(pixels_per_view))
    u0, v0, u1, v1 = padded_box(target_masks[best_view], config.perception.crop_padding_fraction)
    crop_rgb = renders[best_view][0][v0:v1, u0:u1].copy()
    return PerceivedCloud(
        points_world=torch.as_tensor(points_world, dtype=torch.float32),
        normals_world=torch.as_tensor(normals_world, dtype=torch.float32),
        view_index=torch.as_tensor(view_index, dtype=torch.int64),
        crop_rgb=crop_rgb,
        crop_box_px=(u0, v0, u1, v1),
        crop_camera_index=best_view,
        cameras=cameras,
        object_id=scene.target_spec.id,
        object_position_world=object_position,
        object_quat_xyzw=object_quat,
        obstacle_points_world=torch.as_tensor(obstacles_world, dtype=torch.float32),
    )
