"""The scene field's bounds bracket the exhaustive checks, and the verdicts they decide are the exhaustive ones."""
import pytest
import torch
from planner_clouds import box_surface, cylinder_surface

from sagp_batched.config import load_config
from sagp_batched.planning.gripper import gripper_geometry
from sagp_batched.planning.screens import swept_hand
from sagp_batched.robot.description import robot_of
from sagp_batched.robot.hand import DOP_DIRECTIONS
from sagp_batched_kernels import scene_field
from sagp_batched_kernels.gripper_occupancy import gripper_occupancy
from sagp_batched_kernels.hand_clearance import hand_clearance

MARGIN_M = 0.003


def _scene(shape):
    if shape == "box":
        points, _ = box_surface((0.06, 0.09, 0.12), (0.5, 0.0, 0.06), spacing_m=0.006)
    else:
        points, _ = cylinder_surface(0.035, 0.1, (0.5, 0.0, 0.0), spacing_m=0.006)
    return torch.as_tensor(points, dtype=torch.float32)


def _poses(points, n_poses, seed):
    """Grasp frames about the cloud: centres on and near its surface, random rotations and widths."""
    generator = torch.Generator().manual_seed(seed)
    centre = points[torch.randint(points.shape[0], (n_poses,), generator=generator)] + 0.02 * torch.randn(n_poses, 3, generator=generator)
    q, r = torch.linalg.qr(torch.randn(n_poses, 3, 3, generator=generator))
    frames = q * torch.sign(torch.diagonal(r, dim1=1, dim2=2))[:, None, :]
    frames[torch.linalg.det(frames) < 0, :, 0] *= -1
    return centre, frames, 0.02 + 0.06 * torch.rand(n_poses, generator=generator)


@pytest.fixture(scope="module")
def robot_parts():
    config = load_config(None)
    robot = robot_of(config)
    return gripper_geometry(robot, config.planner), swept_hand(robot, config.motion.pregrasp_offset_m, torch.device("cpu"))


@pytest.mark.parametrize("shape", ["box", "cylinder"])
@pytest.mark.parametrize("cell_m", [0.008, 0.016])
def test_cell_count_bounds_bracket_the_exhaustive_count_and_decide_as_it_does(robot_parts, shape, cell_m):
    geometry, _ = robot_parts
    points = _scene(shape)
    centre, frames, width = _poses(points, 600, seed=1)
    count = gripper_occupancy(points[None], torch.zeros(600, dtype=torch.int64), centre, frames[:, None], width, geometry, 1 << 20).total[:, 0]
    upper, lower = scene_field.cell_count_bounds(scene_field.cell_balls(points, cell_m), centre, frames, width, geometry)
    assert torch.all(lower <= count) and torch.all(count <= upper)
    assert (count > 0).sum() > 100  # the poses do hold points
    limit = torch.full((600,), 0.12 * points.shape[0])
    within, beyond = upper <= limit, lower > limit
    reference = count <= limit
    assert torch.equal(reference[within | beyond], within[within | beyond])
    assert within.sum() > 50 and beyond.sum() > 20  # both verdicts are decided by the bounds


def test_distance_field_nodes_hold_the_distance_to_the_nearest_point_truncated():
    points = _scene("cylinder")
    field = scene_field.distance_field(points, 0.004, 0.015)
    shape = field.distance.shape
    index = torch.cartesian_prod(*(torch.arange(n) for n in shape)).to(torch.float32)
    nodes = field.origin + index * field.cell_m
    nearest = torch.cdist(nodes.double(), points.double()).amin(dim=1).clamp_max(0.015)
    assert torch.allclose(field.distance.reshape(-1).double(), nearest, atol=1e-6)
    assert (nearest < 0.015).float().mean() > 0.1


@pytest.mark.parametrize("shape", ["box", "cylinder"])
def test_hand_clearance_bounds_bracket_the_exact_clearance_and_decide_as_it_does(robot_parts, shape):
    _, (low, high) = robot_parts
    points = _scene(shape)
    centre, frames, _ = _poses(points, 400, seed=2)
    # Drawn back along their approaches by up to 15 cm, so that the object lies ahead of many hands: both verdicts occur.
    centre = centre - 0.15 * torch.rand(400, 1, generator=torch.Generator().manual_seed(4)) * frames[:, :, 2]
    exact = hand_clearance(points[None], points[None, ::7], torch.zeros(400, dtype=torch.int64), centre, frames, DOP_DIRECTIONS, low, high,
                           MARGIN_M, 1 << 22)
    least = scene_field.least_separation(points, centre, frames, DOP_DIRECTIONS, low, high)
    slack = scene_field.exact_pass_slack(points, centre, low, high)
    open_poses = ~exact.blocked
    assert torch.allclose(least[open_poses], exact.clearance_m[open_poses], atol=slack)
    assert torch.equal(least < MARGIN_M, exact.blocked)
    balls = scene_field.hand_balls(DOP_DIRECTIONS, low, high, MARGIN_M, 0.008, 0.016, 0.008)
    field = scene_field.distance_field(points, 0.004, float(balls.radius.max()) + 0.004)
    lower, upper = scene_field.hand_clearance_bounds(field, balls, centre, frames, MARGIN_M, slack)
    assert torch.all(lower <= least + slack) and torch.all(least - slack <= upper)
    blocked, clear = upper < MARGIN_M, lower >= MARGIN_M
    assert torch.equal(exact.blocked[blocked | clear], blocked[blocked | clear])
    assert blocked.sum() > 20 and clear.sum() > 20


def test_hand_balls_cover_the_margin_region(robot_parts):
    _, (low, high) = robot_parts
    balls = scene_field.hand_balls(DOP_DIRECTIONS, low, high, MARGIN_M, 0.008, 0.016, 0.008)
    generator = torch.Generator().manual_seed(3)
    lowest, highest = low[:, :3].amin(dim=0) - MARGIN_M, high[:, :3].amax(dim=0) + MARGIN_M
    samples = lowest + (highest - lowest) * torch.rand(200_000, 3, generator=generator)
    inside = samples[scene_field.hulls_separation(samples, DOP_DIRECTIONS, low, high) < MARGIN_M]
    covered = torch.zeros(inside.shape[0], dtype=torch.bool)
    for block in torch.arange(balls.radius.numel()).split(512):
        covered |= (torch.cdist(inside, balls.centre[block]) <= balls.radius[block]).any(dim=1)
    assert inside.shape[0] > 1000 and covered.all()
