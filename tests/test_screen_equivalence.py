"""The planner's culled collision screens decide exactly what evaluating every point decides.

The swept-hand check evaluates the exact k-DOP separation only on the points a cheap bound cannot
rule out, the table check only on the poses a few hull points cannot decide, the gripper volume
only on poses that clear the table, and ``plan_batch`` screens candidates ahead of its window in
blocks; each is compared here with the plain definition: every point, every pose, one window
round at a time.
"""
import dataclasses
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from planner_clouds import box_surface, make_cloud
from sagp_batched import load_object_set
from sagp_batched.benchmarks.planner_speed import BenchmarkSettings, mesh_cloud
from sagp_batched.config import Config
from sagp_batched.planning import (
    CandidateStatus, ScreenedCandidates, SearchTuning, gripper_geometry, hand_geometry, motion_check, plan, plan_batch, screen_candidates,
)
from sagp_batched.planning.lookahead import MotionVerdicts, ScreenVerdicts
from sagp_batched.planning.search import segment_exclusive_cumsum
from sagp_batched.robot.description import load_robot
from sagp_batched.robot.hand import DOP_DIRECTIONS
from sagp_batched_kernels.hand_clearance import HandClearance
from sagp_batched_kernels.table_penetration import TABLE_BLOCK_POSES, table_penetration

ROBOT = load_robot()

CONFIG = Config()
TABLE_Z = CONFIG.scene.table_top_z_m
OBJECTS = ("025_mug", "003_cracker_box", "005_tomato_soup_can")


@pytest.fixture(scope="module")
def ycb_clouds(ycb_dir, tmp_path_factory):
    """Mesh clouds of the mug, box and can standing on the table, alone and beside a distractor
    (another object's points as obstacles), plus a grid-sampled box whose points sit exactly on
    the gripper's faces for axis-aligned grasps (ties the float rounding must decide alike)."""
    settings = BenchmarkSettings(pairs=(CONFIG.planner.n_pairs,), repeats=1, reference_max_pairs=0, cloud_points=3000,
                                 object_xy_m=(0.55, 0.0), ik_targets=1)
    objects = load_object_set(ycb_dir)
    cache = tmp_path_factory.mktemp("clouds")
    clouds = {name: mesh_cloud(objects.get(name), CONFIG, settings, cache) for name in OBJECTS}
    beside = torch.tensor([0.0, 0.1, 0.0])
    clouds["mug beside the can"] = replace(clouds["025_mug"], obstacle_points_world=clouds["005_tomato_soup_can"].points_world + beside)
    clouds["box beside the mug"] = replace(clouds["003_cracker_box"], obstacle_points_world=clouds["025_mug"].points_world - beside)
    points, normals = box_surface((0.06, 0.05, 0.15), (0.55, 0.0, TABLE_Z + 0.075))
    clouds["grid box"] = make_cloud(points, normals, "grid box")
    return clouds


def dense_hand_clearance(screened: ScreenedCandidates, rows: torch.Tensor, slots: torch.Tensor) -> HandClearance:
    """The swept-hand definition on every point of the scene, one GEMM per candidate batch."""
    low, high = hand_geometry(screened.robot).swept((0.0, 0.0, -screened.pregrasp_offset_m))
    relative = screened.hand_check_points[screened.object_index[rows]] - screened.centre_world[rows, None, :]
    axes = DOP_DIRECTIONS @ screened.rotation_world[rows, slots].transpose(-1, -2)
    projection = (axes @ relative.transpose(1, 2))[:, None]
    separation = ((projection - ((low + high) / 2)[None, :, :, None]).abs() - ((high - low) / 2)[None, :, :, None]).amax(dim=2).amin(dim=1)
    clearance = torch.nan_to_num(separation, nan=float("inf")).amin(dim=1)
    return HandClearance(clearance < screened.planner.hand_clearance_margin_m, clearance)


def dense_table_penetration(centre, rotation, points, retreat_m, table_top_z_m):
    lowest = (centre[:, 2, None, None] + rotation[..., 2, :] @ points.T).min(dim=-1).values
    return (lowest < table_top_z_m) | (lowest - retreat_m * rotation[..., 2, 2] < table_top_z_m)


