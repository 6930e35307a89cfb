"""Every antipodal grasp with the planner's verdict: the verdicts are the planner's own checks, the
picked set covers the object (no two the same grasp) and spans the verdicts."""
import dataclasses
import math

import pytest
import torch

from sagp_batched import Scene, capture, load_config, load_object_set, plan
from sagp_batched.datasets.verdicts import (
    FEASIBLE, VERDICTS, _pick, _pick_across_verdicts, _verdict_quotas, capture_verdicts, classify_grasps, pool_for,
)
from sagp_batched_kernels.pose_nms import same_grasp


@pytest.fixture(scope="module")
def can_cloud():
    config = load_config("paper", overrides={"planner": {"n_pairs": 1500}})
    with Scene(config) as scene:
        scene.reset(load_object_set(None).get("005_tomato_soup_can"), trial=3)
        return config, capture(scene, config)


def test_quotas_give_the_feasible_share_and_spread_the_rest_over_the_rejections():
    assert _verdict_quotas({0: 100, 1: 100, 2: 100}, 40, 0.5) == {0: 20, 1: 10, 2: 10}
    # A verdict short of its share passes the remainder on.
    assert _verdict_quotas({0: 5, 1: 100, 2: 3}, 40, 0.5) == {0: 5, 1: 32, 2: 3}
    assert sum(_verdict_quotas({0: 2, 3: 1}, 40, 0.5).values()) == 3
    # A capped verdict (one geometry alone fails) takes no more than its cap, even with room left.
    assert _verdict_quotas({0: 5, 1: 100, 2: 100}, 40, 0.5, caps={1: 2}) == {0: 5, 1: 2, 2: 33}
    assert _verdict_quotas({0: 5, 1: 100}, 40, 0.5, caps={1: 2}) == {0: 5, 1: 2}


def test_every_grasp_the_planner_returns_is_classified_feasible(can_cloud):
    config, cloud = can_cloud
    config = dataclasses.replace(config, dataset=dataclasses.replace(config.dataset, nms_translation_m=0.0, feasible_fraction=1.0))
    classified = classify_grasps(cloud, config, seed=7, n_grasps=100_000)
    planned = plan(cloud, config, seed=7).candidates
    assert len(planned) > 0 and classified.covering_size == classified.pool_size
    feasible = classified.candidates.select(classified.verdict == VERDICTS.index("feasible"))
    for i in range(len(planned)):
        close = (feasible.position - planned.position[i]).norm(dim=1) < 1e-6
        aligned = (feasible.approach * planned.approach[i]).sum(dim=1) > 1 - 1e-6
        assert (close & aligned).any(), f"planned grasp {i} is not among the feasible ones"


def test_picked_grasps_are_distinct_span_the_verdicts_and_each_says_why(can_cloud):
    config, cloud = can_cloud
    classified = classify_grasps(cloud, config, seed=7, n_grasps=60)
    names = classified.verdict_names()
    assert len(classified) == 60 and "feasible" in names and len(set(names)) >= 3
    assert all(reason.startswith(name) for reason, name in zip(classified.reasons, names))
    grasps = classified.candidates
    same = same_grasp(grasps.position, grasps.rotation.double(), grasps.position, grasps.rotation.double(),
                      config.dataset.nms_translation_m, math.radians(config.dataset.nms_rotation_deg))
    assert torch.equal(same, torch.eye(len(grasps), dtype=torch.bool)), "no two picked grasps are the same grasp"
    feasible = classified.verdict == 0
    assert (grasps.joint_path[feasible].abs().sum(dim=(1, 2)) > 0).all() and (grasps.s_reach[feasible] > 0).all()
    assert (grasps.joint_path[~feasible] == 0).all()


@pytest.fixture(scope="module")
def two_captures(can_cloud):
    config, can = can_cloud
    with Scene(config) as scene:
        scene.reset(load_object_set(None).get("025_mug"), trial=5)
        return config, [can, capture(scene, config)]


