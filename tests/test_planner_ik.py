"""Batched Panda IK: solutions reach their targets, stay inside the joint limits, and are deterministic."""
import math

import pytest
import torch

from sagp_batched.config import Config
from sagp_batched.ik import PandaIK


@pytest.fixture(scope="module")
def ik():
    config = Config()
    return PandaIK(config.planner, config.scene.robot_base_xyz_m)


def _reachable_targets(ik, n, seed):
    """Poses the arm provably reaches: forward kinematics of joints inside the limits, near the table."""
    generator = torch.Generator().manual_seed(seed)
    ready = torch.tensor(ik.config.ik_reference_joints)
    joints = (ready + 0.4 * torch.randn(n, 7, generator=generator)).clamp(ik.lower, ik.upper)
    return ik.forward(joints)


def test_round_trip_reaches_targets_inside_limits(ik):
    targets = _reachable_targets(ik, 200, seed=0)
    result = ik.solve(targets[:, :3, 3], targets[:, :3, :3])
    assert result.success.float().mean() > 0.9
    assert ((result.joints >= ik.lower) & (result.joints <= ik.upper)).all()
    reached = ik.forward(result.joints[result.success])
    position_error = (reached[:, :3, 3] - targets[result.success, :3, 3]).norm(dim=1)
    assert position_error.max() < ik.config.ik_pos_tolerance_m
    relative = reached[:, :3, :3].transpose(1, 2) @ targets[result.success, :3, :3]
    angle = torch.arccos(((relative.diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2).clamp(-1, 1))
    assert angle.max() < ik.config.ik_rot_tolerance_rad + 1e-3
    assert (result.s_reach[result.success] > (1 + math.cos(ik.config.ik_rot_tolerance_rad)) / 2 - 1e-6).all()


def test_targets_out_of_reach_fail(ik):
    targets = _reachable_targets(ik, 20, seed=1)
    far = targets[:, :3, 3] + torch.tensor([2.0, 0.0, 0.0])
    result = ik.solve(far, targets[:, :3, :3])
    assert not result.success.any()
    assert (result.position_error_m > 0.5).all()


def test_solutions_are_deterministic_and_seed_joints_are_used(ik):
    targets = _reachable_targets(ik, 50, seed=2)
    first = ik.solve(targets[:, :3, 3], targets[:, :3, :3])
    second = ik.solve(targets[:, :3, 3], targets[:, :3, :3])
    assert torch.equal(first.joints, second.joints)
    seeded = ik.solve(targets[:, :3, 3], targets[:, :3, :3], seed_joints=first.joints)
    assert seeded.success[first.success].all()


def test_bad_shapes_are_named(ik):
    with pytest.raises(ValueError, match="positions_world"):
        ik.solve(torch.zeros(3, 4), torch.eye(3).expand(3, 3, 3))
