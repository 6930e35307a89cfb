"""IK benchmark: targets of known reachability, forward kinematics of random in-limit joints
(reachable) and poses farther from the shoulder than any configuration reaches (unreachable),
every answer judged by forward kinematics, not by the solver's own flag; the planner's
``PandaIK`` against pytorch-kinematics' ``PseudoInverseIK`` on the same targets."""
from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable

import pytorch_kinematics as pk
import torch

from ..config import Config
from ..robot.description import robot_of
from ..robot.ik import PandaIK
from ..robot.kinematics import link_moved_by
from .planner_speed import BenchmarkSettings, median


@dataclasses.dataclass
class IKTargets:
    """A batch of IK target poses of ``panda_grasptarget``, world frame."""

    positions_world: torch.Tensor  # (N, 3) metres
    rotations_world: torch.Tensor  # (N, 3, 3) grasp-target frame -> world
    source_joints: torch.Tensor | None  # (N, 7) arm joints whose forward kinematics gave the pose; None if unreachable


def reachable_ik_targets(ik: PandaIK, table_top_z_m: float, count: int, seed: int) -> IKTargets:
    """``count`` poses that the arm reaches: forward kinematics of joints drawn uniformly inside the limits.

    Only poses whose grasp target lies above the table top are kept (tabletop-relevant), drawing more
    configurations until ``count`` are kept.
    """
    generator = torch.Generator().manual_seed(seed)
    kept_joints, kept_poses, n_kept = [], [], 0
    while n_kept < count:
        joints = ik.lower + (ik.upper - ik.lower) * torch.rand(max(2 * count, 64), 7, generator=generator)
        poses = ik.forward(joints)
        above_table = poses[:, 2, 3] > table_top_z_m
        kept_joints.append(joints[above_table])
        kept_poses.append(poses[above_table])
        n_kept += int(above_table.sum())
    joints = torch.cat(kept_joints)[:count]
    poses = torch.cat(kept_poses)[:count]
    return IKTargets(positions_world=poses[:, :3, 3].clone(), rotations_world=poses[:, :3, :3].clone(), source_joints=joints)


def shoulder_world(ik: PandaIK) -> torch.Tensor:
    """(3,) world position of the shoulder (origin of the link joint 2 moves, on joint 1's axis, so fixed)."""
    frames = ik.chain.forward_kinematics(torch.zeros(1, ik.n_joints), end_only=False)
    return frames[link_moved_by(ik.chain, ik.robot.arm_joints[1])].get_matrix()[0, :3, 3] + ik.base_xyz_world


def reach_bound_from_shoulder_m(ik: PandaIK) -> float:
    """Upper bound (m) on the distance of ``panda_grasptarget`` from the shoulder in any configuration.

    The sum of the lengths of every frame offset after the shoulder's link (triangle inequality), so no
    joint values can exceed it: 1.09 m for the Panda, whose sampled maximum is ~0.95 m.
    """
    names = ik.chain.get_frame_names(exclude_fixed=False)
    bound = 0.0
    for name in names[names.index(link_moved_by(ik.chain, ik.robot.arm_joints[1])) + 1 :]:
        frame = ik.chain.find_frame(name)
        for offset in (frame.joint.offset, frame.link.offset):
            if offset is not None:
                bound += float(offset.get_matrix()[0, :3, 3].norm())
    return bound


def unreachable_ik_targets(ik: PandaIK, count: int, min_distance_from_shoulder_m: float, seed: int) -> IKTargets:
    """``count`` poses beyond the arm's reach: positions between 1x and 1.25x ``min_distance_from_shoulder_m``
    from the shoulder in uniformly random directions, uniformly random orientations."""
    generator = torch.Generator().manual_seed(seed)
    direction = torch.nn.functional.normalize(torch.randn(count, 3, generator=generator), dim=1)
    distance = min_distance_from_shoulder_m * (1.0 + 0.25 * torch.rand(count, 1, generator=generator))
    quaternion_wxyz = torch.nn.functional.normalize(torch.randn(count, 4, generator=generator), dim=1)
    return IKTargets(
        positions_world=shoulder_world(ik) + direction * distance,
        rotations_world=pk.quaternion_to_matrix(quaternion_wxyz),
        source_joints=None,
    )


def pose_errors(ik: PandaIK, joints: torch.Tensor, targets: IKTargets) -> tuple[torch.Tensor, torch.Tensor]:
    """(N,) position error (m) and (N,) rotation angle error (rad) of pk's forward kinematics of
    (N, 7) ``joints`` against ``targets``, computed in float64 from the pose matrices."""
    reached = ik.forward(joints).to(torch.float64)
    position_error = (reached[:, :3, 3] - targets.positions_world.to(torch.float64)).norm(dim=1)
    relative = targets.rotations_world.to(torch.float64).transpose(1, 2) @ reached[:, :3, :3]
    cos_angle = ((relative.diagonal(dim1=1, dim2=2).sum(dim=1) - 1.0) / 2.0).clamp(-1.0, 1.0)
    return position_error, torch.arccos(cos_angle)


def inside_joint_limits(ik: PandaIK, joints: torch.Tensor) -> torch.Tensor:
    """(N,) bool: every joint of (N, 7) ``joints`` within ``ik.lower``/``ik.upper``."""
    return ((joints >= ik.lower) & (joints <= ik.upper)).all(dim=1)


# (positions_world (N, 3), rotations_world (N, 3, 3)) -> (joints (N, 7), the solver's own success claim (N,) bool)
IKSolve = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


