"""The closed-form Panda IK reproduces pytorch-kinematics' kinematics of the pybullet_data Panda."""
import pytest
import pytorch_kinematics as pk
import torch

from sagp_batched.robot.description import load_robot
from sagp_batched.robot.kinematics import arm_chain, link_moved_by, panda_arm_geometry
from sagp_batched_kernels.panda_ik import N_BRANCHES, panda_ik_closed_form, wrist_in_reach

ROBOT = load_robot()


@pytest.fixture(scope="module")
def chain64():
    return arm_chain(ROBOT).to(dtype=torch.float64)


@pytest.fixture(scope="module")
def limits(chain64):
    return tuple(torch.tensor(bound, dtype=torch.float64) for bound in chain64.get_joint_limits())


def _random_joints(limits, count, seed):
    lower, upper = limits
    return lower + (upper - lower) * torch.rand(count, ROBOT.n_arm_joints, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def _link7_pose(chain64, joints):
    return chain64.forward_kinematics(joints, end_only=False)[link_moved_by(chain64, ROBOT.arm_joints[-1])].get_matrix()


def test_arm_geometry_is_read_from_the_urdf_chain():
    geometry = panda_arm_geometry(arm_chain(ROBOT), ROBOT)
    expected = (0.333, 0.316, 0.0825, -0.0825, 0.384, 0.088)  # Franka's published Denavit-Hartenberg a and d
    assert geometry == pytest.approx(expected, abs=1e-6)


def test_one_branch_recovers_the_joints_that_made_the_pose(chain64, limits):
    joints = _random_joints(limits, 5000, seed=0)
    pose = _link7_pose(chain64, joints)
    solutions = panda_ik_closed_form(pose[:, :3, :3], pose[:, :3, 3], joints[:, 6:], panda_arm_geometry(arm_chain(ROBOT), ROBOT), *limits)
    assert solutions.joints.shape == (5000, 1, N_BRANCHES, ROBOT.n_arm_joints)
    difference = (solutions.joints[:, 0] - joints[:, None]).abs().amax(dim=-1)  # (N, 8)
    closest = difference.argmin(dim=1)
    assert difference.min(dim=1).values.max() < 1e-4
    assert solutions.valid[torch.arange(5000), 0, closest].all()


def test_every_valid_solution_reaches_the_pose_inside_the_limits(chain64, limits):
    pose = _link7_pose(chain64, _random_joints(limits, 500, seed=1))
    q7 = torch.linspace(float(limits[0][6]), float(limits[1][6]), 16, dtype=torch.float64).expand(500, 16)
    solutions = panda_ik_closed_form(pose[:, :3, :3], pose[:, :3, 3], q7, panda_arm_geometry(arm_chain(ROBOT), ROBOT), *limits)
    target_row = solutions.valid.nonzero()[:, 0]
    valid_joints = solutions.joints[solutions.valid]
    assert len(valid_joints) > 500  # several solutions per pose: the arm is redundant
    reached = _link7_pose(chain64, valid_joints)
    assert (reached[:, :3, 3] - pose[target_row, :3, 3]).norm(dim=1).max() < 1e-9
    assert (reached[:, :3, :3] - pose[target_row, :3, :3]).abs().max() < 1e-9
    assert ((valid_joints >= limits[0]) & (valid_joints <= limits[1])).all()


def test_shoulder_straight_up_is_solved_despite_the_joint_1_3_singularity(chain64, limits):
    joints = torch.tensor([[0.4, 0.0, 0.3, -1.5, 0.2, 1.5, 0.5]], dtype=torch.float64)  # q2 = 0: only q1 + q3 is defined
    pose = _link7_pose(chain64, joints)
    solutions = panda_ik_closed_form(pose[:, :3, :3], pose[:, :3, 3], joints[:, 6:], panda_arm_geometry(arm_chain(ROBOT), ROBOT), *limits)
    reached = _link7_pose(chain64, solutions.joints[solutions.valid])
    assert len(reached) > 0
    assert (reached[:, :3, 3] - pose[0, :3, 3]).norm(dim=1).max() < 1e-9
    assert (reached[:, :3, :3] - pose[0, :3, :3]).abs().max() < 1e-9


def test_a_pose_beyond_reach_has_no_valid_solution(chain64, limits):
    geometry = panda_arm_geometry(arm_chain(ROBOT), ROBOT)
    pose = _link7_pose(chain64, _random_joints(limits, 50, seed=2))
    shoulder = torch.tensor([0.0, 0.0, geometry.shoulder_height_m], dtype=torch.float64)
    direction = torch.nn.functional.normalize(pose[:, :3, 3] - shoulder, dim=1)
    far = shoulder + 1.3 * direction  # frame 7 stays within ~0.81 m of the shoulder
    q7 = torch.linspace(float(limits[0][6]), float(limits[1][6]), 64, dtype=torch.float64).expand(50, 64)
    solutions = panda_ik_closed_form(pose[:, :3, :3], far, q7, geometry, *limits)
    assert not solutions.valid.any()


def test_a_chain_with_a_different_joint_layout_is_refused():
    chain = arm_chain(ROBOT)
    frame = chain.find_frame("panda_link3")
    # A 5 cm offset between joints 2 and 3 along x (a2), which the Panda lacks.
    frame.joint.offset = frame.joint.offset.compose(pk.Transform3d(pos=torch.tensor([0.05, 0.0, 0.0])))
    with pytest.raises(ValueError, match="does not model"):
        panda_arm_geometry(chain, ROBOT)


# The wrist-reach test rules out only targets the closed form has no solution for at any q7.

def test_every_pose_the_arm_reaches_is_in_reach(chain64, limits):
    pose = _link7_pose(chain64, _random_joints(limits, 5000, seed=0))
    assert wrist_in_reach(pose[:, :3, :3], pose[:, :3, 3], panda_arm_geometry(arm_chain(ROBOT), ROBOT)).all()


def test_targets_out_of_reach_have_no_solution_at_any_q7_and_the_test_is_tight(chain64, limits):
    geometry = panda_arm_geometry(arm_chain(ROBOT), ROBOT)
    pose = _link7_pose(chain64, _random_joints(limits, 400, seed=1))
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
