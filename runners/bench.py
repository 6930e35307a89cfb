"""Benchmark the batched planner against the loop reference on YCB object clouds.

    python -m runners.bench --json OUT.json [--objects 025_mug,003_cracker_box] [--pairs 5000,50000,500000]
        [--repeats 5] [--ik-targets 2000] [--ik-unreachable 200] [--objects-dir DIR] [--cache-dir DIR] [--threads 1[,2]]
        [--batch-sizes 1,4,16] [--batch-objects ID,...] [--batch-pairs 5000] [--compile false,true] [--devices cpu,cuda]
        [--profile-stages] [--compile-start]

    python -m runners.bench --json OUT.json --collision-designs [--objects ...] [--pairs 5000] [--repeats 5]

``--threads 1,2`` times the planner and the IK at each torch thread count in turn, in one run, so
figures for one core and for several compare on the same clouds and targets.

``--compile false,true`` times the planner eager and with ``[planner] compile`` on, in turn at each
thread count (the loop reference once per thread count); ``--compile-start`` measures, in fresh
processes, the first plan eager, compiled with an empty inductor cache and compiled from the cache.
``--devices cpu,cuda`` times each compile mode on each ``[planner] device`` (the clouds stay on the
CPU: a plan's time includes moving them there and its results back, which waits for the device);
``--searches lookahead,blocks`` each ``[planner] search`` likewise.

``--profile-stages`` profiles one more plan per object and pair count (and per batch comparison,
the singles and the batch) with ``torch.profiler`` and prints, per stage, its median time, the
operators it called, their profiled time and its work items.

``--batch-sizes 1,4,16`` times, per batch size B, B single plans against one ``plan_batch`` on the
same B clouds (at the first thread count), per cloud and per stage; 0 or empty (the default) skips it.

    python -m runners.bench --json OUT.json --ray-address HOST:PORT [--study-trials 500] [--study-object ID]
        [--workers 2] [--profile ci] [--study-out DIR]

``--collision-designs`` measures instead the volume and swept-hand checks on one plan's screened
poses per object (at the first pair count and thread count): the exact passes against a scene field
built once per cloud and queried per pose (``collision_designs``), printed as a table.

``--ray-address`` measures Ray workers instead: a study of ``--study-trials`` trials (one object, t1,
Geometry-Only) through the study's Ray backend on that cluster, then each worker's resident memory at
its 50th unit and at its last, and the units per second.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

import torch

from sagp_batched.benchmarks.ik_speed import benchmark_ik
from sagp_batched.benchmarks.collision_designs import collision_designs_report
from sagp_batched.benchmarks.compile_start import compile_start_costs
from sagp_batched.benchmarks.verdict_agreement import agreement_report, unseen_shape_clouds
from sagp_batched.benchmarks.planner_speed import (
    BENCH_OBJECT_XY_M, BenchmarkSettings, benchmark_object, benchmark_plan_batch, benchmark_world, mesh_cloud,
)
from sagp_batched.config import PLANNER_SEARCHES, load_config
from sagp_batched.config.world import GRIPPERS
from sagp_batched.robot.description import robot_of
from sagp_batched.planning.device import device_name, planning_device
from sagp_batched.provenance import REPO_ROOT, git_revision, package_versions
from sagp_batched.runtime import DEFAULT_TORCH_THREADS, configure_torch
from sagp_batched.world.objects import embedded_ycb_dir, load_object_set


def _ycb_dir(argument: str | None) -> Path:
    """The YCB set to benchmark: --objects-dir, $SAGP_YCB_DIR, shared/ycb beside the repository, else the embedded copy."""
    for candidate in (argument, os.environ.get("SAGP_YCB_DIR"), str(REPO_ROOT.parent / "shared" / "ycb")):
        if candidate and (Path(candidate).expanduser() / "objects.json").is_file():
            return Path(candidate).expanduser()
    return embedded_ycb_dir()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", required=True, type=Path, help="where to write the results")
    parser.add_argument("--objects", default="025_mug,003_cracker_box,005_tomato_soup_can", help="comma-separated YCB ids")
    parser.add_argument("--pairs", default="5000,50000,500000", help="comma-separated sampled pair counts")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--reference-max-pairs", type=int, default=50_000, help="largest pair count the loop reference is run at (once)")
    parser.add_argument("--ik-targets", type=int, default=2000, help="reachable IK targets (FK of random in-limit joints, above the table); 0 skips the IK benchmark")
    parser.add_argument("--ik-unreachable", type=int, default=200, help="IK targets beyond the arm's reach (false-reachable rate)")
    parser.add_argument("--cloud-points", type=int, default=3000)
    parser.add_argument("--objects-dir", default=None)
    parser.add_argument("--cache-dir", type=Path, default=Path("~/.cache/sagp_batched/clouds").expanduser())
    parser.add_argument("--profile", default=None)
    parser.add_argument("--gripper", choices=GRIPPERS, help="the [planner] gripper; one no arm carries skips the loop reference, IK and world runs")
    parser.add_argument("--threads", default=str(DEFAULT_TORCH_THREADS), help="comma-separated torch thread counts, each timed in turn")
    parser.add_argument("--world-object", default="005_tomato_soup_can", help="object of the PyBullet timing runs")
    parser.add_argument("--world-runs", type=int, default=20, help="trials timed in PyBullet (reset, capture, plan, attempt); 0 skips")
    parser.add_argument("--batch-sizes", default="", help="comma-separated batch sizes B: B single plans against one plan_batch; 0 or empty skips")
    parser.add_argument("--batch-objects", default=None, help="comma-separated YCB ids the batches cycle through (default: the set's first, as many as the largest B)")
    parser.add_argument("--batch-pairs", type=int, default=5000, help="sampled pairs per cloud in the batch comparison")
    parser.add_argument("--compile", default="false", help="comma-separated [planner] compile modes (false, true), each timed in turn")
    parser.add_argument("--devices", default="cpu", help="comma-separated [planner] devices (cpu, cuda), each timed in turn with every compile mode")
    parser.add_argument("--searches", default="lookahead", help="comma-separated [planner] searches (lookahead, blocks), each timed in turn")
    parser.add_argument("--compile-start", action="store_true", help="first plans of fresh processes: eager, compiled cold, compiled from the cache")
    parser.add_argument("--profile-stages", action="store_true", help="per stage: operators called and their profiled time (torch.profiler)")
    parser.add_argument("--verdict-agreement", type=int, default=0, metavar="N",
                        help="the screens' verdicts against their exhaustive references on the --objects clouds and N unseen shapes; 0 skips")
    parser.add_argument("--collision-designs", action="store_true", help="measure the collision checks' designs on the screened poses instead")
    _add_ray_memory_arguments(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.ray_address is not None:
        return _ray_worker_memory(args)
    thread_counts = _counts(parser, "--threads", args.threads)
    batch_sizes = _counts(parser, "--batch-sizes", args.batch_sizes, skippable=True)
    compile_modes = [mode == "true" for mode in _listed(parser, "--compile", args.compile, ("false", "true"))]
    searches = _listed(parser, "--searches", args.searches, PLANNER_SEARCHES)
    # Each planner mode is a set of [planner] settings, timed in turn: device, search, compile.
    modes = [{"device": device, "search": search, "compile": compile_}
             for device in _devices(parser, args.devices) for search in searches for compile_ in compile_modes]

    configure_torch(thread_counts[0])
    config = load_config(args.profile, overrides={"planner": {"gripper": args.gripper}} if args.gripper else None)
    if not robot_of(config).gripper_mounted:
        print(f"gripper {config.planner.gripper}: no arm carries it, so the loop reference, the IK and the world runs are skipped")
        args.reference_max_pairs, args.ik_targets, args.world_runs = 0, 0, 0
    object_set = load_object_set(_ycb_dir(args.objects_dir))
    settings = BenchmarkSettings(
        pairs=tuple(int(p) for p in args.pairs.split(",")),
        repeats=args.repeats,
        reference_max_pairs=args.reference_max_pairs,
        cloud_points=args.cloud_points,
        object_xy_m=BENCH_OBJECT_XY_M,
        ik_targets=args.ik_targets,
        ik_unreachable_targets=args.ik_unreachable,
        profile_stages=args.profile_stages,
    )
    clouds = [mesh_cloud(object_set.get(object_id.strip()), config, settings, args.cache_dir) for object_id in args.objects.split(",")]
    if args.collision_designs:
        report = collision_designs_report(clouds, config.override("planner", n_pairs=settings.pairs[0]), args.repeats)
        return _written(args.json, {**report, "provenance": _provenance(thread_counts, modes, settings)})
    results, ik = _planner_and_ik_sections(config, settings, clouds, thread_counts, modes)
    configure_torch(thread_counts[0])
    print(f"reference: run once per pair count (and thread count) up to {settings.reference_max_pairs} pairs; no extrapolation")
    plan_batch_rows = _plan_batch_section(args, batch_sizes, config, object_set, settings, thread_counts, modes) if batch_sizes else None
    configure_torch(thread_counts[0])
    compile_start = _compile_start_section(args, settings, clouds[0].object_id, thread_counts[0]) if args.compile_start else None
    world = _world_section(args, config, object_set, thread_counts[0]) if args.world_runs > 0 else None
    agreement = None
    if args.verdict_agreement > 0:
        agreement = agreement_report(clouds + unseen_shape_clouds(config, args.verdict_agreement, args.cloud_points, BENCH_OBJECT_XY_M), config)
    report = {
        "results": results,
        "ik": ik,
        "world": world,
        "plan_batch": None if plan_batch_rows is None else {"threads": thread_counts, "modes": modes, "rows": plan_batch_rows},
        "compile_start": compile_start,
        "verdict_agreement": agreement,
        "provenance": _provenance(thread_counts, modes, settings),
    }
    return _written(args.json, report)


def _provenance(thread_counts: list[int], modes: list[dict], settings: BenchmarkSettings) -> dict:
    return {
        "torch": torch.__version__, "threads": thread_counts, "devices": {mode["device"]: device_name(mode["device"]) for mode in modes},
        "git": git_revision(), "packages": package_versions(), "python": sys.version.split()[0], "settings": dataclasses.asdict(settings),
    }


def _written(path: Path, report: dict) -> int:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2, default=str))
    return 0


def _planner_and_ik_sections(
    config, settings: BenchmarkSettings, clouds: list, thread_counts: list[int], modes: list[dict]
) -> tuple[list[dict], list[dict]]:
    """At each thread count in turn, the planner in each mode (its [planner] settings) against the loop reference
    (run in the first mode, its time shared) on every cloud (one printed line per pair count), then
    the IK unless ``settings.ik_targets`` is 0; (planner rows, IK rows)."""
    results, ik = [], []
    for threads in thread_counts:
        configure_torch(threads)
        for cloud in clouds:
            reference_s = {}
            for index, mode in enumerate(modes):
                mode_settings = settings if index == 0 else dataclasses.replace(settings, reference_max_pairs=0)
                for row in benchmark_object(cloud, config.override("planner", **mode), mode_settings):
                    row["threads"], row["gripper"] = threads, config.planner.gripper
                    reference_s.setdefault(row["pairs"], row["reference_plan_s"])
                    row["reference_plan_s"] = reference_s[row["pairs"]]
                    row["speedup"] = None if row["reference_plan_s"] is None else row["reference_plan_s"] / row["batched_plan_s"]
                    results.append(row)
                    _print_planner_row(row)
        if settings.ik_targets > 0:
            ik.append({"threads": threads, **benchmark_ik(config, settings)})
            _print_ik(ik[-1])
    return results, ik


def _print_planner_row(row: dict) -> None:
    reference = "not run" if row["reference_plan_s"] is None else f"{row['reference_plan_s']:.3f} s (x{row['speedup']:.1f})"
    stages = " ".join(f"{k}={v * 1e3:.1f}ms" for k, v in row["stage_median_s"].items())
    print(
        f"{row['object']:>22} pairs={row['pairs']:>7} device={row['device']} search={row['search']} compile={'on' if row['compile'] else 'off'} "
        f"threads={row['threads']} "
        f"plan={row['batched_plan_s']:.3f} s ({row['candidates_per_s']:.0f} pairs/s, first {row['first_plan_s']:.2f} s) "
        f"reference={reference} | {stages} | {row['counts_last_repeat']}",
        flush=True,
    )
    if row["stage_profile"] is not None:
        _print_stage_table(row["stage_profile"], row["stage_median_s"], row["stage_items_last_repeat"])


def _print_stage_table(profile: dict, seconds: dict, items: dict, per: int = 1) -> None:
    """Per stage: median ms (``seconds``), operators called and their profiled ms (``profile``,
    divided by ``per``, the clouds it covers), and work items (``items``)."""
    print(f"{'':>8}{'stage':<14}{'ms':>8}{'ops':>8}{'in ops ms':>11}{'items':>9}")
    for stage, profiled in profile.items():
        stage_ms = "" if seconds.get(stage) is None else f"{seconds[stage] * 1e3:.1f}"
        stage_items = "" if items.get(stage) is None else f"{items[stage]}"
        print(f"{'':>8}{stage:<14}{stage_ms:>8}{profiled['ops'] // per:>8}{profiled['op_s'] * 1e3 / per:>11.1f}{stage_items:>9}")
    total_ms = "" if any(seconds.get(stage) is None for stage in profile) else f"{sum(seconds[stage] for stage in profile) * 1e3:.1f}"
    total_ops, total_op_ms = sum(p["ops"] for p in profile.values()) // per, sum(p["op_s"] for p in profile.values()) * 1e3 / per
    print(f"{'':>8}{'plan':<14}{total_ms:>8}{total_ops:>8}{total_op_ms:>11.1f}")


def _world_section(args: argparse.Namespace, config, object_set, threads: int) -> dict:
    """``benchmark_world``'s trials in PyBullet, printed as one line of medians."""
    world = benchmark_world(object_set.get(args.world_object), config, args.world_runs)
    print(
        f"PyBullet, {world['object']}, {threads} threads, medians of {world['runs']} trials: reset {world['reset_s']:.3f} s, "
        f"capture (3 views) {world['capture_s']:.3f} s, plan {world['plan_s']:.3f} s, "
        f"attempt {world['attempt_s']:.3f} s, first-attempt success {world['first_attempt_success']:.0%}"
    )
    return world