def panda_ik_solve(ik: PandaIK) -> IKSolve:
    """The planner's IK as configured."""

    def solve(positions_world: torch.Tensor, rotations_world: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        result = ik.solve(positions_world, rotations_world)
        return result.joints, result.success

    return solve


def pk_pseudo_inverse_solve(ik: PandaIK, config: Config, seed: int = 0) -> IKSolve:
    """pytorch-kinematics' own ``PseudoInverseIK`` on the same chain: 10 random retries x 30 iterations.

    It converges to the planner's tolerances so that its ``converged_any`` means what ``IKResult.success``
    means; ``regularlization`` (sic) 1e-6 because its 1e-9 default raised ``LinAlgError`` for a whole
    float32 batch on one near-singular target. Its retry seeds are drawn at construction from torch's
    global generator, seeded here without disturbing the caller's.
    """
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        solver = pk.PseudoInverseIK(
            ik.chain,
            num_retries=10,
            joint_limits=torch.stack((ik.lower, ik.upper), dim=1),
            max_iterations=30,
            early_stopping_any_converged=True,
            regularlization=1e-6,
            pos_tolerance=ik.robot.ik_position_tolerance_m,
            rot_tolerance=ik.robot.ik_rotation_tolerance_rad,
        )

    def solve(positions_world: torch.Tensor, rotations_world: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        target = pk.Transform3d(pos=positions_world - ik.base_xyz_world, rot=pk.matrix_to_quaternion(rotations_world))
        solution = solver.solve(target)
        # Best retry: a converged one first, then the smallest position error.
        best = (solution.err_pos + 1e3 * (~solution.converged).float()).argmin(dim=1)
        rows = torch.arange(len(positions_world))
        return solution.solutions[rows, best], solution.converged_any

    return solve


@dataclasses.dataclass
class IKSolverMeasures:
    """One solver's figures on the reachable and unreachable target sets."""

    solver: str
    seconds_median: float  # one call on all reachable targets in one batch
    targets_per_s: float
    success_rate: float  # reachable set: FK of the answer within tolerance and joints inside limits (independent check)
    claimed_success_rate: float  # reachable set: the solver's own success flag
    inside_limits_rate: float  # reachable set: answers with every joint inside the limits
    false_reachable_rate: float  # unreachable set: the solver's own success flag
    joints: torch.Tensor  # (N, 7) answers on the reachable set (last timed call)

    def figures(self) -> dict[str, Any]:
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self) if field.name != "joints"}


def measure_ik_solver(
    name: str, solve: IKSolve, ik: PandaIK, config: Config, reachable: IKTargets, unreachable: IKTargets, repeats: int
) -> IKSolverMeasures:
    """Time ``solve`` on all reachable targets (median of ``repeats`` calls after a small warm-up) and
    judge its answers by pk forward kinematics against the planner's tolerances."""
    solve(reachable.positions_world[:16], reachable.rotations_world[:16])
    durations = []
    for _ in range(repeats):
        start = time.perf_counter()
        joints, claimed = solve(reachable.positions_world, reachable.rotations_world)
        durations.append(time.perf_counter() - start)
    position_error, rotation_error = pose_errors(ik, joints, reachable)
    inside = inside_joint_limits(ik, joints)
    success = (position_error <= ik.robot.ik_position_tolerance_m) & (rotation_error <= ik.robot.ik_rotation_tolerance_rad) & inside
    _, claimed_unreachable = solve(unreachable.positions_world, unreachable.rotations_world)
    seconds = median(durations)
    return IKSolverMeasures(
        solver=name,
        seconds_median=seconds,
        targets_per_s=len(joints) / seconds,
        success_rate=float(success.double().mean()),
        claimed_success_rate=float(claimed.double().mean()),
        inside_limits_rate=float(inside.double().mean()),
        false_reachable_rate=float(claimed_unreachable.double().mean()) if len(claimed_unreachable) else 0.0,
        joints=joints,
    )


def benchmark_ik_solvers(config: Config, settings: BenchmarkSettings) -> tuple[IKTargets, IKTargets, list[IKSolverMeasures]]:
    """The planner's ``PandaIK.solve`` and pk's ``PseudoInverseIK`` on the same reachable / unreachable targets."""
    ik = PandaIK(config.ik, robot_of(config))
    reachable = reachable_ik_targets(ik, config.scene.table_top_z_m, settings.ik_targets, seed=0)
    unreachable = unreachable_ik_targets(ik, settings.ik_unreachable_targets, settings.ik_unreachable_min_distance_m, seed=1)
    solvers = (("PandaIK", panda_ik_solve(ik)), ("pk.PseudoInverseIK 10x30", pk_pseudo_inverse_solve(ik, config)))
    measures = [measure_ik_solver(name, solve, ik, config, reachable, unreachable, settings.repeats) for name, solve in solvers]
    return reachable, unreachable, measures


def benchmark_ik(config: Config, settings: BenchmarkSettings) -> dict[str, Any]:
    """IK figures on targets of known reachability (see ``benchmark_ik_solvers``), as a JSON-ready dict."""
    _, _, measures = benchmark_ik_solvers(config, settings)
    robot = robot_of(config)
    return {
        "reachable_targets": settings.ik_targets,
        "unreachable_targets": settings.ik_unreachable_targets,
        "unreachable_min_distance_from_shoulder_m": settings.ik_unreachable_min_distance_m,
        "pos_tolerance_m": robot.ik_position_tolerance_m,
        "rot_tolerance_rad": robot.ik_rotation_tolerance_rad,
        "solvers": [m.figures() for m in measures],
    }
