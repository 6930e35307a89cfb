"""Kernels on constructed geometry: antipodal pairs on a box, frames, gripper collision proxies."""
import math

import torch

from planner_clouds import box_surface
from sagp_batched.config import Config
from sagp_batched.planning import gripper_geometry, hand_geometry
from sagp_batched.planning import widest_pair_m
from sagp_batched.robot import load_robot
from sagp_batched.robot.description import load_robot
from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.grasp_frames import approach_directions, grasp_rotations, scene_points_about
from sagp_batched_kernels.gripper_occupancy import gripper_occupancy
from sagp_batched_kernels.sampling import sample_pair_indices
from sagp_batched_kernels.table_penetration import table_penetration

ROBOT = load_robot()

PLANNER = Config().planner
# The widest pair the planner draws for the default gripper (the Panda hand: 0.08 m).
WIDEST_M = widest_pair_m(load_robot(), PLANNER)
DOWN = torch.tensor([0.0, 0.0, -1.0])


def _box(size=(0.05, 0.06, 0.1)):
    points, normals = box_surface(size, (0.0, 0.0, 0.0))
    return torch.as_tensor(points, dtype=torch.float32), torch.as_tensor(normals, dtype=torch.float32)


def _evaluate(points, normals, pairs):
    return antipodal_pairs(points, normals, pairs, PLANNER.min_width_m, WIDEST_M, PLANNER.max_contact_angle_deg)


def _face(normals, axis, sign):
    return ((normals[:, axis] == sign)).nonzero().squeeze(1)


def test_opposite_box_faces_are_antipodal_with_unit_quality():
    points, normals = _box()
    # Straight across the 5 cm x-extent: a point on -x and its mirror on +x.
    minus_x = _face(normals, 0, -1.0)
    i = minus_x[len(minus_x) // 2]
    mirrored = points[i] * torch.tensor([-1.0, 1.0, 1.0])
    j = (points - mirrored).norm(dim=1).argmin()
    assert (points[j] - mirrored).norm() < 1e-6
    result = _evaluate(points, normals, torch.tensor([[i, j], [j, i]]))
    assert result["antipodal"].all()
    assert torch.allclose(result["s_geom"], torch.ones(2))
    assert torch.allclose(result["width_m"], torch.full((2,), 0.05), atol=1e-6)


def test_same_face_pairs_are_rejected_and_wide_pairs_filtered():
    points, normals = _box()
    top = _face(normals, 2, 1.0)
    same_face = torch.stack((top[:50], top[50:100]), dim=1)
    assert not _evaluate(points, normals, same_face)["antipodal"].any()
    # Across the 10 cm z-extent: perfectly opposed but wider than the 8 cm gripper.
    bottom = _face(normals, 2, -1.0)
    i = top[len(top) // 2]
    j = (points - points[i] * torch.tensor([1.0, 1.0, -1.0])).norm(dim=1).argmin()
    assert bottom.eq(j).any()
    across_z = _evaluate(points, normals, torch.tensor([[i, j]]))
    assert not across_z["width_ok"].any() and not across_z["antipodal"].any()


def test_sign_convention_rejects_inward_normals():
    points, normals = _box()
    pairs = sample_pair_indices(len(points), 20000, torch.Generator().manual_seed(3))
    outward = _evaluate(points, normals, pairs)["antipodal"]
    inward = _evaluate(points, -normals, pairs)["antipodal"]
    assert outward.sum() > 100
    assert not inward.any()


def test_sampling_is_reproducible_and_pairs_are_distinct():
    a = sample_pair_indices(500, 5000, torch.Generator().manual_seed(7))
    b = sample_pair_indices(500, 5000, torch.Generator().manual_seed(7))
    c = sample_pair_indices(500, 5000, torch.Generator().manual_seed(8))
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert (a[:, 0] != a[:, 1]).all() and a.min() >= 0 and a.max() < 500


def test_approaches_are_perpendicular_and_rotations_right_handed():
    axes = torch.nn.functional.normalize(torch.randn(300, 3, generator=torch.Generator().manual_seed(1)), dim=1)
    axes = torch.cat((axes, torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])))
    approach = approach_directions(axes, 8, DOWN)
    assert approach.shape == (302, 8, 3)
    assert (approach @ axes.unsqueeze(-1)).abs().max() < 1e-5
    assert torch.allclose(approach.norm(dim=-1), torch.ones(302, 8), atol=1e-5)
    rotation = grasp_rotations(axes[:, None, :], approach)
    identity = torch.eye(3).expand(302, 8, 3, 3)
    assert torch.allclose(rotation.transpose(-1, -2) @ rotation, identity, atol=1e-5)
    assert torch.allclose(torch.linalg.det(rotation), torch.ones(302, 8), atol=1e-5)
    assert torch.allclose(rotation[..., 1], axes[:, None, :].expand(302, 8, 3)) and torch.equal(rotation[..., 2], approach)
    # Approach 0 is the most downward direction perpendicular to a horizontal closing axis.
    horizontal = approach_directions(torch.tensor([[1.0, 0.0, 0.0]]), 8, DOWN)
    assert torch.allclose(horizontal[0, 0], DOWN)


