"""The IK benchmark's targets have known reachability and its success rate is what forward kinematics says."""
import pytest
import pytorch_kinematics as pk
import torch

from sagp_batched.benchmarks.ik_speed import (
    benchmark_ik,
    benchmark_ik_solvers,
    reach_bound_from_shoulder_m,
    reachable_ik_targets,
    shoulder_world,
    unreachable_ik_targets,
)
from sagp_batched.benchmarks.planner_speed import BenchmarkSettings
from sagp_batched.config import Config
from sagp_batched.robot.description import load_robot
from sagp_batched.robot.ik import PandaIK

ROBOT = load_robot()

CONFIG = Config()
SETTINGS = BenchmarkSettings(
    pairs=(), repeats=1, reference_max_pairs=0, cloud_points=0, object_xy_m=(0.55, 0.0), ik_targets=50, ik_unreachable_targets=50
)


@pytest.fixture(scope="module")
def ik():
    return PandaIK(CONFIG.ik, ROBOT)


@pytest.fixture(scope="module")
def solved():
    return benchmark_ik_solvers(CONFIG, SETTINGS)


def test_reachable_targets_are_fk_of_in_limit_joints_above_the_table(ik):
    targets = reachable_ik_targets(ik, CONFIG.scene.table_top_z_m, 300, seed=0)
    assert targets.positions_world.shape == (300, 3) and targets.source_joints.shape == (300, 7)
    assert ((targets.source_joints >= ik.lower) & (targets.source_joints <= ik.upper)).all()
    # pk forward kinematics of the source joints, from the chain directly, in the world frame.
    reached = ik.chain.forward_kinematics(targets.source_joints).get_matrix()
    reached_position_world = reached[:, :3, 3] + torch.tensor(ROBOT.base_xyz_m)
    assert torch.allclose(reached_position_world, targets.positions_world, atol=1e-6)
    assert torch.allclose(reached[:, :3, :3], targets.rotations_world, atol=1e-6)
    assert (targets.positions_world[:, 2] > CONFIG.scene.table_top_z_m).all()
    # A different seed gives different targets: the draw is seeded, not fixed.
    assert not torch.allclose(reachable_ik_targets(ik, CONFIG.scene.table_top_z_m, 300, seed=1).positions_world, targets.positions_world)


def test_reach_bound_holds_for_random_configurations(ik):
    bound = reach_bound_from_shoulder_m(ik)
    joints = ik.lower + (ik.upper - ik.lower) * torch.rand(20_000, 7, generator=torch.Generator().manual_seed(0))
    farthest = (ik.forward(joints)[:, :3, 3] - shoulder_world(ik)).norm(dim=1).max()
    assert 0.85 < farthest < bound < SETTINGS.ik_unreachable_min_distance_m


def test_unreachable_targets_all_lie_beyond_reach(ik):
    targets = unreachable_ik_targets(ik, 500, SETTINGS.ik_unreachable_min_distance_m, seed=1)
    distance = (targets.positions_world - shoulder_world(ik)).norm(dim=1)
    assert (distance > reach_bound_from_shoulder_m(ik)).all()
    assert torch.allclose(targets.rotations_world @ targets.rotations_world.transpose(1, 2), torch.eye(3).expand(500, 3, 3), atol=1e-5)


def _within_tolerance(ik, joints, targets):
    """(N,) bool: pk FK of ``joints`` within the planner's tolerances of ``targets`` (axis-angle error, not the benchmark's arccos)."""
    reached = ik.chain.forward_kinematics(joints).get_matrix().double()
    position_error = (reached[:, :3, 3] + ik.base_xyz_world.double() - targets.positions_world.double()).norm(dim=1)
    relative = reached[:, :3, :3] @ targets.rotations_world.double().transpose(1, 2)
    rotation_error = pk.matrix_to_axis_angle(relative).norm(dim=1)
    return (position_error <= ROBOT.ik_position_tolerance_m) & (rotation_error <= ROBOT.ik_rotation_tolerance_rad)


def test_success_rate_is_the_fraction_within_tolerance_by_forward_kinematics(ik, solved):
    reachable, _, measures = solved
    assert [m.solver for m in measures] == ["PandaIK", "pk.PseudoInverseIK 10x30"]
    for measure in measures:
        within = _within_tolerance(ik, measure.joints, reachable)
        inside = ((measure.joints >= ik.lower) & (measure.joints <= ik.upper)).all(dim=1)
        assert measure.success_rate == pytest.approx(float((within & inside).double().mean()), abs=1e-12)
        assert measure.inside_limits_rate == pytest.approx(float(inside.double().mean()), abs=1e-12)
        assert 0.5 < measure.success_rate <= 1.0


def test_no_solver_calls_an_unreachable_target_reachable(solved):
    _, unreachable, measures = solved
    assert len(unreachable.positions_world) == 50
    for measure in measures:
        assert measure.false_reachable_rate == 0.0


def test_planner_ik_success_flag_passes_the_independent_check(ik, solved):
    reachable, _, measures = solved
    result = ik.solve(reachable.positions_world, reachable.rotations_world)
    (planner,) = [m for m in measures if m.solver == "PandaIK"]
    assert torch.equal(result.joints, planner.joints)  # deterministic seeds: same answers as the benchmark
    assert float(result.success.double().mean()) == planner.claimed_success_rate
    # Every answer the planner calls a success is one by forward kinematics (no false claims).
    assert not (result.success & ~_within_tolerance(ik, result.joints, reachable)).any()


def test_report_has_the_figures_per_solver():
    report = benchmark_ik(CONFIG, SETTINGS)
    assert report["reachable_targets"] == 50 and report["unreachable_targets"] == 50
    assert report["pos_tolerance_m"] == ROBOT.ik_position_tolerance_m
    for row in report["solvers"]:
        assert set(row) == {
            "solver", "seconds_median", "targets_per_s", "success_rate", "claimed_success_rate",
            "inside_limits_rate", "false_reachable_rate",
        }
        assert row["seconds_median"] > 0 and 0 <= row["inside_limits_rate"] <= 1