@pytest.mark.parametrize("name", [*OBJECTS, "mug beside the can", "box beside the mug", "grid box"])
def test_the_culled_hand_check_blocks_exactly_the_grasps_every_point_blocks_and_gives_clear_ones_their_exact_clearance(ycb_clouds, name):
    screened = screen_candidates([ycb_clouds[name]], CONFIG, [1])
    # Grasps the planner would sweep (clear of the table, under the volume limit): every tenth, and
    # every one the culled check calls clear, since beside an obstacle those can be a few in 4,000.
    rows, slots = screened.usable.nonzero(as_tuple=True)
    picked = ~screened.hand_clearance(rows, slots).blocked
    picked[::10] = True
    rows, slots = rows[picked], slots[picked]
    culled = screened.hand_clearance(rows, slots)
    dense = torch.cat([torch.stack(dense_hand_clearance(screened, r, s), dim=1) for r, s in zip(rows.split(512), slots.split(512))])
    blocked, clearance = dense[:, 0].bool(), dense[:, 1]
    assert torch.equal(culled.blocked, blocked)
    assert torch.equal(culled.clearance_m[~blocked], clearance[~blocked])
    # Blocked grasps report a separation under the margin (of a point that blocks them).
    assert (culled.clearance_m[blocked] < CONFIG.planner.hand_clearance_margin_m).all()
    # Both verdicts occur, or the comparison says little.
    assert blocked.any() and not blocked.all()


@pytest.mark.parametrize("name", [*OBJECTS, "grid box"])
def test_the_table_check_decides_every_pose_as_checking_every_hull_point_does(ycb_clouds, name):
    screened = screen_candidates([ycb_clouds[name]], CONFIG, [0])
    hand = hand_geometry(ROBOT)
    centre, rotation = screened.centre_world, screened.rotation_world
    # A grid of table heights puts the table top close to many poses' lowest points.
    for table_z in np.linspace(TABLE_Z - 0.02, TABLE_Z + 0.06, 9):
        for links in (ROBOT.gripper.pad_links, tuple(n for n in hand.links if n not in ROBOT.gripper.pad_links)):
            points = hand.vertices(links)
            through = table_penetration(centre, rotation, points, CONFIG.motion.pregrasp_offset_m, float(table_z))
            assert torch.equal(through, dense_table_penetration(centre, rotation, points, CONFIG.motion.pregrasp_offset_m, float(table_z)))
    assert 0.05 < through.float().mean() < 0.95


@pytest.mark.parametrize(("shift_m", "block_poses"), [((0.0, 0.0, 0.0), TABLE_BLOCK_POSES), ((30.0, -20.0, 10.0), 13)])
def test_the_table_check_decides_poses_whose_lowest_point_lies_exactly_at_the_table_top_as_every_point_does(ycb_clouds, monkeypatch, shift_m, block_poses):
    """Table tops equal to some poses' exact lowest heights (at the grasp or the pre-grasp), where
    the verdict turns on equality, also with the scene moved far from the origin and with GEMMs of
    a few poses each."""
    monkeypatch.setattr("sagp_batched_kernels.table_penetration.TABLE_BLOCK_POSES", block_poses)
    screened = screen_candidates([ycb_clouds["025_mug"]], CONFIG, [0])
    hand = hand_geometry(ROBOT)
    centre, rotation = screened.centre_world + torch.tensor(shift_m), screened.rotation_world
    retreat = CONFIG.motion.pregrasp_offset_m
    for links in (ROBOT.gripper.pad_links, tuple(n for n in hand.links if n not in ROBOT.gripper.pad_links)):
        points = hand.vertices(links)
        lowest = (centre[:, 2, None, None] + rotation[..., 2, :] @ points.T).amin(dim=-1)
        heights = torch.cat((lowest.flatten()[::997], (lowest - retreat * rotation[..., 2, 2]).flatten()[::997]))
        for table_z in heights.tolist():
            through = table_penetration(centre, rotation, points, retreat, table_z)
            assert torch.equal(through, dense_table_penetration(centre, rotation, points, retreat, table_z))


