"""The block search's fixed-shape swept-hand pass against the exhaustive separations: every pose's
least separation from the points it is given, as the exhaustive computation finds it."""
import pytest
import torch

from planner_clouds import box_surface, cylinder_surface
from sagp_batched.config import Config
from sagp_batched.planning.screens import _swept_hand
from sagp_batched.robot.description import load_robot
from sagp_batched.robot.hand import DOP_DIRECTIONS
from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.block_screens import least_separation
from sagp_batched_kernels.compiled import compiled
from sagp_batched_kernels.grasp_frames import approach_directions, grasp_rotations
from sagp_batched_kernels.hand_clearance import _separation
from sagp_batched_kernels.sampling import sample_pair_indices, voxel_representatives

ROBOT = load_robot()
PLANNER = Config().planner


def _poses_and_scene(seed, count=300):
    box, box_normals = (torch.as_tensor(a, dtype=torch.float32) for a in box_surface((0.06, 0.05, 0.15), (0.55, 0.0, 0.075)))
    can = torch.as_tensor(cylinder_surface(0.035, 0.1, (0.55, 0.09, 0.0))[0], dtype=torch.float32)
    pairs = sample_pair_indices(len(box), 4000, torch.Generator().manual_seed(seed))
    result = antipodal_pairs(box, box_normals, pairs, PLANNER.min_width_m, PLANNER.max_width_m, PLANNER.max_contact_angle_deg)
    keep = result["antipodal"].nonzero().squeeze(1)[:count]
    axis = result["closing_axis"][keep]
    rotation = grasp_rotations(axis[:, None, :], approach_directions(axis, 8, torch.tensor([0.0, 0.0, -1.0])))
    scene = torch.cat((box, can))
    return box[pairs[keep]].mean(dim=1).repeat_interleave(8, 0), rotation.reshape(-1, 3, 3), scene


def _exhaustive(points, centres, frames, low, high):
    axes = DOP_DIRECTIONS @ frames.transpose(1, 2)
    middle, half = ((low + high) / 2)[:, :, None, None], ((high - low) / 2)[:, :, None, None]
    return _separation(points[None] - centres[:, None, :], axes, middle, half, compile=False).amin(dim=1)


@pytest.mark.parametrize("voxel_m", [0.006, 0.02])
def test_the_least_separation_is_the_exhaustive_one(voxel_m):
    centres, frames, scene = _poses_and_scene(seed=2)
    points = scene[voxel_representatives(scene, voxel_m)]
    low, high = _swept_hand(ROBOT, 0.1, torch.device("cpu"))
    least = least_separation(points.T.contiguous(), centres, frames, DOP_DIRECTIONS, low, high)
    exact = _exhaustive(points, centres, frames, low, high)
    blocked = exact < PLANNER.hand_clearance_margin_m
    assert blocked.any() and (~blocked).any()
    assert torch.allclose(least, exact, atol=1e-6)


def test_nan_padding_is_never_near():
    centres, frames, scene = _poses_and_scene(seed=3, count=20)
    low, high = _swept_hand(ROBOT, 0.1, torch.device("cpu"))
    padded = torch.cat((scene, torch.full((5, 3), float("nan")))).T.contiguous()
    assert torch.equal(least_separation(padded, centres, frames, DOP_DIRECTIONS, low, high),
                       least_separation(scene.T.contiguous(), centres, frames, DOP_DIRECTIONS, low, high))


@pytest.mark.slow
def test_the_fixed_shape_pass_compiles_to_the_eager_values():
    """Inductor's fused loop gives the eager values (compiling takes tens of seconds: slow)."""
    centres, frames, scene = _poses_and_scene(seed=4)
    low, high = _swept_hand(ROBOT, 0.1, torch.device("cpu"))
    args = (scene.T.contiguous(), centres, frames, DOP_DIRECTIONS, low, high)
    assert torch.allclose(compiled(least_separation)(*args), least_separation(*args), atol=1e-6)
