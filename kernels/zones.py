"""Coarse-zone geometry of object clouds (SPEC stage 3), batched over clouds.

Clouds of different sizes share one padded batch: ``points`` (B, N, 3) with a ``valid`` (B, N) mask;
padded entries may hold any finite value and never influence a result. Every position is in the
world frame, metres. Clustering of protruding points (DBSCAN) is not a tensor operation and is left
to the caller; these kernels give it the far points and map candidates to cloud points.
"""
from __future__ import annotations

import torch

BOTTOM, MIDDLE, TOP = 0, 1, 2


def _masked_mean(values: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    weights = valid.to(values.dtype).unsqueeze(-1)
    count = weights.sum(dim=-2).clamp_min(1.0)
    return (values * weights).sum(dim=-2) / count


def principal_frame(
    points: torch.Tensor,
    valid: torch.Tensor,
    up: torch.Tensor,
    left: torch.Tensor,
    front: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The object's principal frame, with its axes named by world references.

    Args:
        points: (B, N, 3) cloud points, world frame, metres.
        valid: (B, N) bool, which points are real (not padding).
        up: (3,) unit world up; the principal axis most aligned with it (either sign) is the vertical.
        left: (3,) unit world direction called "left"; of the two remaining axes the one more aligned
            with it is the lateral axis.
        front: (3,) unit world direction called "front"; the last axis is the depth axis.

    Returns:
        centroid: (B, 3) mean of the valid points, world frame.
        axes: (B, 3, 3) orthonormal columns (vertical, lateral, depth), world frame, each signed to
            point along ``up`` / ``left`` / ``front`` (a zero dot product keeps the positive sign).
        eigenvalues: (B, 3) covariance eigenvalues of (vertical, lateral, depth), m^2.
    """
    centroid = _masked_mean(points, valid)
    centred = (points - centroid.unsqueeze(1)) * valid.unsqueeze(-1).to(points.dtype)
    count = valid.sum(dim=1).clamp_min(1).to(points.dtype)
    covariance = centred.transpose(1, 2) @ centred / count.view(-1, 1, 1)
    # float64 eigh: near-degenerate covariances of float32 clouds otherwise lose their small axes.
    eigenvalues, eigenvectors = torch.linalg.eigh(covariance.double())
    eigenvalues, eigenvectors = eigenvalues.to(points.dtype), eigenvectors.to(points.dtype)

    batch = torch.arange(points.shape[0], device=points.device)
    vertical_index = (eigenvectors.transpose(1, 2) @ up).abs().argmax(dim=1)
    others = torch.stack([(vertical_index + 1) % 3, (vertical_index + 2) % 3], dim=1)
    other_axes = eigenvectors.transpose(1, 2)[batch.unsqueeze(1), others]  # (B, 2, 3)
    lateral_pick = (other_axes @ left).abs().argmax(dim=1)
    lateral_index = others[batch, lateral_pick]
    depth_index = others[batch, 1 - lateral_pick]

    order = torch.stack([vertical_index, lateral_index, depth_index], dim=1)  # (B, 3)
    axes = eigenvectors.transpose(1, 2)[batch.unsqueeze(1), order].transpose(1, 2)
    references = torch.stack([up, left, front], dim=1)  # (3, 3) columns
    signs = torch.where((axes * references).sum(dim=1) < 0, -1.0, 1.0).to(points.dtype)
    axes = axes * signs.unsqueeze(1)
    return centroid, axes, eigenvalues[batch.unsqueeze(1), order]


def zone_coordinates(
    points: torch.Tensor,
    valid: torch.Tensor,
    centroid: torch.Tensor,
    axes: torch.Tensor,
    min_split_extent_m: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each point's vertical third and side of the lateral and depth axes.

    Args:
        points: (B, N, 3) world frame, metres; valid: (B, N) bool.
        centroid: (B, 3) world frame; axes: (B, 3, 3) columns (vertical, lateral, depth).
        min_split_extent_m: a cloud whose vertical extent is below this is not split: all its
            points are MIDDLE.

    Returns:
        vertical_third: (B, N) int64 in {BOTTOM, MIDDLE, TOP}: equal thirds of the valid points'
            extent along the vertical axis.
        lateral_positive: (B, N) bool, offset from the centroid along the lateral axis >= 0 ("left").
        depth_positive: (B, N) bool, offset along the depth axis >= 0 ("front").
        Padded entries hold MIDDLE / False.
    """
    offsets = (points - centroid.unsqueeze(1)) @ axes  # (B, N, 3) in (vertical, lateral, depth)
    height = offsets[..., 0]
    inf = torch.tensor(float("inf"), dtype=points.dtype, device=points.device)
    lowest = torch.where(valid, height, inf).amin(dim=1, keepdim=True)
    highest = torch.where(valid, height, -inf).amax(dim=1, keepdim=True)
    extent = highest - lowest
    splittable = extent >= min_split_extent_m
    fraction = (height - lowest) / torch.where(splittable, extent, torch.ones_like(extent))
    third = torch.floor(fraction * 3).clamp(BOTTOM, TOP).long()
    third = torch.where(splittable & valid, third, torch.full_like(third, MIDDLE))
    lateral_positive = (offsets[..., 1] >= 0) & valid
    depth_positive = (offsets[..., 2] >= 0) & valid
    return third, lateral_positive, depth_positive


def far_points(
    points: torch.Tensor, valid: torch.Tensor, centroid: torch.Tensor, distance_factor: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points farther from the centroid than ``distance_factor`` x the median centroid distance.

    Args:
        points: (B, N, 3) world frame, metres; valid: (B, N) bool; centroid: (B, 3) world frame.
        distance_factor: multiple of the median distance beyond which a point is far (SPEC: 1.5).

    Returns:
        far: (B, N) bool, valid far points (protrusion candidates, to be clustered).
        distance: (B, N) centroid distance of each point, metres (padding: 0).
        median_distance: (B,) median centroid distance of the valid points, metres (0 if none).
    """
    distance = torch.linalg.vector_norm(points - centroid.unsqueeze(1), dim=-1)
    distance = torch.where(valid, distance, torch.zeros_like(distance))
    masked = torch.where(valid, distance, torch.full_like(distance, float("nan")))
    median_distance = torch.nan_to_num(torch.nanmedian(masked, dim=1).values, nan=0.0)
    far = valid & (distance > distance_factor * median_distance.unsqueeze(1))
    return far, distance, median_distance


def nearest_point_index(queries: torch.Tensor, points: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Index of the nearest valid cloud point to each query.

    Args:
        queries: (B, C, 3) query positions (e.g. grasp contact midpoints), world frame, metres.
        points: (B, N, 3) cloud points, world frame; valid: (B, N) bool with at least one True per cloud.

    Returns:
        (B, C) int64 indices into N.
    """
    distance = torch.cdist(queries, points)
    distance = torch.where(valid.unsqueeze(1), distance, torch.full_like(distance, float("inf")))
    return distance.argmin(dim=-1)