def test_planning_with_verdicts_computed_ahead_returns_what_screening_one_window_round_at_a_time_returns(ycb_clouds, monkeypatch):
    """``plan_batch`` with its lookahead blocks and culled hand check, against the same planner
    screening exactly the window's unscreened candidates per round with the dense hand check."""
    clouds = [ycb_clouds["025_mug"], ycb_clouds["box beside the mug"]]
    seeds = [3, 4]
    config = CONFIG.override("planner", n_pairs=2000)
    fast = plan_batch(clouds, config, seeds)
    monkeypatch.setattr(ScreenVerdicts, "block_sizes", lambda self, missing: missing)
    monkeypatch.setattr(ScreenedCandidates, "hand_clearance", dense_hand_clearance)
    assert_same_plans(fast, plan_batch(clouds, config, seeds))
    assert sum(result.counts.rejected_hand for result in fast) > 0 and all(len(result.candidates) > 0 for result in fast)


def test_plan_batch_returns_each_clouds_single_plan_bit_for_bit(ycb_clouds):
    """One ``plan_batch`` over clouds of different sizes, with and without obstacle points (so
    padded to the largest scene), against a single ``plan`` per cloud: every candidate field and
    every count."""
    names = ["mug beside the can", "005_tomato_soup_can", "grid box", "003_cracker_box", "box beside the mug", "025_mug"]
    seeds = [11, 12, 13, 14, 15, 16]
    config = CONFIG.override("planner", n_pairs=2000, max_candidates=40)
    batched = plan_batch([ycb_clouds[name] for name in names], config, seeds)
    for name, seed, result in zip(names, seeds, batched, strict=True):
        single = plan(ycb_clouds[name], config, seed=seed)
        assert result.counts == single.counts, name
        for field in dataclasses.fields(single.candidates):
            value, expected = getattr(result.candidates, field.name), getattr(single.candidates, field.name)
            assert torch.equal(value, expected) if isinstance(expected, torch.Tensor) else value == expected, (name, field.name)
    assert all(len(result.candidates) > 0 for result in batched)


def assert_same_plans(got: list, expected: list) -> None:
    """The same candidates, frames, joint paths, margins, clearances and counts, bit for bit."""
    for result, reference in zip(got, expected, strict=True):
        assert result.counts == reference.counts
        for field in ("contacts", "s_geom", "approach", "rotation", "joint_path", "s_reach", "hand_clearance_m"):
            assert torch.equal(getattr(result.candidates, field), getattr(reference.candidates, field)), field


def test_planning_with_motions_checked_ahead_returns_what_checking_each_rounds_pending_grasps_returns(ycb_clouds, monkeypatch):
    """``plan_batch`` checking later approaches and candidates past the window ahead, against the
    same planner checking, each round, exactly the pending grasps without a result."""
    clouds = [ycb_clouds["003_cracker_box"], ycb_clouds["005_tomato_soup_can"], ycb_clouds["mug beside the can"]]
    seeds = [5, 6, 7]
    config = CONFIG.override("planner", n_pairs=3000, max_candidates=60)
    batches = []
    check_motions = motion_check.check_motions
    monkeypatch.setattr(motion_check, "check_motions", lambda *args, **kwargs: batches.append(args[0].shape[0]) or check_motions(*args, **kwargs))
    ahead = plan_batch(clouds, config, seeds)
    ahead_batches, batches[:] = list(batches), []

    def pending_only(self, pending, slots, search, screens, check):
        missing = ~self.ready[pending, slots]
        if missing.any():
            self.store(pending[missing], slots[missing], check(pending[missing], slots[missing]))

    monkeypatch.setattr(MotionVerdicts, "ensure", pending_only)
    assert_same_plans(ahead, plan_batch(clouds, config, seeds))
    assert sum(result.counts.rejected_grasp_ik + result.counts.rejected_motion for result in ahead) > 0
    assert len(ahead_batches) < len(batches)


