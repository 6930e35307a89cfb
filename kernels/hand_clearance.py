"""Clearance between point clouds and a gripper's collision hulls bounded by k-DOPs.

A k-DOP is a convex polytope given by its extent [low_d, high_d] along D fixed unit directions.
For a point p (in the polytope's frame) the separation

    s(p) = max_d max(p . u_d - high_d, low_d - p . u_d)

is positive outside the polytope and a lower bound on p's Euclidean distance to it (each term is
the distance to one supporting slab), and <= 0 inside. The gripper is several such polytopes in
the grasp frame (origin at the grasp centre, see ``grasp_frames``); a point's separation from
the gripper is its smallest separation from any of them.
"""
from __future__ import annotations

from typing import NamedTuple

import torch


class HandClearance(NamedTuple):
    points_within: torch.Tensor  # (C,) int64 points whose separation from the gripper is under the margin
    clearance_m: torch.Tensor  # (C,) float32 smallest separation of any point (inf without points)


def hand_clearance(
    points: torch.Tensor,
    object_index: torch.Tensor,
    centre: torch.Tensor,
    rotation: torch.Tensor,
    directions: torch.Tensor,
    low: torch.Tensor,
    high: torch.Tensor,
    margin_m: float,
    chunk_elements: int,
) -> HandClearance:
    """Separation of every candidate gripper from the points of its scene.

    Args:
        points: (B, N, 3) points of B scenes, world frame, metres; NaN rows are padding.
        object_index: (C,) int64 scene of each candidate, in [0, B).
        centre: (C, 3) grasp-frame origins, world frame.
        rotation: (C, 3, 3) grasp frames (grasp -> world rotation).
        directions: (D, 3) unit k-DOP directions, grasp frame.
        low, high: (S, D) extents of S polytopes along ``directions``, metres (low <= high).
        margin_m: points with separation under this count in ``points_within``.
        chunk_elements: bound on the (candidate, polytope, direction, point) elements held at once.

    Returns:
        ``HandClearance`` of (C,) tensors.
    """
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"points must be (B, N, 3), got {tuple(points.shape)}")
    if rotation.shape != (centre.shape[0], 3, 3):
        raise ValueError(f"rotation must be (C, 3, 3) matching centre (C, 3), got {tuple(rotation.shape)} and {tuple(centre.shape)}")
    if low.shape != high.shape or low.shape[1] != directions.shape[0]:
        raise ValueError(f"low and high must be (S, D) with D = {directions.shape[0]}, got {tuple(low.shape)} and {tuple(high.shape)}")
    n_candidates, n_points = centre.shape[0], points.shape[1]
    n_directions = directions.shape[0]
    middle = ((low + high) / 2)[None, :, :, None]  # (1, S, D, 1)
    half = ((high - low) / 2)[None, :, :, None]
    within = torch.zeros(n_candidates, dtype=torch.int64)
    clearance = torch.full((n_candidates,), float("inf"))
    step = max(1, chunk_elements // max(1, low.numel() * n_points))
    for start in range(0, n_candidates, step):
        stop = min(start + step, n_candidates)
        relative = points[object_index[start:stop]] - centre[start:stop, None, :]  # (c, N, 3)
        # Projections on the k-DOP directions in one GEMM: (u_d^T R^T) (p - centre).
        axes = directions @ rotation[start:stop].transpose(-1, -2)  # (c, D, 3)
        projection = (axes @ relative.transpose(1, 2)).view(stop - start, 1, n_directions, n_points)
        separation = ((projection - middle).abs() - half).amax(dim=2).amin(dim=1)  # (c, N)
        separation = torch.nan_to_num(separation, nan=float("inf"))
        within[start:stop] = (separation < margin_m).sum(dim=1)
        clearance[start:stop] = separation.amin(dim=1) if n_points else clearance[start:stop]
    return HandClearance(within, clearance)
