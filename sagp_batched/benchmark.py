"""Planner benchmark: batched planner versus the loop reference on clouds of real YCB objects.

Clouds come from the YCB meshes (Open3D uniform surface sampling with triangle normals, placed
upright on the table at a fixed pose) rather than from perception, so the benchmark measures the
planner alone; they are cached as ``.npz`` files outside the repository.

The IK benchmark solves targets of known reachability: forward kinematics of random in-limit joints
(reachable) and poses farther from the shoulder than any configuration reaches (unreachable), and
judges every answer by forward kinematics, not by the solver's own flag.
"""
from __future__ import annotations

import dataclasses
import json
import statistics
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytorch_kinematics as pk
import torch

from ._open3d import o3d
from .config import Config
from .ik import PandaIK
from .kinematics import link_moved_by
from .objects import ObjectSpec
from .planning import PlanStageTimes, plan, plan_batch, sample_inputs
from .reference import plan_reference
from .robot import robot_of
from .types import PerceivedCloud

STAGES = ("sampling", "antipodal", "frames_volume", "hand_sweep", "ik", "motion")


@dataclasses.dataclass
class BenchmarkSettings:
    pairs: tuple[int, ...]
    repeats: int
    reference_max_pairs: int  # the loop reference runs (once) only up to this many pairs
    cloud_points: int
    object_xy_m: tuple[float, float]
    ik_targets: int  # reachable IK targets (N)
    ik_unreachable_targets: int = 200  # unreachable IK targets (M)
    # Unreachable targets lie at least this far from the shoulder; no Panda pose reaches past 1.09 m.
    ik_unreachable_min_distance_m: float = 1.2


def mesh_cloud(spec: ObjectSpec, config: Config, settings: BenchmarkSettings, cache_dir: Path) -> PerceivedCloud:
    """Surface cloud of ``spec``'s YCB mesh standing on the table, normals pointing away from its centroid."""
    cache_path = cache_dir / f"{spec.id}_{settings.cloud_points}_{settings.object_xy_m[0]:.3f}_{settings.object_xy_m[1]:.3f}.npz"
    if cache_path.is_file():
        cached = np.load(cache_path)
        points, normals = cached["points"], cached["normals"]
    else:
        mesh_path = spec.urdf_path.parent / "textured.obj"
        if not mesh_path.is_file():
            raise FileNotFoundError(f"{spec.id}: no mesh at {mesh_path}")
        mesh = o3d.io.read_triangle_mesh(str(mesh_path))
        mesh.compute_triangle_normals()
        o3d.utility.random.seed(0)
        sampled = mesh.sample_points_uniformly(settings.cloud_points, use_triangle_normal=True)
        # The YCB link frame is the object's bottom centre, so this stands it on the table top.
        points = np.asarray(sampled.points) + np.array([*settings.object_xy_m, config.scene.table_top_z_m])
        normals = np.asarray(sampled.normals)
        # Same orientation rule as perception: normals point away from the centroid.
        inward = ((points - points.mean(axis=0)) * normals).sum(axis=1) < 0
        normals[inward] *= -1
        cache_dir.mkdir(parents=True, exist_ok=True)
        np.savez(cache_path, points=points, normals=normals)
    return PerceivedCloud(
        points_world=torch.as_tensor(points, dtype=torch.float32),
        normals_world=torch.as_tensor(normals, dtype=torch.float32),
        view_index=torch.zeros(len(points), dtype=torch.int64),
        crop_rgb=np.zeros((1, 1, 3), dtype=np.uint8),
        cameras=[],
        object_id=spec.id,
        object_position_world=np.array([*settings.object_xy_m, config.scene.table_top_z_m]),
        object_quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]),
    )


def _median(values: list[float]) -> float:
    return float(statistics.median(values))


def _stage_seconds(times: PlanStageTimes, stage: str) -> float:
    return getattr(times, f"{stage}_s")


def benchmark_object(cloud: PerceivedCloud, config: Config, settings: BenchmarkSettings) -> list[dict[str, Any]]:
    rows = []
    for n_pairs in settings.pairs:
        pair_config = config.override("planner", n_pairs=n_pairs)
        plan(cloud, pair_config, seed=0)  # warm-up: IK chain build, allocator
        totals, stages, counts = [], {stage: [] for stage in STAGES}, {}
        ik_targets = []
        for repeat in range(settings.repeats):
            start = time.perf_counter()
            result = plan(cloud, pair_config, seed=repeat)
            totals.append(time.perf_counter() - start)
            for stage in STAGES:
                stages[stage].append(_stage_seconds(result.times, stage))
            ik_targets.append(result.times.ik_targets)
            counts = result.counts.as_dict()
        batched_s = _median(totals)
        reference_s = None
        if n_pairs <= settings.reference_max_pairs:
            start = time.perf_counter()
            # Drawn inside the timing, as the batched plan draws its own.
            plan_reference(cloud, pair_config, sample_inputs(cloud, robot_of(pair_config), pair_config.planner, 0))
            reference_s = time.perf_counter() - start
        rows.append(
            {
                "object": cloud.object_id,
                "pairs": n_pairs,
                "batched_plan_s": batched_s,
                "reference_plan_s": reference_s,
                "speedup": None if reference_s is None else reference_s / batched_s,
                "candidates_per_s": n_pairs / batched_s,
                "stage_median_s": {stage: _median(values) for stage, values in stages.items()},
                "ik_targets_median": _median(ik_targets),
                "counts_last_repeat": counts,
            }
        )
    return rows


