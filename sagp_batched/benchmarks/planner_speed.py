"""Planner benchmark: batched planner versus the loop reference on clouds of real YCB objects.

Clouds come from the YCB meshes (Open3D uniform surface sampling with triangle normals, placed
upright on the table at a fixed pose) rather than from perception, so the benchmark measures the
planner alone; they are cached as ``.npz`` files outside the repository. The IK's own benchmark
is ``ik_benchmark``.
"""
from __future__ import annotations

import dataclasses
import json
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .._open3d import o3d
from ..config import Config
from ..planning import plan, plan_batch, sample_inputs
from ..planning.reference import plan_reference
from ..planning.stages import STAGES
from ..robot.description import robot_of
from ..types import PerceivedCloud
from ..world.objects import ObjectSpec
from .stage_profile import PROFILED_STAGES, SEARCH, profile_stages


# Where the benchmark stands its objects on the table (world x, y), in front of the robot.
BENCH_OBJECT_XY_M = (0.55, 0.0)


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
    # Profile one more plan per row under torch.profiler: operators and their time per stage.
    profile_stages: bool = False


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


def median(values: list[float]) -> float:
    return float(statistics.median(values))


def benchmark_object(cloud: PerceivedCloud, config: Config, settings: BenchmarkSettings) -> list[dict[str, Any]]:
    rows = []
    for n_pairs in settings.pairs:
        pair_config = config.override("planner", n_pairs=n_pairs)
        start = time.perf_counter()
        plan(cloud, pair_config, seed=0)  # warm-up: IK chain build, allocator, compiled kernels
        first_plan_s = time.perf_counter() - start
        totals, stages, counts = [], {stage: [] for stage in PROFILED_STAGES}, {}
        ik_targets = []
        for repeat in range(settings.repeats):
            start = time.perf_counter()
            result = plan(cloud, pair_config, seed=repeat)
            totals.append(time.perf_counter() - start)
            for stage, seconds in result.times.stage_seconds().items():
                stages[stage].append(seconds)
            stages[SEARCH].append(totals[-1] - sum(result.times.stage_seconds().values()))
            ik_targets.append(result.times.ik_targets)
            counts = result.counts.as_dict()
        batched_s = median(totals)
        reference_s = None
        if n_pairs <= settings.reference_max_pairs:
            start = time.perf_counter()
            # Drawn inside the timing, as the batched plan draws its own.
            plan_reference(cloud, pair_config, sample_inputs(cloud, robot_of(pair_config), pair_config.planner, pair_config.memory, 0))
            reference_s = time.perf_counter() - start
        rows.append(
            {
                "object": cloud.object_id,
                "pairs": n_pairs,
                "device": pair_config.planner.device,
                "search": pair_config.planner.search,
                "compile": pair_config.planner.compile,
                "first_plan_s": first_plan_s,
                "batched_plan_s": batched_s,
                "reference_plan_s": reference_s,
                "speedup": None if reference_s is None else reference_s / batched_s,
                "candidates_per_s": n_pairs / batched_s,
                "stage_median_s": {stage: median(values) for stage, values in stages.items()},
                "ik_targets_median": median(ik_targets),
                "stage_items_last_repeat": result.times.stage_items(),
                "stage_profile": profile_stages([cloud], pair_config, [0]) if settings.profile_stages else None,
                "counts_last_repeat": counts,
            }
        )
    return rows


def benchmark_plan_batch(
    clouds: list[PerceivedCloud], config: Config, batch_sizes: tuple[int, ...] = (1, 4, 16), repeats: int = 5, profile: bool = False
) -> list[dict[str, Any]]:
    """Per batch size B, B single ``plan`` calls against one ``plan_batch`` call on the same B clouds.

    Cloud i of a batch is ``clouds[i % len(clouds)]`` with seed i, in both. Each repeat times the
    singles and then the batch, so a load that drifts over the run weighs on both alike. Returns per
    B the medians over ``repeats`` of the seconds per cloud of each (``singles_per_cloud_s``,
    ``batch_per_cloud_s``), their ``ratio`` (batch over singles), and per stage (``STAGES``) the
    medians of the stage's seconds per cloud, summed over the singles (``singles_stage_per_cloud_s``)
    and in the batch (``batch_stage_per_cloud_s``); with ``profile``, ``profile_stages`` of the
    singles (summed) and of the batch (``singles_profile``, ``batch_profile``).
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
                for stage, seconds in plan(cloud, config, seed=seed).times.stage_seconds().items():
                    stage_sums[stage] += seconds
            singles.append((time.perf_counter() - start) / batch_size)
            start = time.perf_counter()
            times = plan_batch(batch, config, seeds)[0].times
            batched.append((time.perf_counter() - start) / batch_size)
            for stage, seconds in times.stage_seconds().items():
                singles_stages[stage].append(stage_sums[stage] / batch_size)
                batch_stages[stage].append(seconds / batch_size)
        singles_s, batch_s = median(singles), median(batched)
        rows.append(
            {
                "batch_size": batch_size,
                "objects": [cloud.object_id for cloud in batch],
                "pairs": config.planner.n_pairs,
                "repeats": repeats,
                "singles_per_cloud_s": singles_s,
                "batch_per_cloud_s": batch_s,
                "ratio": batch_s / singles_s,
                "singles_stage_per_cloud_s": {stage: median(values) for stage, values in singles_stages.items()},
                "batch_stage_per_cloud_s": {stage: median(values) for stage, values in batch_stages.items()},
                "singles_profile": profile_stages(batch, config, seeds, singles=True) if profile else None,
                "batch_profile": profile_stages(batch, config, seeds) if profile else None,
            }
        )
    return rows


def benchmark_world(spec: ObjectSpec, config: Config, runs: int) -> dict[str, Any]:
    """Medians over ``runs`` trials of one object: scene reset (with settling), capture (three views,
    merge, normals, crop), planning on the captured cloud, and one executed attempt (the best GO grasp)."""
    from ..execution.pick import execute_ranked
    from ..world.perception import capture
    from ..world.scene import Scene

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
        **{name: median(values) if values else None for name, values in timings.items()},
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
            "units_per_s": 1.0 / median([report["unit_s"] for report in reports]),
        })
    times = sorted(line["time"] for line in lines)
    span_s = times[-1] - times[0] if len(times) > 1 else 0.0
    return {
        "early_unit": early_unit,
        "units": len(lines),
        "workers": workers,
        "median_worker_units_per_s": median([worker["units_per_s"] for worker in workers]) if workers else None,
        "run_units_per_s": (len(lines) - 1) / span_s if span_s > 0 else None,
    }