# --- Ray workers' memory over a long study ----------------------------------------------------------

RAY_MEMORY_EARLY_UNIT = 50


def _add_ray_memory_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ray-address", default=None, help="measure Ray workers' memory over a study on this cluster (host:port) instead")
    parser.add_argument("--study-trials", type=int, default=500, help="trials of the --ray-address study")
    parser.add_argument("--study-object", default="005_tomato_soup_can", help="object of the --ray-address study")
    parser.add_argument("--workers", type=int, default=2, help="Ray workers of the --ray-address study")
    parser.add_argument("--study-out", type=Path, default=None, help="run directory of the --ray-address study (default: a fresh temporary one)")


def _ray_worker_memory(args: argparse.Namespace) -> int:
    import tempfile
    import time

    from sagp_batched.benchmarks.planner_speed import worker_memory
    from sagp_batched.config import ConfigError
    from sagp_batched.world.objects import ObjectLoadError, ObjectSetError, UnknownObjectError
    from sagp_batched.preflight import PreflightError, check_ray_address, check_ray_installed
    from sagp_batched.run_directory import WORKERS_FILE
    from sagp_batched.study.study_run import run_study

    out = args.study_out or Path(tempfile.mkdtemp(prefix="sagp_ray_memory_"))
    objects_dir = _ycb_dir(args.objects_dir)
    try:
        check_ray_installed()
        check_ray_address(args.ray_address, flag="--ray-address")
        config = load_config(args.profile or "ci", overrides={"run": {
            "objects": [args.study_object], "tasks": ["t1"], "methods": ["go"], "n_trials": args.study_trials,
            "backend": "ray", "ray_address": args.ray_address, "workers": args.workers, "out": str(out),
            "objects_dir": str(objects_dir), "export_grasps": False, "save_frames": False,
        }})
        objects = load_object_set(objects_dir)
        configure_torch()
        start = time.perf_counter()
        result = run_study(config, objects, config.run.methods, progress=False)
        wall_s = time.perf_counter() - start
    except (ConfigError, PreflightError, ObjectSetError, ObjectLoadError, UnknownObjectError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    memory = worker_memory(out / WORKERS_FILE, RAY_MEMORY_EARLY_UNIT)
    errors = sum(record["error"] is not None for record in result.records)
    print(f"Ray workers, {args.study_object} t1 go, {result.new_records} trials in {wall_s:.0f} s ({errors} errors), run directory {out}")
    for worker in memory["workers"]:
        early = "n/a" if worker["rss_early_bytes"] is None else f"{worker['rss_early_bytes'] / 2**20:.0f} MiB"
        growth = "n/a" if worker["growth_percent"] is None else f"{worker['growth_percent']:+.1f} %"
        print(f"  worker {worker['node']}:{worker['pid']}: {worker['units']} units, RSS at unit {RAY_MEMORY_EARLY_UNIT} {early}, "
              f"at its last {worker['rss_last_bytes'] / 2**20:.0f} MiB ({growth}), {worker['units_per_s']:.2f} units/s")
    run_rate = memory["run_units_per_s"]
    print(f"  median worker rate {memory['median_worker_units_per_s']:.2f} units/s; whole run "
          f"{'n/a' if run_rate is None else f'{run_rate:.2f}'} units/s")
    report = {"ray_memory": {**memory, "trials": result.new_records, "errors": errors, "wall_s": wall_s, "run_directory": str(out),
                             "object": args.study_object, "profile": args.profile or "ci", "address": args.ray_address},
              "provenance": {"git": git_revision(), "packages": package_versions(), "python": sys.version.split()[0]}}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2, default=str))
    return 0


