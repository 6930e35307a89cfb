"""Planner benchmark: batched planner versus the loop reference on clouds of real YCB objects.

Clouds come from the YCB meshes (Open3D uniform surface sampling with triangle normals, placed
upright on the table at a fixed pose) rather than from perception, so the benchmark measures the
planner alone; they are cached as ``.npz`` files outside the repository.
"""
from __future__ import annotations

import dataclasses
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ._open3d import o3d
from .config import Config
from .ik import PandaIK
from .objects import ObjectSpec
from .planner import plan, screen_candidates
from .reference import plan_reference
from .types import PerceivedCloud

STAGES = ("sampling", "antipodal", "frames_volume", "hand_sweep", "ik", "motion")


@dataclasses.dataclass
class BenchmarkSettings:
    pairs: tuple[int, ...]
    repeats: int
    reference_max_pairs: int  # the loop reference runs (once) only up to this many pairs
    cloud_points: int
    object_xy_m: tuple[float, float]
    ik_targets: int


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
        table_top_z_m=config.scene.table_top_z_m,
    )


def _median(values: list[float]) -> float:
    return float(statistics.median(values))


def benchmark_object(cloud: PerceivedCloud, config: Config, settings: BenchmarkSettings) -> list[dict[str, Any]]:
    rows = []
    for n_pairs in settings.pairs:
        pair_config = config.override("planner", n_pairs=n_pairs)
        plan(cloud, pair_config, seed=0)  # warm-up: IK chain build, allocator
        totals, stages, counts = [], {stage: [] for stage in STAGES}, {}
        ik_targets = []
        for repeat in range(settings.repeats):
            timings: dict[str, float] = {}
            start = time.perf_counter()
            candidates = plan(cloud, pair_config, seed=repeat, timings=timings)
            totals.append(time.perf_counter() - start)
            for stage in STAGES:
                stages[stage].append(timings[stage])
            ik_targets.append(timings["ik_targets"])
            counts = candidates.counts
        batched_s = _median(totals)
        reference_s = None
        if n_pairs <= settings.reference_max_pairs:
            start = time.perf_counter()
            plan_reference(cloud, pair_config, seed=0)
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


def benchmark_ik(clouds: list[PerceivedCloud], config: Config, settings: BenchmarkSettings) -> dict[str, Any]:
    """Throughput of one batched IK call on grasp poses around the objects (top-down-first approaches)."""
    screened = screen_candidates(clouds, config.override("planner", n_pairs=50_000), [0] * len(clouds))
    usable_rows, usable_slots = screened.usable.nonzero(as_tuple=True)
    pick = torch.randperm(len(usable_rows), generator=torch.Generator().manual_seed(0))[: settings.ik_targets]
    positions = screened.centre_world[usable_rows[pick]]
    rotations = screened.rotation_world[usable_rows[pick], usable_slots[pick]]
    ik = PandaIK(config.planner, config.scene.robot_base_xyz_m)
    ik.solve(positions[:10], rotations[:10])
    durations, success = [], 0.0
    for _ in range(settings.repeats):
        start = time.perf_counter()
        result = ik.solve(positions, rotations)
        durations.append(time.perf_counter() - start)
        success = float(result.success.float().mean())
    feasible = (result.position_error_m < config.planner.ik_pos_tolerance_m) & (result.s_reach >= config.planner.min_reach)
    return {
        "targets": len(positions),
        "seconds_median": _median(durations),
        "targets_per_s": len(positions) / _median(durations),
        "success_rate": success,
        "feasible_rate": float(feasible.float().mean()),
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
            candidates = plan(cloud, config, seed=trial)
            timings["plan_s"].append(time.perf_counter() - start)
            if len(candidates) == 0:
                continue
            start = time.perf_counter()
            (attempt,) = execute_ranked(scene, config, candidates, [0])
            timings["attempt_s"].append(time.perf_counter() - start)
            successes += attempt.success
    return {
        "object": spec.id,
        "runs": runs,
        **{name: _median(values) if values else None for name, values in timings.items()},
        "first_attempt_success": successes / max(1, len(timings["attempt_s"])),
    }