def benchmark_plan_batch(
    clouds: list[PerceivedCloud], config: Config, batch_sizes: tuple[int, ...] = (1, 4, 16), repeats: int = 5
) -> list[dict[str, Any]]:
    """Per batch size B, B single ``plan`` calls against one ``plan_batch`` call on the same B clouds.

    Cloud i of a batch is ``clouds[i % len(clouds)]`` with seed i, in both. Each repeat times the
    singles and then the batch, so a load that drifts over the run weighs on both alike. Returns per
    B the medians over ``repeats`` of the seconds per cloud of each (``singles_per_cloud_s``,
    ``batch_per_cloud_s``), their ``ratio`` (batch over singles), and per stage (``STAGES``) the
    medians of the stage's seconds per cloud, summed over the singles (``singles_stage_per_cloud_s``)
    and in the batch (``batch_stage_per_cloud_s``).
    """
    rows = []
    for batch_size in batch_sizes:
        batch = [clouds[index % len(clouds)] for index in range(batch_size)]
        seeds = list(range(batch_size))
        plan_batch(batch, config, seeds)  # warm-up: IK chain build, allocator
        singles, batched = [], []
        singles_stages, batch_stages = {stage: [] for stage in STAGES}, {stage: [] for stage in STAGES}
        for _ in range(repeats):
            stage_sums = dict.fromkeys(STAGES, 0.0)
            start = time.perf_counter()
            for cloud, seed in zip(batch, seeds):
                times = plan(cloud, config, seed=seed).times
                for stage in STAGES:
                    stage_sums[stage] += _stage_seconds(times, stage)
            singles.append((time.perf_counter() - start) / batch_size)
            start = time.perf_counter()
            times = plan_batch(batch, config, seeds)[0].times
            batched.append((time.perf_counter() - start) / batch_size)
            for stage in STAGES:
                singles_stages[stage].append(stage_sums[stage] / batch_size)
                batch_stages[stage].append(_stage_seconds(times, stage) / batch_size)
        singles_s, batch_s = _median(singles), _median(batched)
        rows.append(
            {
                "batch_size": batch_size,
                "objects": [cloud.object_id for cloud in batch],
                "pairs": config.planner.n_pairs,
                "repeats": repeats,
                "singles_per_cloud_s": singles_s,
                "batch_per_cloud_s": batch_s,
                "ratio": batch_s / singles_s,
                "singles_stage_per_cloud_s": {stage: _median(values) for stage, values in singles_stages.items()},
                "batch_stage_per_cloud_s": {stage: _median(values) for stage, values in batch_stages.items()},
            }
        )
    return rows


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
    seconds = _median(durations)
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


def benchmark_world(spec: ObjectSpec, config: Config, runs: int) -> dict[str, Any]:
    """Medians over ``runs`` trials of one object: scene reset (with settling), capture (three views,
    merge, normals, crop), planning on the captured cloud, and one executed attempt (the best GO grasp)."""
    from .execution import execute_ranked
    from .perception import capture
    from .scene import Scene

    timings: dict[str, list[float]] = {"reset_s": [], "capture_s": [], "plan_s": [], "attempt_s": []}
    successes = 0
    with Scene(config) as scene:
        for trial in range(runs):
            start = time.perf_counter()
            scene.reset(spec, trial)
            timings["reset_s"].append(time.perf_counter() - start)
            start = time.perf_counter()
            cloud = capture(scene, config)
            timings["capture_s"].append(time.perf_counter() - start)
            start = time.perf_counter()
            candidates = plan(cloud, config, seed=trial).candidates
            timings["plan_s"].append(time.perf_counter() - start)
            if len(candidates) == 0:
                continue
            start = time.perf_counter()
            (attempt,) = execute_ranked(scene, config, candidates[:1])
            timings["attempt_s"].append(time.perf_counter() - start)
            successes += attempt.success
    return {
        "object": spec.id,
        "runs": runs,
        **{name: _median(values) if values else None for name, values in timings.items()},
        "first_attempt_success": successes / max(1, len(timings["attempt_s"])),
    }


def worker_memory(workers_file: Path, early_unit: int = 50) -> dict[str, Any]:
    """Each worker's resident memory at its ``early_unit``-th unit and at its last, from a run's ``workers.jsonl``.

    Growth is the last unit's RSS over the early one's, in percent (None for a worker that ran fewer units);
    a worker's rate is 1 / its median unit time; the run's rate is units over the span from the first
    report to the last."""
    lines = [json.loads(line) for line in workers_file.read_text().splitlines() if line.strip()]
    by_worker: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for line in lines:
        by_worker.setdefault((line["node"], line["pid"]), []).append(line)
    workers = []
    for (node, pid), reports in sorted(by_worker.items()):
        reports.sort(key=lambda report: report["units_done"])
        early = next((report for report in reports if report["units_done"] == early_unit), None)
        last = reports[-1]
        workers.append({
            "node": node, "pid": pid, "units": last["units_done"],
            "rss_early_bytes": early["rss_bytes"] if early else None, "rss_last_bytes": last["rss_bytes"],
            "growth_percent": 100.0 * (last["rss_bytes"] / early["rss_bytes"] - 1.0) if early else None,
            "units_per_s": 1.0 / _median([report["unit_s"] for report in reports]),
        })
    times = sorted(line["time"] for line in lines)
    span_s = times[-1] - times[0] if len(times) > 1 else 0.0
    return {
        "early_unit": early_unit,
        "units": len(lines),
        "workers": workers,
        "median_worker_units_per_s": _median([worker["units_per_s"] for worker in workers]) if workers else None,
        "run_units_per_s": (len(lines) - 1) / span_s if span_s > 0 else None,
    }