def _counts(parser: argparse.ArgumentParser, flag: str, text: str, skippable: bool = False) -> list[int]:
    """The comma list ``text`` of ``flag`` as positive whole numbers; where ``skippable``, 0 or nothing is none."""
    if skippable and text.strip() in ("", "0"):
        return []
    try:
        counts = [int(part) for part in text.split(",")]
    except ValueError:
        counts = []
    if not counts or min(counts) < 1:
        parser.error(f"{flag} takes positive whole numbers separated by commas{' (0 or empty skips)' if skippable else ''}, got {text!r}")
    return counts


def _plan_batch_section(
    args: argparse.Namespace, batch_sizes: list[int], config, object_set, settings: BenchmarkSettings, thread_counts: list[int],
    modes: list[dict],
) -> list[dict]:
    """``benchmark_plan_batch`` on the --batch-objects clouds at each thread count and mode ([planner] settings),
    one printed line per batch size (and with --profile-stages, the per-cloud stage tables)."""
    batch_ids = args.batch_objects.split(",") if args.batch_objects else list(object_set.ids)[: max(batch_sizes)]
    clouds = [mesh_cloud(object_set.get(object_id.strip()), config, settings, args.cache_dir) for object_id in batch_ids]
    rows = []
    for threads in thread_counts:
        configure_torch(threads)
        for mode in modes:
            batch_config = config.override("planner", n_pairs=args.batch_pairs, **mode)
            for row in benchmark_plan_batch(clouds, batch_config, tuple(batch_sizes), args.repeats, settings.profile_stages):
                rows.append({**row, "threads": threads, **mode})
                _print_plan_batch_row(rows[-1])
    return rows