def previous_lookahead(self, pending, slots, search, screens, check):
    """The motion lookahead before the losses it expects were sized by cost (e8ed604): the pending
    grasps without a result (with their later approaches in a round of fewer than 32), and the first
    usable approach of 1.25 x (pending x the share of decided candidates that ran out) candidates
    past the window, a small round filled to 32 with more of them."""
    missing = ~self.ready[pending, slots]
    if not missing.any():
        return
    candidate_object, n_objects = screens.screened.object_index, int(screens.screened.occupancy_points.shape[0])
    rows = pending[missing]
    ahead = torch.zeros_like(self.ready)
    ahead[rows, slots[missing]] = True
    small = rows.numel() < 32
    if small:
        ahead[rows] = search.usable[rows] & (torch.arange(self.ready.shape[1]) >= slots[missing, None])
    decided = search.screened & screens.any_usable & (search.status != CandidateStatus.UNDECIDED)
    exhausted = torch.zeros(n_objects).index_add_(0, candidate_object, (decided & (search.status == CandidateStatus.EXHAUSTED)).float())
    share = (exhausted + 0.4) / (torch.zeros(n_objects).index_add_(0, candidate_object, decided.float()) + 4)
    per_object = torch.zeros(n_objects).index_add_(0, candidate_object[rows], torch.ones(rows.numel()))
    extra = (1.25 * per_object * share).ceil().to(torch.int64)
    if small:
        spare = max(0, 32 - int(ahead.sum())) / int((per_object > 0).sum())
        extra = torch.where(per_object > 0, extra.clamp_min(math.ceil(spare)), extra)
    beyond = ~search.screened & (search.status == CandidateStatus.UNDECIDED)  # the window's candidates are all screened
    past_count = torch.zeros(n_objects, dtype=torch.int64).index_add_(0, candidate_object, (beyond & screens.ready & screens.any_usable).long())
    if ((extra - past_count) > 0).any() and (beyond & ~screens.ready).any():
        screens.compute_ahead(beyond & ~screens.ready, (extra - past_count).clamp_min(0))
    past = beyond & screens.ready & screens.any_usable
    chosen = (past & (segment_exclusive_cumsum(past.long(), candidate_object, n_objects) < extra[candidate_object])).nonzero().squeeze(1)
    ahead[chosen, screens.usable[chosen].to(torch.int8).argmax(dim=1)] = True
    check_rows, check_slots = (ahead & ~self.ready).nonzero(as_tuple=True)
    self.store(check_rows, check_slots, check(check_rows, check_slots))


def test_lookahead_sized_by_the_observed_losses_plans_alike_in_fewer_motion_rounds_and_screening_calls(ycb_clouds, monkeypatch):
    """Once an object's losses to the motion checks are observed, a round checks every approach its
    expected candidates may need and the window screens them in its own blocks, which grow by at
    least ``SearchTuning.min_block_growth``: against the previous rule (``previous_lookahead``, blocks growing by
    halves for the window alone) the plans are the same, in fewer motion rounds and screening calls.
    A cracker box loses ~40 % of its screened candidates to grasp IK and motion; the mug screens all
    of its candidates and still lacks feasible ones, while the others screen further ahead."""
    clouds = [ycb_clouds["003_cracker_box"], ycb_clouds["005_tomato_soup_can"], ycb_clouds["box beside the mug"], ycb_clouds["025_mug"]]
    seeds = [1, 2, 3, 0]
    calls = {"screen": 0, "motion": 0}
    check_motions, compute = motion_check.check_motions, ScreenVerdicts.compute

    def counted_check(*args, **kwargs):
        calls["motion"] += 1
        return check_motions(*args, **kwargs)

    def counted_compute(self, rows):
        calls["screen"] += 1
        return compute(self, rows)

    monkeypatch.setattr(motion_check, "check_motions", counted_check)
    monkeypatch.setattr(ScreenVerdicts, "compute", counted_compute)
    sized = plan_batch(clouds, CONFIG, seeds)
    sized_calls, calls["screen"], calls["motion"] = dict(calls), 0, 0
    monkeypatch.setattr(MotionVerdicts, "ensure", previous_lookahead)
    monkeypatch.setattr(MotionVerdicts, "screening_shortfall", lambda self, search, screens: torch.zeros(len(clouds), dtype=torch.int64))
    assert_same_plans(sized, plan_batch(clouds, CONFIG, seeds, tuning=SearchTuning(min_block_growth=0)))
    assert all(result.counts.rejected_grasp_ik + result.counts.rejected_motion > 20 for result in sized[:3])
    assert len(sized[3].candidates) < CONFIG.planner.max_candidates
    assert sized_calls["motion"] < calls["motion"] and sized_calls["screen"] < calls["screen"], (sized_calls, calls)


