"""Clearance between point clouds and a gripper's collision hulls bounded by k-DOPs.

A k-DOP is a convex polytope given by its extent [low_d, high_d] along D fixed unit directions.
For a point p (in the polytope's frame) the separation

    s(p) = max_d max(p . u_d - high_d, low_d - p . u_d)

is positive outside the polytope and a lower bound on p's Euclidean distance to it (each term is
the distance to one supporting slab), and <= 0 inside. The gripper is several such polytopes in
the grasp frame (origin at the grasp centre, see ``grasp_frames``); a point's separation from
the gripper is its smallest separation from any of them.

The same maximum over only the first three directions is a lower bound of s(p) at a quarter of
the cost. It picks the points likely to strike a gripper first and rules out points that cannot
change the answer, so s(p) is evaluated on a few dozen of a scene's ~1,000 points.
"""
from __future__ import annotations

from typing import NamedTuple

import torch

from .grasp_frames import scene_points_about

# Probe points whose exact separation is evaluated first, nearest by the lower bound: a blocked
# grasp almost always has one of them under the margin.
PROBE_POINTS = 16
# The lower bound's float32 rounding (~1e-8 m at gripper sizes) is far inside this slack.
BOUND_SLACK_M = 1e-6
# MKL's batched GEMM rounds like the exhaustive product only from 12 columns up.
MIN_GEMM_COLUMNS = 16
# (candidate, polytope, axis, probe) elements of the probes' bound computed at once: blocks of
# ~1 MB temporaries, measured 6-8 % faster over a plan's checks than the point pass's blocks.
PROBE_BLOCK_ELEMENTS = 262_144


class HandClearance(NamedTuple):
    blocked: torch.Tensor  # (C,) bool: some point's separation from the gripper is under the margin
    # (C,) float32 smallest separation of any point where not blocked (inf without points); where
    # blocked, the smallest among the points evaluated, an upper bound of it.
    clearance_m: torch.Tensor