def _print_plan_batch_row(row: dict) -> None:
    stages = " ".join(
        f"{stage}={row['singles_stage_per_cloud_s'][stage] * 1e3:.1f}/{row['batch_stage_per_cloud_s'][stage] * 1e3:.1f}ms"
        for stage in row["singles_stage_per_cloud_s"]
    )
    print(
        f"plan_batch B={row['batch_size']:>2} pairs={row['pairs']} device={row['device']} search={row['search']} threads={row['threads']} "
        f"compile={'on' if row['compile'] else 'off'}: "
        f"singles {row['singles_per_cloud_s'] * 1e3:.1f} ms/cloud, batch {row['batch_per_cloud_s'] * 1e3:.1f} ms/cloud, "
        f"ratio {row['ratio']:.2f} | per cloud, singles/batch: {stages}",
        flush=True,
    )
    for name in ("singles", "batch"):
        if row[f"{name}_profile"] is not None:
            print(f"      {name}, per cloud:")
            _print_stage_table(row[f"{name}_profile"], row[f"{name}_stage_per_cloud_s"], {}, row["batch_size"])


def _compile_start_section(args: argparse.Namespace, settings: BenchmarkSettings, object_id: str, threads: int) -> dict:
    """``compile_start_costs`` for ``object_id`` at the first pair count, printed as one line."""
    pairs = settings.pairs[0]
    costs = compile_start_costs(object_id, _ycb_dir(args.objects_dir), args.cache_dir, settings.cloud_points, pairs, threads)
    print(f"compile start, {object_id}, {pairs} pairs, {threads} threads, fresh processes: " + ", ".join(
        f"{case} first plan {cost['first_plan_s']:.2f} s (second {cost['second_plan_s']:.3f} s, process {cost['process_s']:.1f} s)"
        for case, cost in costs.items()
    ), flush=True)
    return {"object": object_id, "pairs": pairs, "threads": threads, **costs}


