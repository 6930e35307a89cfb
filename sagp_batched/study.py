"""The study loop: units over objects x tasks x trials, run locally, in processes, or on Ray.

Long runs lose nothing: each finished record is appended to ``trials.jsonl`` and flushed at once;
a re-run into the same directory skips finished records (a truncated last line from a killed run
is dropped and re-run); a unit that raises or times out is recorded with its error.
"""
from __future__ import annotations

import concurrent.futures
import json
import multiprocessing
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from . import provenance
from .config import Config, ConfigError, load_config
from .experiment import TrialRunner
from .records import TrialRecord, TrialUnit, record_key
from .metrics import summarise
from .objects import ObjectSet, load_object_set
from .types import METHODS, TASKS

TRIALS_FILE = "trials.jsonl"
# Settings that say how a run is executed, not what it computes: they may differ on resume.
EXECUTION_ONLY = {"out", "workers", "backend", "ray_address", "gui", "trial_timeout_s", "objects", "tasks", "methods", "n_trials", "save_frames", "export_grasps"}


class RunDirectoryMismatch(ConfigError):
    """The output directory holds a run made with different method settings."""


@dataclass
class StudyResult:
    out_dir: Path
    records: list[dict[str, Any]]
    summary: dict[str, Any]
    new_records: int
    not_run: dict[str, str] = field(default_factory=dict)


def resolve_object_ids(config: Config, objects: ObjectSet) -> list[str]:
    requested = list(config.run.objects)
    if requested in (["all"], []):
        return [spec.id for spec in objects.targets()]
    for object_id in requested:
        objects.get(object_id)  # raises UnknownObjectError naming the id
    return requested


def plan_units(config: Config, objects: ObjectSet, methods: Iterable[str]) -> list[TrialUnit]:
    methods = tuple(methods)
    for task in config.run.tasks:
        if task not in TASKS:
            raise ConfigError(f"unknown task '{task}' (known: {', '.join(TASKS)})")
    for method in methods:
        if method not in METHODS:
            raise ConfigError(f"unknown method '{method}' (known: {', '.join(METHODS)})")
    if config.run.n_trials < 1:
        raise ConfigError(f"n_trials must be at least 1, got {config.run.n_trials}")
    return [
        TrialUnit(object_id, task, trial, methods)
        for object_id in resolve_object_ids(config, objects)
        for task in config.run.tasks
        for trial in range(config.run.n_trials)
    ]


def read_records(path: Path) -> list[dict[str, Any]]:
    """Records of a trials file, last one per key kept; a torn final line is ignored."""
    if not path.exists():
        return []
    by_key: dict[tuple, dict[str, Any]] = {}
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # the line a killed run was writing: its unit is run again
        by_key[record_key(record)] = record
    return list(by_key.values())


def _method_settings(config_dict: dict[str, Any]) -> dict[str, Any]:
    settings = dict(config_dict)
    settings["run"] = {k: v for k, v in config_dict["run"].items() if k not in EXECUTION_ONLY}
    return settings


def _check_run_directory(out_dir: Path, config: Config) -> None:
    saved = out_dir / "config.json"
    if not saved.exists():
        return
    previous = json.loads(saved.read_text())
    current = json.loads(json.dumps(config.to_dict()))
    if _method_settings(previous) != _method_settings(current):
        differing = sorted(
            f"{section}.{key}"
            for section, values in _method_settings(current).items()
            for key, value in values.items()
            if _method_settings(previous).get(section, {}).get(key) != value
        )
        raise RunDirectoryMismatch(
            f"{out_dir} holds a run made with other settings ({', '.join(differing)}); "
            "choose another --out or delete that directory"
        )


