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
# Kept grasps a block's free grasps are compared with at a time: small enough that the grasps a chunk
# suppresses skip the rest, large enough that a chunk's fixed cost is small.
KEPT_CHUNK = 256


def _frame_features(rotations: torch.Tensor) -> torch.Tensor:
    """(N, 9) columns of (N, 3, 3) frames laid end to end, so trace(R_a^T R_b) is a dot product of rows."""
    return rotations.transpose(1, 2).reshape(-1, 9)


def _same(positions_a, features_a, positions_b, features_b, flipped_b, translation_m: float, cos_rotation: float) -> torch.Tensor:
    """(A, B) bool ``same_grasp`` on precomputed frame features (``_frame_features``) of both sides."""
    near = torch.cdist(positions_a, positions_b) < translation_m
    a, b = near.nonzero(as_tuple=True)
    same = torch.zeros_like(near)
    same[a, b] = _same_frames(features_a[a], features_b[b], flipped_b[b], cos_rotation)
    return same


def _same_frames(features_a: torch.Tensor, features_b: torch.Tensor, flipped_b: torch.Tensor, cos_rotation: float) -> torch.Tensor:
    """(P,) bool: the P frame pairs (``_frame_features`` rows) are within the rotation, or one flipped.
    Frames are compared only where centres are near: a few pairs of an (A, B) grid."""
    trace = torch.maximum((features_a * features_b).sum(dim=1), (features_a * flipped_b).sum(dim=1))
    # angle < threshold  <=>  cos(angle) = (trace - 1) / 2 > cos(threshold)
    return (trace - 1.0) / 2.0 > cos_rotation


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

    Every pair's verdict is ``same_grasp``'s, but frames are compared only where a verdict can change
    the answer: a grasp is dropped as soon as one kept grasp is the same (``_suppressed``), and inside a
    block only the grasps no kept one suppressed are compared with each other, since only they can be
    kept or suppress. On a dense capture (300,000 poses, a few thousand kept, hundreds of kept ones
    near each pose) that spares most of the frame comparisons, which were most of its time. Centre distances still come from one
    ``cdist`` of the whole block against the kept grasps (and against itself), as ``same_grasp``
    computes them, so that every near/far decision is the same bits.
    """
    centres, features, flipped = _sides(positions, rotations)
    cos_rotation = math.cos(rotation_rad)
    kept = torch.zeros(0, dtype=torch.int64)
    for start in range(0, centres.shape[0], block):
        rows = torch.arange(start, min(centres.shape[0], start + block))
        near_kept = torch.cdist(centres[rows], centres[kept]) < translation_m
        free = (~_suppressed(near_kept, features[rows], features[kept], flipped[kept], cos_rotation)).nonzero().squeeze(1)
        if free.numel() < 2:  # most blocks of a dense capture: nothing left to sweep
            kept = torch.cat((kept, rows[free]))
            continue
        # Among the free grasps of the block: (F, F) same-grasp verdicts, near from the block's own cdist.
        near = (torch.cdist(centres[rows], centres[rows]) < translation_m)[free][:, free]
        a, b = near.nonzero(as_tuple=True)
        inside = torch.zeros_like(near)
        inside[a, b] = _same_frames(features[rows[free[a]]], features[rows[free[b]]], flipped[rows[free[b]]], cos_rotation)
        inside_np, free_np = inside.numpy(), np.ones(len(free), dtype=bool)
        chosen = []
        for i in range(len(free)):
            if free_np[i]:
                chosen.append(i)
                free_np &= ~inside_np[i]
        kept = torch.cat((kept, rows[free[torch.as_tensor(chosen, dtype=torch.int64)]]))
    return kept


def _suppressed(near: torch.Tensor, features: torch.Tensor, kept_features: torch.Tensor, kept_flipped: torch.Tensor, cos_rotation: float) -> torch.Tensor:
    """(R,) bool: the R grasps are the same grasp as some kept one, given their (R, K) ``near`` centres
    and frame features. Kept grasps are taken ``KEPT_CHUNK`` at a time, each chunk only by the grasps
    still free: most grasps meet a kept one that suppresses them in the first chunk."""
    suppressed = torch.zeros(near.shape[0], dtype=torch.bool)
    for first in range(0, near.shape[1], KEPT_CHUNK):
        open_rows = (~suppressed).nonzero().squeeze(1)
        a, b = near[open_rows, first : first + KEPT_CHUNK].nonzero(as_tuple=True)
        b = b + first
        same = _same_frames(features[open_rows[a]], kept_features[b], kept_flipped[b], cos_rotation)
        suppressed[open_rows[a[same]]] = True
    return suppressed


def distinct_grasp_count(positions: torch.Tensor, rotations: torch.Tensor, translation_m: float, rotation_rad: float) -> int:
    """How many of N grasps ((N, 3) centres, (N, 3, 3) frames) are distinct at the thresholds: the
    size of the greedy suppression's survivors in the given order."""
    return int(pose_nms(positions, rotations, translation_m, rotation_rad).numel())