def _listed(parser: argparse.ArgumentParser, flag: str, text: str, known: tuple[str, ...]) -> list[str]:
    """The comma list ``text`` of ``flag``, each entry one of ``known``; anything else is one error line."""
    parts = [part.strip().lower() for part in text.split(",") if part.strip()]
    if not parts or any(part not in known for part in parts):
        parser.error(f"{flag} takes {' and/or '.join(known)} separated by commas, got {text!r}")
    return parts


def _devices(parser: argparse.ArgumentParser, text: str) -> list[str]:
    """The --devices list, each checked before any plan: a device this machine lacks is one error line."""
    devices = [part.strip() for part in text.split(",") if part.strip()]
    if not devices:
        parser.error(f"--devices takes torch devices (cpu, cuda, cuda:N) separated by commas, got {text!r}")
    for device in devices:
        try:
            planning_device(load_config(None).override("planner", device=device).planner)
        except ValueError as exc:
            parser.error(f"--devices: {exc}")
    return devices


def _print_ik(ik: dict) -> None:
    print(
        f"IK ({ik['threads']} threads): {ik['reachable_targets']} reachable targets (FK of random in-limit joints, above the table), "
        f"{ik['unreachable_targets']} unreachable (>= {ik['unreachable_min_distance_from_shoulder_m']} m from the shoulder); "
        f"success = FK within {ik['pos_tolerance_m'] * 1e3:.1f} mm / {ik['rot_tolerance_rad']} rad and inside the limits"
    )
    for solver in ik["solvers"]:
        print(
            f"IK {solver['solver']:>26}: {solver['targets_per_s']:.0f} targets/s, success {solver['success_rate']:.1%} "
            f"(claimed {solver['claimed_success_rate']:.1%}), inside limits {solver['inside_limits_rate']:.1%}, "
            f"false reachable {solver['false_reachable_rate']:.1%}",
            flush=True,
        )


if __name__ == "__main__":
    raise SystemExit(main())