class TrialWriter:
    """Appends records to trials.jsonl, flushed and synced one by one."""

    def __init__(self, path: Path):
        self._file = path.open("a", encoding="utf-8")

    def write(self, record: dict[str, Any]) -> None:
        self._file.write(json.dumps(record, sort_keys=True) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


# --- executors ---------------------------------------------------------------------------------

_WORKER_RUNNER: TrialRunner | None = None


def _init_worker(config_dict: dict[str, Any], objects_dir: str | None) -> None:
    global _WORKER_RUNNER
    from .runtime import configure_torch

    configure_torch()
    config = load_config(overrides=config_dict)
    _WORKER_RUNNER = TrialRunner(config, load_object_set(objects_dir))


def _run_unit_in_worker(unit: TrialUnit) -> list[TrialRecord]:
    records: list[TrialRecord] = []
    _WORKER_RUNNER.run_unit(unit, records.append)
    return records


def _run_inline(config: Config, objects: ObjectSet, units: list[TrialUnit], emit: Callable) -> None:
    runner = TrialRunner(config, objects)
    for unit in units:
        runner.run_unit(unit, emit)


def _run_processes(config: Config, units: list[TrialUnit], emit: Callable, objects_dir: str | None) -> None:
    # spawn: each worker gets a fresh interpreter and its own PyBullet client (fork would copy
    # the parent's torch thread pools and any open client).
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(
        max_workers=config.run.workers, mp_context=context, initializer=_init_worker,
        initargs=(config.to_dict(), objects_dir),
    ) as pool:
        futures = {pool.submit(_run_unit_in_worker, unit): unit for unit in units}
        try:
            for future in concurrent.futures.as_completed(futures):
                unit = futures[future]
                try:
                    records = future.result()
                except concurrent.futures.process.BrokenProcessPool as exc:
                    records = _crashed_unit_records(config, objects_dir, unit, exc)
                for record in records:
                    emit(record)
        except KeyboardInterrupt:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _crashed_unit_records(config: Config, objects_dir: str | None, unit: TrialUnit, exc: BaseException) -> list[TrialRecord]:
    spec = load_object_set(objects_dir).get(unit.object_id)
    return [TrialRecord.build(spec, unit, method, config, error=f"worker process died: {exc}") for method in unit.methods]


def _run_ray(config: Config, units: list[TrialUnit], emit: Callable, objects_dir: str | None) -> None:
    try:
        import ray
    except ImportError as exc:
        raise ConfigError("--backend ray needs Ray: pip install 'sagp-batched[ray]'") from exc
    started_here = not ray.is_initialized()
    if started_here:
        if config.run.ray_address:
            ray.init(address=config.run.ray_address, log_to_driver=False)
        else:
            ray.init(num_cpus=max(1, config.run.workers), include_dashboard=False, log_to_driver=False)

    @ray.remote(num_cpus=1)
    def run_unit_task(config_dict: dict[str, Any], objects_dir_: str | None, unit: TrialUnit) -> list[TrialRecord]:
        if _WORKER_RUNNER is None:  # Ray reuses worker processes: build the scene once per process
            _init_worker(config_dict, objects_dir_)
        return _run_unit_in_worker(unit)

    config_ref = ray.put(config.to_dict())
    pending = [run_unit_task.remote(config_ref, objects_dir, unit) for unit in units]
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for record in ray.get(done[0]):
                emit(record)
    finally:
        if started_here:
            ray.shutdown()


# --- the study ---------------------------------------------------------------------------------


def run_study(
    config: Config,
    objects: ObjectSet,
    methods: Iterable[str],
    *,
    objects_dir: str | None = None,
    progress: bool = True,
    not_run: dict[str, str] | None = None,
) -> StudyResult:
    """Run (or finish) the study described by ``config`` into ``config.run.out``."""
    from .report import write_reports

    out_dir = Path(config.run.out).expanduser()
    units = plan_units(config, objects, methods)
    out_dir.mkdir(parents=True, exist_ok=True)
    _check_run_directory(out_dir, config)
    (out_dir / "config.json").write_text(json.dumps(config.to_dict(), indent=2, sort_keys=True))
    seeds = sorted({config.scene.seed_base + u.trial for u in units})
    (out_dir / "provenance.json").write_text(json.dumps(provenance.collect(
        config.to_dict(),
        scene_seeds=seeds,
        candidate_seed_offset=config.planner.seed + config.scene.seed_base,
        objects={"source": objects.source, "checksum": objects.checksum(), "ids": [u for u in dict.fromkeys(x.object_id for x in units)]},
        methods=list(methods),
        not_run=not_run or {},
    ), indent=2, sort_keys=True, default=str))

    trials_path = out_dir / TRIALS_FILE
    finished = {record_key(r) for r in read_records(trials_path)}
    pending = [u for u in units if not all(key in finished for key in u.keys())]
    pending = [TrialUnit(u.object_id, u.task, u.trial, tuple(m for m in u.methods if (u.object_id, u.task, m, u.trial) not in finished)) for u in pending]

    writer = TrialWriter(trials_path)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(len(u.methods) for u in pending), unit="trial", file=sys.stderr, dynamic_ncols=True)
    new_records = 0

    def emit(record: TrialRecord) -> None:
        nonlocal new_records
        writer.write(record.to_json())
        new_records += 1
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(f"{record.object} {record.task} {record.method} #{record.trial}")

    try:
        if config.run.backend == "ray":
            _run_ray(config, pending, emit, objects_dir)
        elif config.run.backend == "local" and config.run.workers > 1:
            _run_processes(config, pending, emit, objects_dir)
        elif config.run.backend == "local":
            _run_inline(config, objects, pending, emit)
        else:
            raise ConfigError(f"unknown backend '{config.run.backend}' (known: local, ray)")
    finally:
        writer.close()
        if bar is not None:
            bar.close()

    wanted = {key for u in units for key in u.keys()}
    records = sorted((r for r in read_records(trials_path) if record_key(r) in wanted), key=record_key)
    summary = summarise(records)
    write_reports(out_dir, records, summary, not_run or {})
    return StudyResult(out_dir, records, summary, new_records, not_run or {})