def _slab_excess(projection: torch.Tensor, middle: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """(c, S, d, n) |projection - middle| - half for (c, 1, d, n) projections and (1, S, d, 1) slabs.

    In place on the one temporary: these are the sweep's largest tensors (~1 MB a block), and
    fresh allocations of that size cost as much as the arithmetic."""
    return (projection - middle).abs_().sub_(half)


def _separation(relative: torch.Tensor, axes: torch.Tensor, middle: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """(c, n) separation s(p) of points ``relative`` (c, n, 3) from the polytopes, NaN rows -> inf."""
    n_points = relative.shape[1]
    padded = torch.cat((relative, relative.new_full((relative.shape[0], max(0, MIN_GEMM_COLUMNS - n_points), 3), float("nan"))), dim=1)
    # Projections on the k-DOP directions in one GEMM: (u_d^T R^T) (p - centre).
    projection = (axes @ padded.transpose(1, 2))[:, None, :, :n_points]  # (c, 1, D, n)
    separation = _slab_excess(projection, middle, half).amax(dim=2).amin(dim=1)
    return torch.nan_to_num(separation, nan=float("inf"))


def _lower_bound(relative: torch.Tensor, axes: torch.Tensor, middle: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """(c, n) a lower bound of s(p) from the first three directions only, NaN rows -> inf."""
    projection = (axes[:, :3] @ relative.transpose(1, 2))[:, None]  # (c, 1, 3, n)
    bound = _slab_excess(projection, middle[:, :, :3], half[:, :, :3]).amax(dim=2).amin(dim=1)
    return torch.nan_to_num(bound, nan=float("inf")) - BOUND_SLACK_M


def _gather(relative: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    return relative.gather(1, index[:, :, None].expand(-1, -1, 3))


def _compacted(relative: torch.Tensor, chosen: torch.Tensor, per_row: torch.Tensor) -> torch.Tensor:
    """(r, max per_row, 3) each row's ``chosen`` points of ``relative`` (r, n, 3) in index order,
    then NaN padding; ``per_row``: (r,) ``chosen.sum(dim=1)``.

    Scattered to their places from ``nonzero``'s row-major list rather than ordered by a stable
    sort of the mask: the sort of every (row, point) flag cost an eighth of the sweep."""
    row, point = chosen.nonzero(as_tuple=True)
    slot = torch.arange(row.numel()) - (per_row.cumsum(0) - per_row)[row]
    compact = relative.new_full((relative.shape[0], int(per_row.max()), 3), float("nan"))
    compact[row, slot] = relative[row, point]
    return compact


def hand_clearance(
    points: torch.Tensor,
    probe_points: torch.Tensor,
    object_index: torch.Tensor,
    centre: torch.Tensor,
    rotation: torch.Tensor,
    directions: torch.Tensor,
    low: torch.Tensor,
    high: torch.Tensor,
    margin_m: float,
    chunk_elements: int,
) -> HandClearance:
    """Whether each candidate gripper comes within ``margin_m`` of a point of its scene, and its clearance.

    Args:
        points: (B, N, 3) points of B scenes, world frame, metres; NaN rows are padding.
        probe_points: (B, P, 3) a subset of each scene's points (e.g. one per coarse voxel, NaN
            padded) among which the nearest, by the lower bound, are evaluated first.
        object_index: (C,) int64 scene of each candidate, in [0, B).
        centre: (C, 3) grasp-frame origins, world frame.
        rotation: (C, 3, 3) grasp frames (grasp -> world rotation).
        directions: (D, 3) unit k-DOP directions, grasp frame, D >= 3; the first three also
            give the lower bound that culls points (the axes, for box-like hulls).
        low, high: (S, D) extents of S polytopes along ``directions``, metres (low <= high).
        margin_m: a point with separation under this blocks the gripper.
        chunk_elements: bound on the (candidate, polytope, direction, point) elements held at once.

    Returns:
        ``HandClearance`` of (C,) tensors; every separation it reports is the exhaustive
        computation's for that point, bit for bit, so ``blocked`` is exactly "some point of
        ``points`` is under the margin".
    """
    if points.ndim != 3 or points.shape[-1] != 3 or probe_points.ndim != 3 or probe_points.shape[-1] != 3:
        raise ValueError(f"points and probe_points must be (B, N, 3), got {tuple(points.shape)} and {tuple(probe_points.shape)}")
    if rotation.shape != (centre.shape[0], 3, 3):
        raise ValueError(f"rotation must be (C, 3, 3) matching centre (C, 3), got {tuple(rotation.shape)} and {tuple(centre.shape)}")
    if low.shape != high.shape or low.shape[1] != directions.shape[0] or directions.shape[0] < 3:
        raise ValueError(f"low and high must be (S, D) with D = {directions.shape[0]} >= 3, got {tuple(low.shape)} and {tuple(high.shape)}")
    n_candidates, n_points = centre.shape[0], points.shape[1]
    middle = ((low + high) / 2)[None, :, :, None]  # (1, S, D, 1)
    half = ((high - low) / 2)[None, :, :, None]
    clearance = torch.full((n_candidates,), float("inf"))
    n_probe = min(PROBE_POINTS, probe_points.shape[1])
    step = max(1, chunk_elements // max(1, low.numel() * n_points))
    if n_probe:
        # The probes of every candidate first, in blocks sized by the probes' own bound tensor.
        probe_step = max(1, min(chunk_elements, PROBE_BLOCK_ELEMENTS) // max(1, low.shape[0] * 3 * probe_points.shape[1]))
        for start in range(0, n_candidates, probe_step):
            stop = min(start + probe_step, n_candidates)
            axes = directions @ rotation[start:stop].transpose(-1, -2)  # (c, D, 3)
            probe = scene_points_about(probe_points, object_index[start:stop], centre[start:stop])  # (c, P, 3)
            nearest = _lower_bound(probe, axes, middle, half).topk(n_probe, dim=1, largest=False).indices
            clearance[start:stop] = _separation(_gather(probe, nearest), axes, middle, half).amin(dim=1)
    for start in range(0, n_candidates, step):
        stop = min(start + step, n_candidates)
        # The rest only where the probes left the gripper clear; there only points whose bound is
        # under the probes' clearance can block it or lower that clearance.
        rows = (clearance[start:stop] >= margin_m).nonzero().squeeze(1)
        if not rows.numel():
            continue
        axes = directions @ rotation[start + rows].transpose(-1, -2)  # (r, D, 3)
        relative = scene_points_about(points, object_index[start + rows], centre[start + rows])  # (r, N, 3)
        candidates = _lower_bound(relative, axes, middle, half) < clearance[start + rows, None]
        per_row = candidates.sum(dim=1)
        if int(per_row.max()):
            found = _separation(_compacted(relative, candidates, per_row), axes, middle, half).amin(dim=1)
            clearance[start + rows] = torch.minimum(clearance[start + rows], found)
    return HandClearance(clearance < margin_m, clearance)