def dense_gripper_points(screened: ScreenedCandidates, rows: torch.Tensor) -> torch.Tensor:
    """(R, K) points inside the finger slabs plus points inside the palm, every point and approach."""
    geometry = gripper_geometry(screened.robot, screened.planner)
    n_approaches, n_points = screened.rotation_world.shape[1], screened.occupancy_points.shape[1]
    relative = screened.occupancy_points[screened.object_index[rows]] - screened.centre_world[rows, None, :]
    axes = screened.rotation_world[rows].transpose(-1, -2).reshape(rows.numel(), n_approaches * 3, 3)
    x, y, z = (axes @ relative.transpose(1, 2)).view(rows.numel(), n_approaches, 3, n_points).unbind(dim=2)
    finger_z_max = geometry.fingertip_offset_m
    finger_z_min = finger_z_max - geometry.finger_length_m
    palm_z_min = finger_z_min - geometry.palm_depth_m
    finger_y_max = geometry.open_width_m / 2 + geometry.finger_thickness_m
    finger_y_min = (screened.width_m[rows] / 2 + geometry.contact_clearance_m)[:, None, None]
    # The interval tests in the kernel's |value - middle| <= half-length form, whose rounding
    # decides points that lie exactly on a face (the grid box's).
    def within(value, lower, upper):
        return (value - (lower + upper) / 2).abs() <= (upper - lower) / 2
    fingers = within(y.abs(), finger_y_min, finger_y_max) & (x.abs() <= geometry.finger_width_m / 2) & within(z, finger_z_min, finger_z_max)
    palm = (y.abs() <= geometry.palm_span_m / 2) & (x.abs() <= geometry.palm_width_m / 2) & within(z, palm_z_min, finger_z_min)
    return fingers.sum(dim=-1) + palm.sum(dim=-1)


@pytest.mark.parametrize("name", ["025_mug", "box beside the mug", "grid box"])
def test_volumes_counted_only_where_the_table_is_clear_give_the_verdicts_of_counting_every_pose(ycb_clouds, name):
    screened = screen_candidates([ycb_clouds[name]], CONFIG, [2])
    rows = torch.arange(0, screened.width_m.shape[0], 3)
    counted = torch.cat([dense_gripper_points(screened, part) for part in rows.split(256)])
    under_limit = counted.to(torch.float32) <= CONFIG.planner.occupancy_max_fraction * screened.occupancy_total[0]
    clear_of_table = screened.clear_of_table(rows)
    expected = clear_of_table & under_limit
    assert torch.equal(screened.table_and_volume_ok(rows), expected)
    assert expected.any() and not expected.all() and (clear_of_table & ~under_limit).any()


def assert_identical_plans(got, expected) -> None:
    """Every tensor field of the candidates (and the counts and zone names) equal, bit for bit, dtypes included."""
    assert got.counts == expected.counts and got.candidates.zone_names == expected.candidates.zone_names
    for field in dataclasses.fields(expected.candidates):
        value, reference = getattr(got.candidates, field.name), getattr(expected.candidates, field.name)
        if isinstance(reference, torch.Tensor):
            assert value.dtype == reference.dtype and torch.equal(value, reference), field.name
        else:
            assert value == reference, field.name


def test_each_cloud_of_a_batch_is_planned_as_it_is_alone(ycb_clouds):
    """``plan_batch`` over clouds of different sizes and kinds (mug, box, can, with and without an
    obstacle beside them, a grid box) gives each cloud the plan ``plan`` gives it alone with its
    seed, every tensor bit for bit; and a batch of one is ``plan``."""
    names = [*OBJECTS, "mug beside the can", "box beside the mug", "grid box"]
    clouds, seeds = [ycb_clouds[name] for name in names], [7, 1, 4, 2, 5, 3]
    config = CONFIG.override("planner", n_pairs=3000)
    batched = plan_batch(clouds, config, seeds)
    for cloud, seed, result in zip(clouds, seeds, batched, strict=True):
        assert_identical_plans(result, plan(cloud, config, seed=seed))
    (alone,) = plan_batch(clouds[-1:], config, seeds[-1:])
    assert_identical_plans(alone, plan(clouds[-1], config, seed=seeds[-1]))
    # Full plans, short ones and an empty one (the mug at this seed) alike.
    assert sum(len(result.candidates) > 0 for result in batched) >= 4 and len({len(result.candidates) for result in batched}) > 2
