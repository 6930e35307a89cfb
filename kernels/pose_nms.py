"""Pose-space non-maximum suppression of parallel-jaw grasps (graspnetAPI's ``GraspGroup.nms`` rule).

Two grasps are the same grasp when their centres lie within a translation threshold and their frames
within a rotation threshold. A parallel-jaw gripper turned half a turn about its approach holds the
object the same way, so that flip counts as the same frame (graspnetAPI compares frames as given;
counting flipped duplicates as distinct would inflate a dataset's diversity).

Written here rather than taken from graspnetAPI: its ``nms`` is a compiled extension (``grasp_nms``)
that needs a C++ build and the whole GraspNet stack; this is a few matrix products in torch.
"""
from __future__ import annotations

import math

import torch

# Signs that turn trace(R_a^T R_b) into trace(R_a^T R_b Rz(pi)): the flip negates the frames' x and y columns.
_FLIP_SIGNS = torch.tensor([-1.0, -1.0, 1.0])


def _frame_features(rotations: torch.Tensor) -> torch.Tensor:
    """(N, 9) columns of (N, 3, 3) frames laid end to end, so trace(R_a^T R_b) is a dot product of rows."""
    return rotations.transpose(1, 2).reshape(-1, 9)


def _same(positions_a, features_a, positions_b, features_b, flipped_b, translation_m: float, cos_rotation: float) -> torch.Tensor:
    """(A, B) bool ``same_grasp`` on precomputed frame features (``_frame_features``) of both sides."""
    near = torch.cdist(positions_a, positions_b) < translation_m
    a, b = near.nonzero(as_tuple=True)
    # Frames are compared only where centres are near: a few pairs of the (A, B) grid.
    trace = torch.maximum((features_a[a] * features_b[b]).sum(dim=1), (features_a[a] * flipped_b[b]).sum(dim=1))
    same = torch.zeros_like(near)
    # angle < threshold  <=>  cos(angle) = (trace - 1) / 2 > cos(threshold)
    same[a, b] = (trace - 1.0) / 2.0 > cos_rotation
    return same


def _sides(positions: torch.Tensor, rotations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Centres in float32 (millimetre thresholds, metre coordinates), frame features and those of the flipped frames in float64."""
    rotations = rotations.double()
    return positions.float(), _frame_features(rotations), _frame_features(rotations * _FLIP_SIGNS.double())


def same_grasp(
    positions_a: torch.Tensor,
    rotations_a: torch.Tensor,
    positions_b: torch.Tensor,
    rotations_b: torch.Tensor,
    translation_m: float,
    rotation_rad: float,
) -> torch.Tensor:
    """(A, B) bool: grasp a is the same grasp as grasp b.

    positions: (A, 3) / (B, 3) grasp centres (m); rotations: (A, 3, 3) / (B, 3, 3) grasp frames whose
    z column is the approach (any frame convention works as long as both sides share it), same frame.
    Same: centres closer than ``translation_m`` and frames, or one of them flipped half a turn about
    its z axis, closer than ``rotation_rad`` (geodesic angle).
    """
    side_a, side_b = _sides(positions_a, rotations_a), _sides(positions_b, rotations_b)
    return _same(side_a[0], side_a[1], *side_b, translation_m, math.cos(rotation_rad))


def pose_nms(
    positions: torch.Tensor,
    rotations: torch.Tensor,
    translation_m: float,
    rotation_rad: float,
    block: int = 1024,
) -> torch.Tensor:
    """(K,) int64 indices of the grasps kept by greedy suppression in the given order (best first).

    positions: (N, 3) grasp centres (m); rotations: (N, 3, 3) grasp frames, z = approach. A grasp is
    kept unless it is the same grasp (``same_grasp``) as one kept before it. Blocks of ``block``
    grasps are compared against every kept grasp at once; only inside a block is the sweep sequential.
    """
    centres, features, flipped = _sides(positions, rotations)
    cos_rotation = math.cos(rotation_rad)
    kept = torch.zeros(0, dtype=torch.int64)
    for start in range(0, centres.shape[0], block):
        rows = torch.arange(start, min(centres.shape[0], start + block))
        free = ~_same(centres[rows], features[rows], centres[kept], features[kept], flipped[kept], translation_m, cos_rotation).any(dim=1)
        inside = _same(centres[rows], features[rows], centres[rows], features[rows], flipped[rows], translation_m, cos_rotation).numpy()
        free_np = free.numpy().copy()
        chosen = []
        for i in range(len(rows)):
            if free_np[i]:
                chosen.append(i)
                free_np &= ~inside[i]
        kept = torch.cat((kept, rows[torch.as_tensor(chosen, dtype=torch.int64)]))
    return kept


def distinct_grasp_count(positions: torch.Tensor, rotations: torch.Tensor, translation_m: float, rotation_rad: float) -> int:
    """How many of N grasps ((N, 3) centres, (N, 3, 3) frames) are distinct at the thresholds: the
    size of the greedy suppression's survivors in the given order."""
    return int(pose_nms(positions, rotations, translation_m, rotation_rad).numel())
