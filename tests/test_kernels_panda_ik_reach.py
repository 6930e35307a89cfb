"""The wrist-reach test rules out only targets the closed-form IK has no solution for at any q7."""
import pytest
import torch

from sagp_batched.ik import N_ARM_JOINTS, _panda_chain, link_moved_by, panda_arm_geometry
from sagp_batched.robot import PANDA
from sagp_batched_kernels.panda_ik import panda_ik_closed_form, wrist_in_reach


@pytest.fixture(scope="module")
def chain64():
    return _panda_chain().to(dtype=torch.float64)


@pytest.fixture(scope="module")
def limits(chain64):
    return tuple(torch.tensor(bound, dtype=torch.float64) for bound in chain64.get_joint_limits())


def _link7_poses(chain64, limits, count, seed):
    lower, upper = limits
    joints = lower + (upper - lower) * torch.rand(count, N_ARM_JOINTS, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return chain64.forward_kinematics(joints, end_only=False)[link_moved_by(chain64, PANDA.arm_joints[-1])].get_matrix()


def test_every_pose_the_arm_reaches_is_in_reach(chain64, limits):
    pose = _link7_poses(chain64, limits, 5000, seed=0)
    assert wrist_in_reach(pose[:, :3, :3], pose[:, :3, 3], panda_arm_geometry(_panda_chain())).all()


def test_targets_out_of_reach_have_no_solution_at_any_q7_and_the_test_is_tight(chain64, limits):
    geometry = panda_arm_geometry(_panda_chain())
    pose = _link7_poses(chain64, limits, 400, seed=1)
    shoulder = torch.tensor([0.0, 0.0, geometry.shoulder_height_m], dtype=torch.float64)
    direction = torch.nn.functional.normalize(pose[:, :3, 3] - shoulder, dim=1)
    # Frame 7 moved along its shoulder ray from 0.5 m to 1.0 m: across the edge of the reach.
    distance = torch.linspace(0.5, 1.0, 400, dtype=torch.float64)[:, None]
    position = shoulder + distance * direction
    in_reach = wrist_in_reach(pose[:, :3, :3], position, geometry)
    q7 = torch.linspace(-4.0, 4.0, 2001, dtype=torch.float64).expand(400, -1)  # beyond the joint's range
    wide = (torch.full((7,), -10.0, dtype=torch.float64), torch.full((7,), 10.0, dtype=torch.float64))
    solvable = panda_ik_closed_form(pose[:, :3, :3], position, q7, geometry, *wide).valid.flatten(1).any(dim=1)
    assert not solvable[~in_reach].any()
    assert (~in_reach).sum() > 50 and in_reach.sum() > 50
    # Tight: near the edge, targets it keeps are mostly solvable with q7 free.
    assert solvable[in_reach].float().mean() > 0.9
