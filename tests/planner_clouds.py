"""Constructed test geometry for the planner tests: surface clouds with exact outward normals."""
from __future__ import annotations

import math

import numpy as np
import torch

from sagp_batched.types import PerceivedCloud


def box_surface(size_m, centre_m, spacing_m=0.004):
    """Points on the six faces of an axis-aligned box on a regular grid, with outward normals."""
    size = np.asarray(size_m, dtype=np.float64)
    centre = np.asarray(centre_m, dtype=np.float64)
    points, normals = [], []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        u = np.arange(-size[others[0]] / 2, size[others[0]] / 2 + 1e-9, spacing_m)
        v = np.arange(-size[others[1]] / 2, size[others[1]] / 2 + 1e-9, spacing_m)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        for sign in (-1.0, 1.0):
            face = np.zeros((uu.size, 3))
            face[:, others[0]] = uu.ravel()
            face[:, others[1]] = vv.ravel()
            face[:, axis] = sign * size[axis] / 2
            normal = np.zeros((uu.size, 3))
            normal[:, axis] = sign
            points.append(face + centre)
            normals.append(normal)
    return np.concatenate(points), np.concatenate(normals)


def cylinder_surface(radius_m, height_m, base_centre_m, spacing_m=0.004):
    """Side and caps of an upright cylinder standing on ``base_centre_m``, with outward normals."""
    base = np.asarray(base_centre_m, dtype=np.float64)
    n_around = max(8, int(2 * math.pi * radius_m / spacing_m))
    theta = np.linspace(0, 2 * math.pi, n_around, endpoint=False)
    heights = np.arange(0, height_m + 1e-9, spacing_m)
    tt, hh = np.meshgrid(theta, heights, indexing="ij")
    radial = np.stack((np.cos(tt.ravel()), np.sin(tt.ravel()), np.zeros(tt.size)), axis=1)
    side = radial * radius_m + np.stack((np.zeros(tt.size), np.zeros(tt.size), hh.ravel()), axis=1)
    grid = np.arange(-radius_m, radius_m + 1e-9, spacing_m)
    gx, gy = np.meshgrid(grid, grid, indexing="ij")
    inside = gx.ravel() ** 2 + gy.ravel() ** 2 <= radius_m**2
    disc = np.stack((gx.ravel()[inside], gy.ravel()[inside]), axis=1)
    caps, cap_normals = [], []
    for z, nz in ((0.0, -1.0), (height_m, 1.0)):
        caps.append(np.concatenate((disc, np.full((len(disc), 1), z)), axis=1))
        cap_normals.append(np.tile([0.0, 0.0, nz], (len(disc), 1)))
    points = np.concatenate([side] + caps) + base
    normals = np.concatenate([radial] + cap_normals)
    return points, normals


def make_cloud(points, normals, object_id="test_object", obstacles=None):
    return PerceivedCloud(
        points_world=torch.as_tensor(points, dtype=torch.float32),
        normals_world=torch.as_tensor(normals, dtype=torch.float32),
        view_index=torch.zeros(len(points), dtype=torch.int64),
        crop_rgb=np.zeros((4, 4, 3), dtype=np.uint8),
        cameras=[],
        object_id=object_id,
        object_position_world=np.asarray(points).mean(axis=0),
        object_quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]),
        obstacle_points_world=torch.zeros(0, 3) if obstacles is None else torch.as_tensor(obstacles, dtype=torch.float32),
    )
