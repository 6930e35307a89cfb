"""The gripper-volume verdict decides every pose exactly as counting with ``gripper_occupancy`` does,
including points lying exactly on the gripper's faces, NaN padding, candidates of several scenes in
one block, approaches that do not share one closing axis and grasp centres far from the origin."""
import math

import pytest
import torch

from planner_clouds import box_surface
from sagp_batched.config import Config
from sagp_batched.planning import gripper_geometry
from sagp_batched.planning import widest_pair_m
from sagp_batched.robot import load_robot
from sagp_batched.robot.description import load_robot
from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.grasp_frames import approach_directions, grasp_rotations
from sagp_batched_kernels.gripper_occupancy import gripper_occupancy
from sagp_batched_kernels.occupancy_verdict import gripper_occupancy_within
from sagp_batched_kernels.sampling import sample_pair_indices

ROBOT = load_robot()

PLANNER = Config().planner
# The widest pair the planner draws for the default gripper (the Panda hand: 0.08 m).
WIDEST_M = widest_pair_m(load_robot(), PLANNER)
DOWN = torch.tensor([0.0, 0.0, -1.0])


def _grasps(points, normals, seed):
    pairs = sample_pair_indices(len(points), 4000, torch.Generator().manual_seed(seed))
    result = antipodal_pairs(points, normals, pairs, PLANNER.min_width_m, WIDEST_M, PLANNER.max_contact_angle_deg)
    keep = result["antipodal"]
    centre = points[pairs[keep]].mean(dim=1)
    rotation = grasp_rotations(result["closing_axis"][keep][:, None, :], approach_directions(result["closing_axis"][keep], 8, DOWN))
    return centre, rotation, result["width_m"][keep]


def _limits_at_the_counts(counts, seed):
    """(C,) limits equal to one pose's count, or just below or above it, so verdicts flip at the limit."""
    generator = torch.Generator().manual_seed(seed)
    slot = torch.randint(0, counts.shape[1], (counts.shape[0],), generator=generator)
    offset = torch.tensor([-1.0, -0.5, 0.0, 0.5])[torch.randint(0, 4, (counts.shape[0],), generator=generator)]
    return counts[torch.arange(counts.shape[0]), slot].to(torch.float32) + offset


# The far box's grasp centres are beyond the reach where the verdict's rounding bound holds, so
# they are counted exhaustively.
@pytest.mark.parametrize(("spacing_m", "box_centre_m"), [(0.004, (0.0, 0.0, 0.0)), (0.0025, (0.0, 0.0, 0.0)), (0.004, (4.0, -2.0, 1.0))])
def test_verdicts_equal_counting_on_a_grid_box_whose_points_lie_on_the_gripper_faces(spacing_m, box_centre_m):
    points, normals = (torch.as_tensor(array, dtype=torch.float32) for array in box_surface((0.05, 0.06, 0.1), box_centre_m, spacing_m))
    centre, rotation, width = _grasps(points, normals, seed=0)
    geometry = gripper_geometry(ROBOT, PLANNER)
    index = torch.zeros(len(centre), dtype=torch.int64)
    poses = torch.rand(rotation.shape[:2], generator=torch.Generator().manual_seed(1)) < 0.7
    counts = gripper_occupancy(points[None], index, centre, rotation, width, geometry, 10**6).total
    for seed in range(3):
        limit = _limits_at_the_counts(counts, seed)
        expected = poses & (counts.to(torch.float32) <= limit[:, None])
        got = gripper_occupancy_within(points[None], index, centre, rotation, width, geometry, limit, 262_144, poses)
        assert torch.equal(got, expected)
        assert got.any() and (poses & ~got).any()


# Small chunks split each group size's poses into several blocks and its groups' y terms into
# several spans.
@pytest.mark.parametrize("chunk_elements", [50_000, 8_000])
def test_verdicts_equal_counting_across_padded_scenes_and_frames_without_one_closing_axis(chunk_elements):
    generator = torch.Generator().manual_seed(2)
    box, box_normals = (torch.as_tensor(array, dtype=torch.float32) for array in box_surface((0.04, 0.07, 0.12), (0.5, 0.1, 0.7)))
    blob = torch.randn(700, 3, generator=generator) * 0.03 + torch.tensor([0.5, 0.1, 0.7])
    scenes = torch.full((2, len(box) + 50, 3), math.nan)
    scenes[0, : len(box)] = box
    scenes[1, : len(blob)] = blob
    centre, rotation, width = _grasps(box, box_normals, seed=3)
    # Every third candidate's frames are scrambled: its approaches are not turns about one closing axis.
    scrambled = torch.arange(len(centre)) % 3 == 0
    rotation = rotation.clone()
    rotation[scrambled] = rotation[scrambled].roll(1, dims=-1)
    index = torch.arange(len(centre)) % 2
    geometry = gripper_geometry(ROBOT, PLANNER)
    # Most poses counted: the candidates' groups of poses sharing a closing axis take every size.
    poses = torch.rand(rotation.shape[:2], generator=generator) < 0.85
    counts = gripper_occupancy(scenes, index, centre, rotation, width, geometry, 10**6).total
    limit = _limits_at_the_counts(counts, seed=4)
    expected = poses & (counts.to(torch.float32) <= limit[:, None])
    assert torch.equal(gripper_occupancy_within(scenes, index, centre, rotation, width, geometry, limit, chunk_elements, poses), expected)