def test_grasp_through_the_table_is_rejected():
    hand = hand_geometry(ROBOT)
    hulls = hand.vertices()
    table_z = 0.625
    centre = torch.tensor([[0.5, 0.0, table_z + 0.04]])
    closing = torch.tensor([[0.0, 1.0, 0.0]])
    approaches = torch.tensor([[[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]])  # down, up (from below), sideways
    rotation = grasp_rotations(closing[:, None, :], approaches)
    blocked = table_penetration(centre, rotation, hulls, 0.10, table_z)
    # Sideways 4 cm up, the hand (6.3 cm across) clears the table but the wrist behind it (link 7,
    # 8.8 cm across) does not; 7 cm up it clears, and without link 7 in the model it would have
    # passed (the arm then hit the table in PyBullet).
    assert blocked.tolist() == [[False, True, True]]
    higher = table_penetration(centre + torch.tensor([0.0, 0.0, 0.03]), rotation, hulls, 0.10, table_z)
    assert higher.tolist() == [[False, True, False]]
    without_wrist = hand.vertices(tuple(name for name in hand.links if name != "panda_link7"))
    assert table_penetration(centre, rotation, without_wrist, 0.10, table_z).tolist() == [[False, True, False]]
    # A side grasp whose closing axis is vertical puts the 20 cm-wide hand through the table.
    vertical = grasp_rotations(torch.tensor([[[0.0, 0.0, 1.0]]]), torch.tensor([[[1.0, 0.0, 0.0]]]))
    assert table_penetration(centre, vertical, hulls, 0.10, table_z).all()


def test_finger_sweeping_through_a_protrusion_is_rejected():
    """A 4 cm box with a thin fin sticking out next to one contact: the finger must not sweep through it."""
    geometry = gripper_geometry(ROBOT, PLANNER)
    body, _ = _box((0.04, 0.04, 0.04))
    fin = torch.cartesian_prod(
        torch.linspace(-0.005, 0.005, 6), torch.linspace(0.026, 0.05, 12), torch.linspace(-0.02, 0.02, 12)
    )
    centre = torch.zeros(1, 3)
    closing = torch.tensor([[0.0, 1.0, 0.0]])
    rotation = grasp_rotations(closing[:, None, :], torch.tensor([[[0.0, 0.0, -1.0]]]))
    width = torch.tensor([0.04])
    clean = gripper_occupancy(body[None], torch.tensor([0]), centre, rotation, width, geometry, 10**6).total
    with_fin = torch.cat((body, fin))
    blocked = gripper_occupancy(with_fin[None], torch.tensor([0]), centre, rotation, width, geometry, 10**6).total
    limit = PLANNER.occupancy_max_fraction * len(with_fin)
    assert clean.item() <= PLANNER.occupancy_max_fraction * len(body)
    assert blocked.item() > limit
    # Turned 90 deg about the approach, the fingers close along x and miss the fin.
    turned = grasp_rotations(torch.tensor([[[1.0, 0.0, 0.0]]]), torch.tensor([[[0.0, 0.0, -1.0]]]))
    assert gripper_occupancy(with_fin[None], torch.tensor([0]), centre, turned, width, geometry, 10**6).total.item() <= limit


def test_occupancy_ignores_nan_padding_and_matches_across_chunks():
    geometry = gripper_geometry(ROBOT, PLANNER)
    points, normals = _box()
    pairs = sample_pair_indices(len(points), 3000, torch.Generator().manual_seed(5))
    result = _evaluate(points, normals, pairs)
    keep = result["antipodal"]
    centre = points[pairs[keep]].mean(dim=1)
    approach = approach_directions(result["closing_axis"][keep], 8, DOWN)
    rotation = grasp_rotations(result["closing_axis"][keep][:, None, :], approach)
    padded = torch.cat((points, torch.full((100, 3), math.nan)))[None]
    index = torch.zeros(len(centre), dtype=torch.int64)
    whole = gripper_occupancy(points[None], index, centre, rotation, result["width_m"][keep], geometry, 10**9).total
    chunked = gripper_occupancy(padded, index, centre, rotation, result["width_m"][keep], geometry, 5000).total
    assert torch.equal(whole, chunked)
    assert whole.max() > 0



def test_scene_points_about_equals_the_gather_for_one_scene_several_and_none():
    generator = torch.Generator().manual_seed(5)
    points = torch.randn(3, 20, 3, generator=generator)
    points[1, 15:] = float("nan")  # padding rows stay NaN
    centre = torch.randn(7, 3, generator=generator)
    for object_index in (torch.full((7,), 1), torch.tensor([0, 0, 1, 1, 2, 2, 2]), torch.zeros(0, dtype=torch.int64)):
        rows = centre[: object_index.numel()]
        found, gathered = scene_points_about(points, object_index, rows), points[object_index] - rows[:, None, :]
        assert torch.equal(found.isnan(), gathered.isnan())
        assert torch.equal(found.nan_to_num(nan=7.0), gathered.nan_to_num(nan=7.0))
