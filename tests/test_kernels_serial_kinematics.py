"""The hand-written chain kinematics reproduce pytorch-kinematics' forward kinematics and Jacobian
of the pybullet_data Panda, and are faster than them at the motion check's batch sizes."""
import time

import pytest
import torch

from sagp_batched.robot.description import load_robot
from sagp_batched.robot.kinematics import ChainFrames, arm_chain

ROBOT = load_robot()


@pytest.fixture(scope="module")
def chain():
    return arm_chain(ROBOT)


def _random_joints(chain, count, seed, dtype=torch.float32):
    lower, upper = (torch.tensor(bound, dtype=dtype) for bound in chain.get_joint_limits())
    return lower + (upper - lower) * torch.rand(count, ROBOT.n_arm_joints, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def _matrices(frames):
    """(F, B, 4, 4) homogeneous transforms of (F, 3, 4, B) ``ChainFrames.poses`` rows."""
    bottom = torch.zeros(frames.shape[0], 1, 4, frames.shape[3], dtype=frames.dtype)
    bottom[:, :, 3] = 1.0
    return torch.cat((frames, bottom), dim=1).permute(0, 3, 1, 2)


def test_every_frame_pose_matches_pytorch_kinematics_to_a_micrometre_in_float32(chain):
    joints = _random_joints(chain, 5000, seed=0)
    frames = ChainFrames.of(chain)
    poses = _matrices(frames.poses(joints))
    expected = chain.forward_kinematics(joints, end_only=False)
    assert frames.names[-1] == chain.get_frame_names(exclude_fixed=False)[-1]
    for index, name in enumerate(frames.names):
        assert torch.allclose(poses[index], expected[name].get_matrix(), rtol=0.0, atol=1e-6), name


def test_poses_and_jacobian_match_pytorch_kinematics_to_rounding_in_float64(chain):
    chain64 = arm_chain(ROBOT).to(dtype=torch.float64)
    joints = _random_joints(chain64, 2000, seed=1, dtype=torch.float64)
    frames = ChainFrames.of(chain64)
    poses = frames.poses(joints)
    assert torch.allclose(_matrices(poses), chain64.forward_kinematics_tensor(joints), rtol=0.0, atol=1e-12)
    assert torch.allclose(frames.jacobian(poses), chain64.jacobian(joints), rtol=0.0, atol=1e-12)


def test_the_jacobian_matches_pytorch_kinematics_to_a_micrometre_in_float32(chain):
    joints = _random_joints(chain, 5000, seed=2)
    frames = ChainFrames.of(chain)
    assert torch.allclose(frames.jacobian(frames.poses(joints)), chain.jacobian(joints), rtol=0.0, atol=1e-6)


def test_forward_kinematics_of_a_motion_check_batch_is_faster_than_pytorch_kinematics(chain):
    joints = _random_joints(chain, 7600, seed=3)  # the waypoints of ~200 motions
    frames = ChainFrames.of(chain)

    def best_of(function, repeats=5):
        durations = []
        for _ in range(repeats):
            start = time.perf_counter()
            function(joints)
            durations.append(time.perf_counter() - start)
        return min(durations)

    assert best_of(frames.poses) < best_of(chain.forward_kinematics_tensor)


def test_a_configuration_gets_the_same_frames_and_jacobian_in_any_batch(chain):
    # The planner solves a grasp in batches of 1 to thousands: its answer must not depend on them.
    joints = _random_joints(chain, 3000, seed=4)
    frames = ChainFrames.of(chain)
    poses = frames.poses(joints)
    jacobian = frames.jacobian(poses)
    for rows in (slice(0, 1), slice(7, 12), slice(100, 160)):
        assert torch.equal(frames.poses(joints[rows]), poses[..., rows])
        assert torch.equal(frames.jacobian(frames.poses(joints[rows])), jacobian[rows])
