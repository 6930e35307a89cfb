"""Depth-image kernels: OpenGL depth-buffer linearisation and pinhole back-projection to world frame.

Camera frame convention (OpenCV): x right, y down (image v grows downward), z forward along the
optical axis. PyBullet's depth buffer stores, per pixel, the non-linear OpenGL z-buffer value of the
point's depth *along the optical axis* (not the ray length), so the pinhole model applies directly.
"""
from __future__ import annotations

import torch


def linearize_depth(depth_buffer: torch.Tensor, near_m: torch.Tensor, far_m: torch.Tensor) -> torch.Tensor:
    """Metric depth along the optical axis from OpenGL depth-buffer values.

    ``d = far * near / (far - (far - near) * z)``.

    Args:
        depth_buffer: (B, H, W) z-buffer values in [0, 1] (1 = far plane / background).
        near_m: (B,) near clipping distance of each camera, metres.
        far_m: (B,) far clipping distance of each camera, metres.

    Returns:
        (B, H, W) depth in metres along each camera's optical axis (z in the camera frame).
    """
    if depth_buffer.dim() != 3:
        raise ValueError(f"depth_buffer must be (B, H, W), got shape {tuple(depth_buffer.shape)}")
    near = near_m.to(depth_buffer.dtype).view(-1, 1, 1)
    far = far_m.to(depth_buffer.dtype).view(-1, 1, 1)
    if near.shape[0] != depth_buffer.shape[0] or far.shape[0] != depth_buffer.shape[0]:
        raise ValueError("near_m and far_m need one value per depth image")
    return far * near / (far - (far - near) * depth_buffer)


def pixel_rays(height_px: int, width_px: int, intrinsics: torch.Tensor) -> torch.Tensor:
    """Camera-frame direction of every pixel centre, scaled so its z component is 1.

    Args:
        height_px: image height H.
        width_px: image width W.
        intrinsics: (B, 3, 3) pinhole matrices K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels;
            pixel (u, v) has its centre at integer coordinates (u to the right, v downward).

    Returns:
        (B, H, W, 3) rays ``((u - cx) / fx, (v - cy) / fy, 1)`` in the camera frame.
    """
    if intrinsics.dim() != 3 or intrinsics.shape[1:] != (3, 3):
        raise ValueError(f"intrinsics must be (B, 3, 3), got shape {tuple(intrinsics.shape)}")
    dtype, device = intrinsics.dtype, intrinsics.device
    v, u = torch.meshgrid(
        torch.arange(height_px, dtype=dtype, device=device),
        torch.arange(width_px, dtype=dtype, device=device),
        indexing="ij",
    )
    fx = intrinsics[:, 0, 0].view(-1, 1, 1)
    fy = intrinsics[:, 1, 1].view(-1, 1, 1)
    cx = intrinsics[:, 0, 2].view(-1, 1, 1)
    cy = intrinsics[:, 1, 2].view(-1, 1, 1)
    x = (u.unsqueeze(0) - cx) / fx
    y = (v.unsqueeze(0) - cy) / fy
    return torch.stack((x, y, torch.ones_like(x)), dim=-1)


def backproject_to_world(depth_m: torch.Tensor, intrinsics: torch.Tensor, camera_to_world: torch.Tensor) -> torch.Tensor:
    """World-frame point of every pixel: ``p_cam = d * ((u - cx) / fx, (v - cy) / fy, 1)``, then the camera pose.

    Args:
        depth_m: (B, H, W) metric depth along each camera's optical axis.
        intrinsics: (B, 3, 3) pinhole matrices in pixels (see ``pixel_rays``).
        camera_to_world: (B, 4, 4) pose of each camera frame (x right, y down, z forward) in world.

    Returns:
        (B, H, W, 3) points in the world frame, metres.
    """
    if depth_m.dim() != 3:
        raise ValueError(f"depth_m must be (B, H, W), got shape {tuple(depth_m.shape)}")
    batch, height, width = depth_m.shape
    if intrinsics.shape[0] != batch or camera_to_world.shape != (batch, 4, 4):
        raise ValueError(
            f"need one (3, 3) intrinsics and one (4, 4) pose per image: depth {tuple(depth_m.shape)}, "
            f"intrinsics {tuple(intrinsics.shape)}, camera_to_world {tuple(camera_to_world.shape)}"
        )
    points_camera = pixel_rays(height, width, intrinsics.to(depth_m.dtype)) * depth_m.unsqueeze(-1)
    pose = camera_to_world.to(depth_m.dtype)
    rotation = pose[:, :3, :3]
    translation = pose[:, :3, 3]
    return torch.einsum("bij,bhwj->bhwi", rotation, points_camera) + translation.view(batch, 1, 1, 3)
