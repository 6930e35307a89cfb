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

import numpy as np
import torch

# Signs that turn trace(R_a^T R_b) into trace(R_a^T R_b Rz(pi)): the flip negates the frames' x and y columns.
_FLIP_SIGNS = torch.tensor([-1.0, -1.0, 1.0])


def _frame_features(rotations: torch.Tensor) -> torch.Tensor:
    """(N, 9) columns of (N, 3, 3) frames laid end to end, so trace(R_a^T R_b) is a dot product of rows."""
    return rotations.transpose(1, 2).reshape(-1, 9)


def same_grasp(
    positions_a: torch.Tensor,
    rotations_a: torch.Tensor,
    positions_b: torch.Tensor,
    rotations_b: torch.Tensor,
    translation_m: float,
    rotation_rad: float,
) -> torch.Tensor:
    """(A, B) bool: grasp a is the same grasp as grasp b.

    Centres are compared in float32 (millimetre thresholds, metre coordinates), frames in float64.

    positions: (A, 3) / (B, 3) grasp centres (m); rotations: (A, 3, 3) / (B, 3, 3) grasp frames whose
    z column is the approach (any frame convention works as long as both sides share it), same frame.
    Same: centres closer than ``translation_m`` and frames, or one of them flipped half a turn about
    its z axis, closer than ``rotation_rad`` (geodesic angle).
    """
    near = torch.cdist(positions_a.float(), positions_b.float()) < translation_m
    a, b = near.nonzero(as_tuple=True)
    # Frames are compared only where centres are near: a few pairs of the (A, B) grid.
    features_a = _frame_features(rotations_a.double()[a])
    features_b = _frame_features(rotations_b.double()[b])
    flipped_b = _frame_features(rotations_b.double()[b] * _FLIP_SIGNS.double())
    trace = torch.maximum((features_a * features_b).sum(dim=1), (features_a * flipped_b).sum(dim=1))
    # angle < threshold  <=>  cos(angle) = (trace - 1) / 2 > cos(threshold)
    same = torch.zeros_like(near)
    same[a, b] = (trace - 1.0) / 2.0 > math.cos(rotation_rad)
    return same


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
    n = positions.shape[0]
    kept: list[int] = []
    kept_positions = positions[:0]
    kept_rotations = rotations[:0]
    for start in range(0, n, block):
        stop = min(n, start + block)
        block_positions, block_rotations = positions[start:stop], rotations[start:stop]
        free = ~same_grasp(block_positions, block_rotations, kept_positions, kept_rotations, translation_m, rotation_rad).any(dim=1)
        inside = same_grasp(block_positions, block_rotations, block_positions, block_rotations, translation_m, rotation_rad).numpy()
        free_np = free.numpy().copy()
        chosen = []
        for i in range(stop - start):
            if free_np[i]:
                chosen.append(i)
                free_np &= ~inside[i]
        chosen_index = torch.as_tensor(np.asarray(chosen, dtype=np.int64))
        kept.extend((chosen_index + start).tolist())
        kept_positions = torch.cat((kept_positions, block_positions[chosen_index]))
        kept_rotations = torch.cat((kept_rotations, block_rotations[chosen_index]))
    return torch.as_tensor(kept, dtype=torch.int64)


def distinct_grasp_count(positions: torch.Tensor, rotations: torch.Tensor, translation_m: float, rotation_rad: float) -> int:
    """How many of N grasps ((N, 3) centres, (N, 3, 3) frames) are distinct at the thresholds: the
    size of the greedy suppression's survivors in the given order."""
    return int(pose_nms(positions, rotations, translation_m, rotation_rad).numel())
