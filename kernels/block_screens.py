"""The swept hand against a point set as one fixed sequence of element-wise operations: every pose
against every point, each (pose, point) value from its own arithmetic, so the work has the block's
shape whatever the data.

``hand_clearance`` spends its time deciding which poses and points need exact work (bounds, probes,
compaction); this spends it on the work itself, in a shape a compiler fuses into one loop
(``torch.compile``: each (pose, point) value stays in registers) and a GPU runs in one launch. Over
a scene's coarse subset (a few hundred points) that is cheap, and it blocks most blocked poses;
the block search (``planning.block_search``) sweeps only the rest over every point. Eager on a CPU
it runs on slices of ``POSE_SLICE`` poses, whose (pose, point) temporaries stay in cache.

Frames: points, centres and frames in the world; a pose's grasp-frame coordinates are R^T (p - c)
(``grasp_frames``). Each value differs from ``hand_clearance``'s GEMMs by rounding alone (~1e-8 m at
gripper sizes), and it only ever blocks a pose, whose every point ``hand_clearance`` would also reach.
"""
from __future__ import annotations

import torch

# Poses per eager slice: a slice's (pose, point) temporaries of ~1,000 points are ~1 MB.
POSE_SLICE = 256


def least_separation(
    columns: torch.Tensor, centre: torch.Tensor, frames: torch.Tensor, directions: torch.Tensor, low: torch.Tensor, high: torch.Tensor,
) -> torch.Tensor:
    """(P,) each pose's least k-DOP separation s(p) of the swept hand from the points: the largest
    slab excess over the D directions, least over the S polytopes (see ``hand_clearance``), every
    point of every pose evaluated. Over a coarse subset of a scene (one point per 2 cm cell) it is
    an upper bound of the least separation from the whole scene that already blocks most blocked
    poses, at a few hundred points a pose.

    Args:
        columns: (3, N) points as world x, y and z rows (NaN columns: padding, never near).
        centre: (P, 3) grasp centres, world. frames: (P, 3, 3) grasp frames (grasp -> world).
        directions: (D, 3) unit k-DOP directions, grasp frame.
        low, high: (S, D) the polytopes' extents, metres.
    """
    axes = directions @ frames.transpose(1, 2)  # (P, D, 3): u_d^T R^T
    projection = [_projected(columns, centre, axes[:, d]) for d in range(directions.shape[0])]
    separation = _least_excess(projection, (low + high) / 2, (high - low) / 2).nan_to_num(nan=float("inf"))
    return separation.amin(dim=1)


def _projected(columns: torch.Tensor, centre: torch.Tensor, axis: torch.Tensor) -> torch.Tensor:
    """(P, N) a . (p - c) of the points (``columns`` (3, N)) for P axes a (P, 3) and centres c (P, 3)."""
    return ((axis[:, 0, None] * (columns[0] - centre[:, 0, None]) + axis[:, 1, None] * (columns[1] - centre[:, 1, None]))
            + axis[:, 2, None] * (columns[2] - centre[:, 2, None]))


def _least_excess(projection: list[torch.Tensor], middle: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """The largest slab excess |projection_d - middle_d| - half_d over the directions of ``projection``
    (D tensors of one shape), least over the (S, D) polytopes' ``middle`` and ``half``."""
    least = None
    for polytope in range(middle.shape[0]):
        excess = None
        for d, values in enumerate(projection):
            term = (values - middle[polytope, d]).abs() - half[polytope, d]
            excess = term if excess is None else torch.maximum(excess, term)
        least = excess if least is None else torch.minimum(least, excess)
    return least
