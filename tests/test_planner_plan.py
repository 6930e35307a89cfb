"""The batched planner: API contract, determinism, batching, and agreement with the loop reference."""
import dataclasses

import numpy as np
import pytest
import torch

from planner_clouds import box_surface, cylinder_surface, make_cloud
from sagp_batched.config import Config
from sagp_batched.planning import plan, plan_batch, sample_inputs, screen_candidates
from sagp_batched.planning import block_search
from sagp_batched.robot.description import load_robot
from sagp_batched.robot.ik import panda_ik

ROBOT = load_robot()

CONFIG = Config()
TABLE_Z = CONFIG.scene.table_top_z_m


@pytest.fixture(scope="module")
def box_cloud():
    points, normals = box_surface((0.06, 0.05, 0.15), (0.55, 0.0, TABLE_Z + 0.075))
    return make_cloud(points, normals, "box")


@pytest.fixture(scope="module")
def can_cloud():
    points, normals = cylinder_surface(0.035, 0.1, (0.5, 0.1, TABLE_Z))
    return make_cloud(points, normals, "can")


def test_plan_returns_feasible_candidates_ranked_by_geometry(box_cloud):
    result = plan(box_cloud, CONFIG, seed=0)
    candidates, counts = result.candidates, result.counts
    assert 0 < len(candidates) <= CONFIG.planner.max_candidates
    assert counts.sampled == CONFIG.planner.n_pairs
    assert counts.sampled >= counts.antipodal >= counts.collision_free
    assert counts.ik_feasible >= len(candidates)
    assert all(seconds >= 0 for seconds in dataclasses.astuple(result.times))
    assert (candidates.s_geom[:-1] >= candidates.s_geom[1:]).all()
    assert torch.equal(candidates.score, candidates.s_geom)
    assert (candidates.zone == -1).all() and (candidates.s_reach >= CONFIG.planner.min_reach).all()
    # Closing axis is grasp y, approach grasp z, and the approach never comes up from under the table.
    assert torch.allclose(candidates.rotation[:, :, 1], candidates.closing_axis)
    assert torch.allclose(candidates.rotation[:, :, 2], candidates.approach)
    assert (candidates.approach[:, 2] < 0.5).all()
    # The stored joints put the grasp target on the grasp centre.
    reached = panda_ik(CONFIG).forward(candidates.ik_solution)
    assert (reached[:, :3, 3] - candidates.position).norm(dim=1).max() < ROBOT.ik_position_tolerance_m


def test_plan_is_deterministic_for_a_seed(box_cloud):
    first, second = plan(box_cloud, CONFIG, seed=11).candidates, plan(box_cloud, CONFIG, seed=11).candidates
    other = plan(box_cloud, CONFIG, seed=12).candidates
    assert torch.equal(first.contacts, second.contacts)
    assert torch.equal(first.ik_solution, second.ik_solution)
    assert not torch.equal(first.contacts, other.contacts)


def test_plan_batch_matches_single_object_plans(box_cloud, can_cloud):
    batched = plan_batch([box_cloud, can_cloud], CONFIG, [3, 4])
    for cloud, seed, result in ((box_cloud, 3, batched[0]), (can_cloud, 4, batched[1])):
        single = plan(cloud, CONFIG, seed=seed)
        assert result.counts == single.counts
        assert torch.equal(result.candidates.contacts, single.candidates.contacts)
        assert torch.allclose(result.candidates.rotation, single.candidates.rotation)
    assert batched[0].times is batched[1].times  # the call's stage times, shared


def test_obstacle_points_in_the_finger_path_remove_candidates(can_cloud):
    free = plan(can_cloud, CONFIG, seed=5)
    # A wall of obstacle points hugging the can on all sides blocks every finger path.
    points = can_cloud.points_world.numpy()
    centre = points.mean(axis=0)
    radial = points[:, :2] - centre[:2]
    ring = points.copy()
    ring[:, :2] = centre[:2] + radial * (1 + 0.012 / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-9))
    crowded = make_cloud(points, can_cloud.normals_world.numpy(), "can", obstacles=np.concatenate([ring] * 2))
    blocked = plan(crowded, CONFIG, seed=5)
    assert blocked.counts.antipodal == free.counts.antipodal
    assert blocked.counts.collision_free < free.counts.collision_free


