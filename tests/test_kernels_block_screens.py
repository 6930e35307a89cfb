"""The block search's fixed-shape screens against the exhaustive computations: the gripper's point
counts and the hand's lowest height as the exhaustive checks find them, and the swept hand's probes
an upper bound of its least separation that finds the blocked poses."""
import pytest
import torch

from planner_clouds import box_surface, cylinder_surface
from sagp_batched.config import Config
from sagp_batched.planning import gripper_geometry
from sagp_batched.planning.screens import _padded_to_runs, _swept_hand, _table_check_points
from sagp_batched.robot.description import load_robot
from sagp_batched.robot.hand import DOP_DIRECTIONS
from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.block_screens import gripper_point_counts, hand_probe, lowest_hand_height
from sagp_batched_kernels.compiled import compiled
from sagp_batched_kernels.grasp_frames import approach_directions, grasp_rotations
from sagp_batched_kernels.gripper_occupancy import gripper_occupancy
from sagp_batched_kernels.hand_clearance import _separation
from sagp_batched_kernels.sampling import sample_pair_indices

ROBOT = load_robot()
PLANNER = Config().planner
GEOMETRY = gripper_geometry(ROBOT, PLANNER)


def _poses(points, normals, seed, count=300):
    pairs = sample_pair_indices(len(points), 4000, torch.Generator().manual_seed(seed))
    result = antipodal_pairs(points, normals, pairs, PLANNER.min_width_m, PLANNER.max_width_m, PLANNER.max_contact_angle_deg)
    keep = result["antipodal"].nonzero().squeeze(1)[:count]
    axis = result["closing_axis"][keep]
    rotation = grasp_rotations(axis[:, None, :], approach_directions(axis, 8, torch.tensor([0.0, 0.0, -1.0])))
    return points[pairs[keep]].mean(dim=1), rotation, result["width_m"][keep]


def _scene():
    box, box_normals = box_surface((0.06, 0.05, 0.15), (0.55, 0.0, 0.075))
    can, can_normals = cylinder_surface(0.035, 0.1, (0.55, 0.09, 0.0))
    points = torch.as_tensor(box, dtype=torch.float32)
    return points, torch.as_tensor(box_normals, dtype=torch.float32), torch.cat((points, torch.as_tensor(can, dtype=torch.float32)))


def test_gripper_point_counts_are_the_exhaustive_counts():
    points, normals, scene = _scene()
    centre, rotation, width = _poses(points, normals, seed=0)
    exhaustive = gripper_occupancy(scene[None], torch.zeros(len(centre), dtype=torch.int64), centre, rotation, width, GEOMETRY, 1 << 22).total
    counts = gripper_point_counts(scene.T.contiguous(), centre.repeat_interleave(8, 0), rotation.reshape(-1, 3, 3),
                                  (width / 2 + PLANNER.contact_clearance_m).repeat_interleave(8), GEOMETRY)
    assert exhaustive.sum() > 0 and (exhaustive == 0).any()
    assert torch.equal(counts.view(-1, 8), exhaustive.to(torch.float32))


def test_the_lowest_hand_height_is_every_vertex_placed_at_the_grasp_and_the_pregrasp():
    points, normals, _ = _scene()
    centre, rotation, _ = _poses(points, normals, seed=1)
    (fingers, _), _ = _table_check_points(ROBOT, torch.device("cpu"))
    height = lowest_hand_height(centre[:, 2], rotation, fingers, 0.1)
    placed = centre[:, None, None, :] + torch.einsum("ckij,vj->ckvi", rotation, fingers)
    pregrasp = placed - 0.1 * rotation[..., None, :, 2]
    expected = torch.minimum(placed[..., 2].amin(dim=-1), pregrasp[..., 2].amin(dim=-1))
    assert torch.allclose(height, expected, atol=1e-6)


def test_the_hand_probe_bounds_the_least_separation_from_above_and_finds_the_blocked_poses():
    points, normals, scene = _scene()
    centre, rotation, _ = _poses(points, normals, seed=2)
    low, high = _swept_hand(ROBOT, 0.1, torch.device("cpu"))
    frames = rotation.reshape(-1, 3, 3)
    centres = centre.repeat_interleave(8, 0)
    columns = _padded_to_runs(scene, 16).T.contiguous()
    probe = hand_probe(columns, centres, frames, DOP_DIRECTIONS, low, high, 16)
    axes = DOP_DIRECTIONS @ frames.transpose(1, 2)
    middle, half = ((low + high) / 2)[:, :, None, None], ((high - low) / 2)[:, :, None, None]
    exact = _separation(scene[None] - centres[:, None, :], axes, middle, half, compile=False).amin(dim=1)
    margin = PLANNER.hand_clearance_margin_m
    assert (probe >= exact - 1e-6).all()
    blocked = exact < margin
    assert blocked.any() and (~blocked).any()
    found = (probe < margin) & blocked
    assert found.sum() >= 0.95 * blocked.sum()


@pytest.mark.slow
def test_the_fixed_shape_screens_compile_to_the_eager_values():
    """Inductor's fused loops give the eager values (compiling takes tens of seconds: slow)."""
    points, normals, scene = _scene()
    centre, rotation, width = _poses(points, normals, seed=3)
    low, high = _swept_hand(ROBOT, 0.1, torch.device("cpu"))
    centres, frames = centre.repeat_interleave(8, 0), rotation.reshape(-1, 3, 3)
    columns = _padded_to_runs(scene, 16).T.contiguous()
    finger_y_min = (width / 2 + PLANNER.contact_clearance_m).repeat_interleave(8)
    for function, args in ((hand_probe, (columns, centres, frames, DOP_DIRECTIONS, low, high, 16)),
                           (gripper_point_counts, (scene.T.contiguous(), centres, frames, finger_y_min, GEOMETRY))):
        assert torch.allclose(compiled(function)(*args), function(*args))
