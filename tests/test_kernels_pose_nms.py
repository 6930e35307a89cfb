"""Pose-space suppression: the same grasp is one centre within the translation threshold and one frame
(or its half-turn flip about the approach) within the rotation threshold; survivors are greedy in order."""
import math

import torch
from scipy.spatial.transform import Rotation

from sagp_batched_kernels.pose_nms import KEPT_CHUNK, distinct_grasp_count, pose_nms, same_grasp

FLIP = torch.diag(torch.tensor([-1.0, -1.0, 1.0], dtype=torch.float64))


def _frames(rotations):
    return torch.as_tensor(rotations.as_matrix(), dtype=torch.float64)


def test_a_grasp_turned_half_a_turn_about_its_approach_is_the_same_grasp():
    frame = _frames(Rotation.random(random_state=0))[None]
    centre = torch.zeros(1, 3)
    assert same_grasp(centre, frame, centre, frame @ FLIP, 0.01, math.radians(20)).item()
    assert pose_nms(torch.zeros(2, 3), torch.cat([frame, frame @ FLIP]), 0.01, math.radians(20)).tolist() == [0]


def test_thresholds_separate_grasps_just_beyond_them():
    frame = torch.eye(3, dtype=torch.float64)[None]
    turned = _frames(Rotation.from_euler("x", 25, degrees=True))[None]
    centre, moved = torch.zeros(1, 3), torch.tensor([[0.015, 0.0, 0.0]])
    assert not same_grasp(centre, frame, centre, turned, 0.01, math.radians(20)).item()
    assert same_grasp(centre, frame, centre, turned, 0.01, math.radians(30)).item()
    assert not same_grasp(centre, frame, moved, frame, 0.01, math.radians(20)).item()
    assert same_grasp(centre, frame, moved, frame, 0.02, math.radians(20)).item()


def _greedy_reference(positions, rotations, translation_m, rotation_rad):
    kept = []
    for i in range(len(positions)):
        if not kept or not same_grasp(positions[i:i + 1], rotations[i:i + 1], positions[kept], rotations[kept], translation_m, rotation_rad).any():
            kept.append(i)
    return kept


def test_blocked_suppression_equals_the_one_by_one_greedy_sweep():
    generator = torch.Generator().manual_seed(3)
    positions = torch.rand(700, 3, generator=generator) * 0.05
    rotations = _frames(Rotation.random(700, random_state=4))
    reference = _greedy_reference(positions, rotations, 0.01, math.radians(40))
    assert pose_nms(positions, rotations, 0.01, math.radians(40), block=64).tolist() == reference
    assert pose_nms(positions, rotations, 0.01, math.radians(40), block=4096).tolist() == reference
    assert distinct_grasp_count(positions, rotations, 0.01, math.radians(40)) == len(reference) < 700


def test_a_dense_capture_keeps_what_the_one_by_one_sweep_keeps():
    """Thousands of poses around a few frames, as a capture's candidates crowd a small object: most are
    suppressed by a kept one, more than one chunk of kept ones exists (``KEPT_CHUNK``), and the grasps
    no kept one suppressed are swept inside each block."""
    generator = torch.Generator().manual_seed(5)
    n = 4000
    positions = torch.rand(n, 3, generator=generator) * 0.06
    frames = _frames(Rotation.random(6, random_state=6))
    jitter = _frames(Rotation.from_rotvec(torch.randn(n, 3, generator=generator).numpy() * 0.15))
    rotations = frames[torch.randint(0, 6, (n,), generator=generator)] @ jitter
    reference = _greedy_reference(positions, rotations, 0.01, math.radians(20))
    assert 4 * KEPT_CHUNK < len(reference) < n / 2
    assert pose_nms(positions, rotations, 0.01, math.radians(20)).tolist() == reference
    assert pose_nms(positions, rotations, 0.01, math.radians(20), block=300).tolist() == reference
