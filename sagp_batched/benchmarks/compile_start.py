"""What ``[planner] compile`` costs a process before its plans pay: the first plans of fresh
processes, eager, compiled with an empty inductor cache (every kernel compiled) and compiled again
with the cache the previous process left (kernels loaded, not compiled).

Each measurement is a process of its own (``python -m sagp_batched.benchmarks.compile_start``, which
plans one benchmark cloud twice and prints its seconds as one JSON line), since a process compiles
a kernel once and keeps it.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def compile_start_costs(object_id: str, objects_dir: Path, cloud_cache_dir: Path, cloud_points: int, pairs: int, threads: int) -> dict[str, Any]:
    """Per case (``eager``, ``compile_cold``: empty inductor cache, ``compile_cached``: the cache
    the cold process left), the first plan's and a second plan's seconds of a fresh process
    planning ``object_id``'s benchmark cloud of ``cloud_points`` points (``mesh_cloud``, cached in
    ``cloud_cache_dir``) at ``pairs`` pairs on ``threads`` torch threads; each process's wall time
    from start to exit."""
    costs = {}
    with tempfile.TemporaryDirectory(prefix="sagp_inductor_") as inductor_dir:
        for case, compile_ in (("eager", False), ("compile_cold", True), ("compile_cached", True)):
            command = [sys.executable, "-m", "sagp_batched.benchmarks.compile_start", object_id, str(objects_dir), str(cloud_cache_dir),
                       str(cloud_points), str(pairs), str(threads), "--compile" if compile_ else "--eager"]
            start = time.perf_counter()
            done = subprocess.run(command, env={**os.environ, "TORCHINDUCTOR_CACHE_DIR": inductor_dir}, capture_output=True, text=True,
                                  check=True)
            costs[case] = {**json.loads(done.stdout.strip().splitlines()[-1]), "process_s": time.perf_counter() - start}
    return costs


def _main() -> None:
    parser = argparse.ArgumentParser(description="plan one benchmark cloud twice in this process; print the two plans' seconds")
    parser.add_argument("object_id")
    parser.add_argument("objects_dir", type=Path)
    parser.add_argument("cloud_cache_dir", type=Path)
    parser.add_argument("cloud_points", type=int)
    parser.add_argument("pairs", type=int)
    parser.add_argument("threads", type=int)
    parser.add_argument("--compile", dest="compile", action="store_true")
    parser.add_argument("--eager", dest="compile", action="store_false")
    args = parser.parse_args()

    from ..config import load_config
    from ..planning import plan
    from ..runtime import configure_torch
    from ..world.objects import load_object_set
    from .planner_speed import BENCH_OBJECT_XY_M, BenchmarkSettings, mesh_cloud

    configure_torch(args.threads)
    config = load_config(None).override("planner", n_pairs=args.pairs, compile=args.compile)
    settings = BenchmarkSettings(pairs=(args.pairs,), repeats=1, reference_max_pairs=0, cloud_points=args.cloud_points,
                                 object_xy_m=BENCH_OBJECT_XY_M, ik_targets=0)
    cloud = mesh_cloud(load_object_set(args.objects_dir).get(args.object_id), config, settings, args.cloud_cache_dir)
    seconds = []
    for seed in (0, 1):
        start = time.perf_counter()
        plan(cloud, config, seed=seed)
        seconds.append(time.perf_counter() - start)
    print(json.dumps({"first_plan_s": seconds[0], "second_plan_s": seconds[1]}))


if __name__ == "__main__":
    _main()