def test_bad_cloud_is_named():
    cloud = make_cloud(np.zeros((1, 3)), np.zeros((1, 3)), "lonely")
    with pytest.raises(ValueError, match="lonely"):
        plan(cloud, CONFIG)


@pytest.mark.slow
def test_loop_reference_gives_the_same_candidates_and_mostly_agrees_on_ik(box_cloud, can_cloud):
    from sagp_batched.planning.reference import plan_reference

    for cloud in (box_cloud, can_cloud):
        reference = plan_reference(cloud, CONFIG, sample_inputs(cloud, ROBOT, CONFIG.planner, CONFIG.memory, 0))
        screened = screen_candidates([cloud], CONFIG, [0])
        # Same candidate set (pairs may repeat: sampling is with replacement) and the same S_geom
        # ranking; pairs whose S_geom ties to float32 precision (opposite box faces all give 1.0)
        # may swap places, so rows are compared after sorting both by pair.
        assert np.allclose(screened.s_geom.numpy(), reference.s_geom, atol=1e-5)
        batched_pairs = screened.pair_indices.numpy()
        batched_order = np.lexsort(batched_pairs.T[::-1])
        reference_order = np.lexsort(reference.ranked_pairs.T[::-1])
        assert np.array_equal(batched_pairs[batched_order], reference.ranked_pairs[reference_order])
        assert np.allclose(screened.approach.numpy()[batched_order], reference.approaches[reference_order], atol=1e-4)
        usable_agreement = (screened.usable.numpy()[batched_order] == reference.usable[reference_order]).mean()
        assert usable_agreement > 0.99
        poses = reference.ik_trials
        batched = panda_ik(CONFIG).solve(
            torch.tensor(np.array([t["position"] for t in poses]), dtype=torch.float32),
            torch.tensor(np.array([t["rotation"] for t in poses]), dtype=torch.float32),
        )
        batched_feasible = (
            (batched.position_error_m < ROBOT.ik_position_tolerance_m) & (batched.s_reach >= CONFIG.planner.min_reach)
        ).numpy()
        agreement = (batched_feasible == np.array([t["feasible"] for t in poses])).mean()
        print(f"{cloud.object_id}: IK feasibility agreement {agreement:.1%} over {len(poses)} poses")
        assert agreement > 0.75


@pytest.mark.parametrize("first_block, max_block", [(512, 4096), (16, 64)])
def test_the_block_search_finds_the_lookahead_searchs_grasps_and_counts(box_cloud, can_cloud, monkeypatch, first_block, max_block):
    """Blocks of every verdict at once, or rounds sized by survival: the same first feasible approach
    of the same candidates, the same counts; with small blocks, over many blocks of several sizes."""
    monkeypatch.setattr(block_search, "FIRST_BLOCK_CANDIDATES", first_block)
    monkeypatch.setattr(block_search, "MIN_BLOCK_CANDIDATES", min(first_block, 256))
    monkeypatch.setattr(block_search, "MAX_BLOCK_CANDIDATES", max_block)
    blocks = CONFIG.override("planner", search="blocks")
    for seeds in ([0, 1], [5, 6]):
        expected = plan_batch([box_cloud, can_cloud], CONFIG, seeds)
        got = plan_batch([box_cloud, can_cloud], blocks, seeds)
        for want, result in zip(expected, got):
            assert result.counts == want.counts and want.counts.ik_feasible > 0
            assert max_block > 64 or want.counts.antipodal > 2 * max_block  # small blocks: many, growing
            for name in ("contacts", "approach", "ik_solution", "joint_path", "s_reach", "hand_clearance_m"):
                assert torch.equal(getattr(result.candidates, name), getattr(want.candidates, name)), name


def test_block_sizes_follow_the_yield_in_powers_of_two():
    assert block_search.next_block_size(0, 0, 200) == block_search.FIRST_BLOCK_CANDIDATES
    # 512 searched gave 125 of 200: 75 more at that yield, 1.25 times over, is 384 -> 512.
    assert block_search.next_block_size(512, 125, 200) == 512
    assert block_search.next_block_size(512, 199, 200) == block_search.MIN_BLOCK_CANDIDATES
    assert block_search.next_block_size(512, 0, 200) == 1024
    assert block_search.next_block_size(8192, 1, 200) == block_search.MAX_BLOCK_CANDIDATES