def test_captures_planned_as_one_batch_get_the_verdicts_and_picks_each_gets_alone(two_captures):
    config, clouds = two_captures
    seeds = [7, 8]
    batch = capture_verdicts(clouds, config, seeds, n_grasps=30)
    for cloud, seed, verdicts in zip(clouds, seeds, batch):
        alone = capture_verdicts([cloud], config, [seed], n_grasps=30)[0]
        assert verdicts.pool_size == alone.pool_size and len(set(alone.verdict.tolist())) >= 3
        for name in ("verdict", "clearance", "joint_path", "s_reach"):
            assert torch.equal(getattr(verdicts, name), getattr(alone, name)), name
        for name in ("slots", "approach", "rotation", "centre"):
            assert torch.equal(getattr(verdicts.poses, name), getattr(alone.poses, name)), name
        assert torch.equal(verdicts.screened.pair_indices[verdicts.poses.rows], alone.screened.pair_indices[alone.poses.rows])
        from_batch, single = classify_grasps(cloud, config, seed, 30, verdicts=verdicts), classify_grasps(cloud, config, seed, 30)
        assert from_batch.verdict_names() == single.verdict_names() and from_batch.reasons == single.reasons
        for field in dataclasses.fields(single.candidates):
            mine, theirs = getattr(from_batch.candidates, field.name), getattr(single.candidates, field.name)
            assert torch.equal(mine, theirs) if isinstance(mine, torch.Tensor) else mine == theirs, field.name


def test_a_later_capture_leaves_out_the_grasps_an_earlier_one_took(can_cloud):
    config, cloud = can_cloud
    first = classify_grasps(cloud, config, seed=7, n_grasps=40)
    taken = first.candidates.transform(cloud.object_from_world, "object").poses()
    again = classify_grasps(cloud, config, seed=7, n_grasps=40, taken_object=taken)
    assert again.pool_size == first.pool_size and again.covering_size <= first.covering_size - len(first)
    picked = again.candidates.transform(cloud.object_from_world, "object").poses()
    same = same_grasp(picked.position, picked.rotation, taken.position, taken.rotation,
                      config.dataset.nms_translation_m, math.radians(config.dataset.nms_rotation_deg))
    assert len(again) == 40 and not same.any()


@pytest.mark.parametrize("poses, clear_share, n_grasps", [(5000, 0.6, 21), (300, 0.05, 40), (100, 0.0, 10), (50, 1.0, 60)])
def test_a_floating_pick_tests_the_draw_until_it_has_enough_and_picks_what_testing_every_pose_picks(poses, clear_share, n_grasps):
    dataset = load_config("dataset", overrides={"dataset": {"protocol": "floating"}}).dataset
    clear = torch.rand(poses, generator=torch.Generator().manual_seed(poses)) < clear_share
    tested = []
    lazy = _pick(torch.zeros(poses, dtype=torch.int64), 7, n_grasps, dataset, lambda rows: (tested.append(len(rows)), clear[rows])[1])
    colliding = VERDICTS.index("volume")
    classes = torch.where(clear, torch.full((poses,), FEASIBLE), torch.full((poses,), colliding))
    assert torch.equal(lazy, _pick_across_verdicts(classes, 7, n_grasps, 1.0, {colliding: int(dataset.geometry_verdict_fraction * n_grasps)}))
    # Enough clear hands early in the draw: a block or two tested, not every pose.
    assert sum(tested) == (64 if clear_share == 0.6 else poses)


def test_a_capture_samples_pairs_for_the_grasps_it_is_asked_for(can_cloud):
    config, cloud = can_cloud
    config = config.override("dataset", pairs_per_grasp=100, min_pairs=400)
    assert [pool_for(config, n).planner.n_pairs for n in (1, 4, 10, 15, 10_000)] == [400, 400, 1000, 1500, 1500]
    assert pool_for(config, None).planner.n_pairs == 1500
    few, full = (capture_verdicts([cloud], config, [7], n_grasps=n)[0] for n in (4, None))
    assert 0 < few.pool_size < full.pool_size
    assert len(classify_grasps(cloud, config, seed=7, n_grasps=4)) == 4
