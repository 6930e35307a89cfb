"""Boundary variants of a floating dataset's grasps: measured on the mesh, clear of it, moved as the settings say."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from sagp_batched.config import load_config
from sagp_batched.datasets.boundary_grasps import add_boundary_grasps
from sagp_batched.datasets.grasp_geometry import object_surface, open_hand_clear
from sagp_batched.datasets.verdicts import VERDICTS, ClassifiedGrasps
from sagp_batched.grasps import GraspCandidates, GraspPoses
from sagp_batched.robot.description import robot_of
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.objects import load_object_set

RADIUS_M, HEIGHT_M = 0.025, 0.10


@pytest.fixture(scope="module")
def can(tmp_path_factory):
    folder = tmp_path_factory.mktemp("can")
    trimesh.creation.cylinder(radius=RADIUS_M, height=HEIGHT_M, sections=96).export(folder / "can.obj")
    return load_object_set(folder, MeshImportSettings(cache_dir=tmp_path_factory.mktemp("cache"))).get("can")


def _across(can, along) -> ClassifiedGrasps:
    """Top-down grasps across the can's diameter (approach -z, closing y) at ``along`` on its axis: the
    import lays it on its side, axis along x at z = radius (its link frame: the resting pose's box bottom)."""
    n = len(along)
    centre = torch.tensor([[x, 0.0, RADIUS_M] for x in along], dtype=torch.float64)
    closing, approach = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    rotation = torch.stack([torch.linalg.cross(closing, approach), closing, approach], dim=1).expand(n, 3, 3)
    contacts = torch.stack([centre - RADIUS_M * closing, centre + RADIUS_M * closing], dim=1)
    zeros = torch.zeros(n, dtype=torch.float64)
    candidates = GraspCandidates(
        contacts=contacts, closing_axis=closing.expand(n, 3), width_m=torch.full((n,), 2 * RADIUS_M, dtype=torch.float64),
        s_geom=torch.ones(n, dtype=torch.float64), approach=approach.expand(n, 3), rotation=rotation, s_reach=zeros,
        ik_solution=torch.zeros(n, 7), zone=torch.full((n,), -1), s_afford=zeros, s_avoid=zeros, s_task=zeros, score=zeros)
    return ClassifiedGrasps(candidates, torch.zeros(n, dtype=torch.int64), ("feasible",) * n, n, n)


def test_boundary_variants_are_measured_on_the_mesh_clear_of_it_and_moved_within_their_ranges(can):
    config = load_config("dataset")
    source = _across(can, [-0.02, 0.0, 0.02])
    grown = add_boundary_grasps(source, 8, object_surface(can), np.eye(4), robot_of(config), config, seed=5)
    variants = grown.candidates[len(source):]
    assert len(grown) == len(source) + 8 and grown.verdict_names()[len(source):] == ["boundary"] * 8
    assert torch.equal(grown.candidates.candidate_id, torch.arange(len(grown)))
    # Contacts on the can's side, where both fingers meet it; the hand sent to their midpoint stays clear.
    radial = (variants.contacts[:, :, 1:] - torch.tensor([0.0, RADIUS_M])).norm(dim=2)
    assert torch.allclose(radial, torch.full_like(radial, RADIUS_M), atol=2e-4)
    assert open_hand_clear(object_surface(can), variants.transform(np.eye(4), "object").poses(), robot_of(config), config.labelling.geometry_tolerance_m).all()
    reasons = grown.reasons[len(source):]
    withdrawn = torch.tensor(["withdrawn" in r for r in reasons])
    assert withdrawn.any() and (~withdrawn).any()
    # Withdrawn along the approach (-z): the closing chord d above the axis, contacts' normals tilted asin(d / r).
    depth = variants.position[withdrawn, 2] - RADIUS_M
    low, high = config.dataset.boundary_withdrawal_m
    assert ((depth >= low - 1e-6) & (depth <= high + 1e-6)).all()
    stated = torch.tensor([float(r.split(" withdrawn ")[1].split(" mm")[0]) / 1000 for r, w in zip(reasons, withdrawn) if w], dtype=torch.float64)
    assert torch.allclose(depth, stated, atol=6e-4)
    tilt = torch.asin(depth / RADIUS_M)
    expected_s_geom = torch.where(tilt < math.radians(config.planner.max_contact_angle_deg), torch.cos(tilt) ** 2, torch.zeros_like(tilt))
    assert torch.allclose(variants.s_geom[withdrawn].double(), expected_s_geom, atol=0.03)
    assert torch.allclose(variants.width_m[withdrawn].double(), 2 * torch.sqrt(RADIUS_M ** 2 - depth ** 2), atol=5e-4)
    # Turned: the fingers' closing axis off the source's by an angle in range.
    turned = variants.rotation[~withdrawn, :, 1].double() @ torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    angle = torch.rad2deg(torch.acos(turned.clamp(-1, 1)))
    low, high = config.dataset.boundary_turn_deg
    assert ((angle >= low - 1e-3) & (angle <= high + 1e-3)).all()


def test_boundary_variants_follow_their_seed_and_none_are_made_where_none_are_asked(can):
    config = load_config("dataset")
    source, surface, robot = _across(can, [-0.01, 0.01]), object_surface(can), robot_of(config)
    first = add_boundary_grasps(source, 4, surface, np.eye(4), robot, config, seed=1)
    again = add_boundary_grasps(source, 4, surface, np.eye(4), robot, config, seed=1)
    other = add_boundary_grasps(source, 4, surface, np.eye(4), robot, config, seed=2)
    assert torch.equal(first.candidates.rotation, again.candidates.rotation) and first.reasons == again.reasons
    assert not torch.equal(first.candidates.rotation, other.candidates.rotation)
    assert add_boundary_grasps(source, 0, surface, np.eye(4), robot, config, seed=1) is source
    assert VERDICTS[-1] == "boundary"


def test_a_variant_whose_fingers_meet_nothing_is_not_kept(can):
    """Withdrawn by more than the can's radius the fingers close on air: no variant, however many are asked."""
    config = load_config("dataset", overrides={"dataset": {"boundary_withdrawal_m": [0.03, 0.04], "boundary_turn_deg": [89.0, 90.0]}})
    source = _across(can, [0.0])
    grown = add_boundary_grasps(source, 6, object_surface(can), np.eye(4), robot_of(config), config, seed=3)
    kinds = {r.split()[4] for r in grown.reasons[len(source):]}
    assert "withdrawn" not in kinds


def test_the_open_hand_test_culls_no_point_a_hand_hull_holds():
    """A surface point hits where it lies inside a hand hull's planes by more than the tolerance: the
    box and k-DOP culls ahead of the planes only spare work, on poses near and inside a real object."""
    from scipy.spatial.transform import Rotation

    from sagp_batched.datasets.grasp_geometry import _hand_hulls, _surface_in_hulls, floating_hand_links

    robot = robot_of(load_config(None))
    hulls = _hand_hulls(robot, floating_hand_links(robot))
    points = object_surface(load_object_set(None).get("025_mug")).points[::4]
    rng = np.random.default_rng(3)
    rotation = torch.tensor(Rotation.random(96, random_state=4).as_matrix(), dtype=torch.float32)
    position = (points[rng.integers(0, len(points), 96)] + torch.tensor(rng.normal(0.0, 0.03, (96, 3)), dtype=torch.float32)).float()
    local = torch.einsum("bji,pj->bpi", rotation, points) - torch.einsum("bji,bj->bi", rotation, position)[:, None]
    depth = torch.stack([-(local @ planes[:, :3].T + planes[:, 3]).max(dim=2).values for planes in hulls.planes])  # (H, B, P)
    expected = (depth > 0.001).any(dim=2).any(dim=0).numpy()
    assert 10 < expected.sum() < 86, "the poses straddle the object: some hit, some clear"
    assert np.array_equal(_surface_in_hulls(points, rotation, position, hulls, 0.001), expected)
