"""The study loop: units over objects x tasks x trials, run here, in processes, or on Ray (``workers.WorkerPool``).

Long runs lose nothing: each finished record is appended to ``trials.jsonl`` and synced at once
(``run_directory``); a re-run into the same directory skips finished records and runs again the
trials whose line was torn or invalid, and those that ended in an error unless ``run.keep_errors``;
a unit that raises or times out is recorded with its error, and so is each unit of a worker process that died.

Only the driver writes the run directory, whichever backend runs the units: a unit comes back with
its records and the contents of the files they name, and the driver writes the files (whole, by
rename) before the records, so a resume never finds a record whose file is missing. Each worker
process reports its resident memory after every unit; the driver appends it to ``workers.jsonl``.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable

from .. import provenance
from ..config import Config, ConfigError, load_config
from ..run_directory import (
    CONFIG_FILE, PROVENANCE_FILE, WORKERS_FILE, RunDirectoryError, RunLock, WorkerReport, append_json_line, check_same_run, run_file_path,
    write_file_atomically, write_json,
)
from ..seeds import candidate_seed, scene_seed
from ..types import METHODS, TASKS
from ..workers import Recipe, WorkerPool
from ..world.objects import ObjectSet, load_object_set
from .experiment import TrialRunner, UnitResult
from .metrics import summarise
from .records import TrialRecord, TrialUnit, record_key
from .trials_file import TRIALS_FILE, TrialsFile, TrialWriter, read_records, recover_trials_file

if TYPE_CHECKING:
    from ..world.object_transfer import PackedObjects


@dataclass
class StudyResult:
    out_dir: Path
    records: list[dict[str, Any]]
    summary: dict[str, Any]
    new_records: int
    not_run: dict[str, str] = field(default_factory=dict)
    rejected_lines: int = 0  # lines of trials.jsonl set aside in trials.rejected.jsonl on this start


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
    if "t3" in config.run.tasks and not objects.distractors():
        # Without distractors t3's clutter condition holds trivially and its trials would repeat t1's.
        raise ConfigError(f"task t3 needs distractors and the object set {objects.source} has none: drop t3 from --tasks")
    return [
        TrialUnit(object_id, task, trial, methods)
        for object_id in resolve_object_ids(config, objects)
        for task in config.run.tasks
        for trial in range(config.run.n_trials)
    ]


# --- executors ---------------------------------------------------------------------------------


class _Worker:
    """One worker's ``TrialRunner`` (one PyBullet client and rater, kept for the whole run)."""

    def __init__(self, config: Config, objects: ObjectSet, objects_dir: str | None):
        self.runner = TrialRunner(config, objects)
        self.objects_dir = objects_dir

    def run(self, unit: TrialUnit) -> UnitResult:
        return self.runner.run_unit(unit)

    def close(self) -> None:
        """Nothing to free: the runner keeps its client as long as its process lives."""


def _process_worker(config_dict: dict[str, Any], objects_dir: str | None) -> _Worker:
    return _Worker(load_config(overrides=config_dict), load_object_set(objects_dir), objects_dir)


def _ray_worker(config_dict: dict[str, Any], packed_objects: PackedObjects) -> _Worker:
    """A Ray actor's worker: its objects arrive from the object store (``object_transfer``) and are written
    to this node's own cache, so no node needs the driver's objects folder."""
    from ..world.object_transfer import materialise, materialised_dir

    objects = materialise(packed_objects)
    return _Worker(load_config(overrides=config_dict), objects, str(materialised_dir(packed_objects)))


def _crashed_unit(config: Config, objects: ObjectSet, unit: TrialUnit, exc: BaseException) -> UnitResult:
    spec = objects.get(unit.object_id)
    return UnitResult([TrialRecord.build(spec, unit, method, config, error=f"worker process died: {exc}") for method in unit.methods])


def objects_used(objects: ObjectSet, units: Iterable[TrialUnit]) -> list[str]:
    """The ids of the objects ``units`` place in their scenes: each unit's object, and the distractors for t3."""
    units = list(units)
    ids = list(dict.fromkeys(unit.object_id for unit in units))
    if any(unit.task == "t3" for unit in units):
        ids += [spec.id for spec in objects.distractors() if spec.id not in ids]
    return ids


# --- the study ---------------------------------------------------------------------------------


def _pending_units(units: list[TrialUnit], finished: set[tuple[str, str, str, int]]) -> list[TrialUnit]:
    """The units with methods still to run, each holding only those methods."""
    pending = []
    for unit in units:
        methods = tuple(m for m in unit.methods if (unit.object_id, unit.task, m, unit.trial) not in finished)
        if methods:
            pending.append(TrialUnit(unit.object_id, unit.task, unit.trial, methods))
    return pending


def run_study(
    config: Config,
    objects: ObjectSet,
    methods: Iterable[str],
    *,
    objects_dir: str | None = None,
    progress: bool = True,
    not_run: dict[str, str] | None = None,
    on_note: Callable[[str], None] | None = None,
) -> StudyResult:
    """Run (or finish) the study described by ``config`` into ``config.run.out``.

    ``on_note`` hears, in one line each, what a resume found and set aside (torn or invalid lines,
    error records run again)."""
    out_dir = Path(config.run.out).expanduser()
    units = plan_units(config, objects, methods)
    packed = None
    if config.run.backend == "ray":
        from ..world import object_transfer

        # Read before anything is written: a file that cannot be packed stops the run with no run directory made.
        packed = object_transfer.pack_objects(objects, objects_used(objects, units))
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create the run directory {out_dir}: {exc.strerror or exc}") from exc
    with RunLock(out_dir):
        return _run_locked(config, objects, methods, units, out_dir, objects_dir, packed, progress, not_run or {},
                           on_note or (lambda note: None))


def _run_locked(config: Config, objects: ObjectSet, methods: Iterable[str], units: list[TrialUnit], out_dir: Path,
                objects_dir: str | None, packed: PackedObjects | None, progress: bool, not_run: dict[str, str],
                on_note: Callable[[str], None]) -> StudyResult:
    from .study_report import write_reports

    trials_path = out_dir / TRIALS_FILE
    recovered = _open_run_directory(config, objects, methods, units, out_dir, not_run, on_note)
    wanted = {key for u in units for key in u.keys()}
    errors = {record_key(r) for r in recovered.records if r["error"] is not None} & wanted
    if errors and not config.run.keep_errors:
        on_note(f"{len(errors)} trial(s) that ended in an error run again (--keep-errors keeps them)")
    finished = {record_key(r) for r in recovered.records} - (set() if config.run.keep_errors else errors)
    pending = _pending_units(units, finished)
    new_records = _run_pending(config, objects, pending, out_dir, objects_dir, packed, progress)

    records = sorted((r for r in read_records(trials_path) if record_key(r) in wanted), key=record_key)
    summary = summarise(records)
    try:
        write_reports(out_dir, records, summary, not_run)
    except OSError as exc:
        raise RunDirectoryError(f"cannot write the reports in {out_dir}: {exc.strerror or exc}; every trial is kept in {trials_path}") from exc
    return StudyResult(out_dir, records, summary, new_records, not_run, len(recovered.rejected))


def _open_run_directory(config: Config, objects: ObjectSet, methods: Iterable[str], units: list[TrialUnit], out_dir: Path,
                        not_run: dict[str, str], on_note: Callable[[str], None]) -> TrialsFile:
    """Check that ``out_dir`` holds this run (or none), set aside the torn or invalid lines of its
    trials file and write the run's config and provenance; the trials recovered."""
    checksum = objects.checksum()
    check_same_run(out_dir, config, checksum, objects.source)
    trials_path = out_dir / TRIALS_FILE
    recovered = recover_trials_file(trials_path)
    if recovered.rejected:
        reasons = sorted({line.reason for line in recovered.rejected})
        on_note(f"{len(recovered.rejected)} line(s) of {trials_path} set aside in trials.rejected.jsonl and their trials "
                f"run again ({'; '.join(reasons)[:300]})")
    write_json(out_dir / CONFIG_FILE, config.to_dict())
    write_json(out_dir / PROVENANCE_FILE, provenance.collect(
        config.to_dict(),
        scene_seeds=sorted({scene_seed(config, u.trial) for u in units}),
        # Trial t's candidate seed is this offset plus t.
        candidate_seed_offset=candidate_seed(config, trial=0),
        objects={"source": objects.source, "checksum": checksum, "ids": list(dict.fromkeys(u.object_id for u in units))},
        methods=list(methods),
        not_run=not_run,
    ))
    return recovered


def _run_pending(config: Config, objects: ObjectSet, pending: list[TrialUnit], out_dir: Path, objects_dir: str | None,
                 packed: PackedObjects | None, progress: bool) -> int:
    """Run ``pending`` on the configured backend, each unit written as it finishes; the records written."""
    writer = TrialWriter(out_dir / TRIALS_FILE)
    workers_path = out_dir / WORKERS_FILE
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(len(u.methods) for u in pending), unit="trial", file=sys.stderr, dynamic_ncols=True)
    new_records = 0

    def finish(result: UnitResult, report: WorkerReport | None) -> None:
        """Write a finished unit on the driver: its files first, then its records, so a record on disk names only files on disk."""
        nonlocal new_records
        for name, contents in result.files.items():
            write_file_atomically(run_file_path(out_dir, name), contents)
        for record in result.records:
            writer.write(record.to_json())
            new_records += 1
            if bar is not None:
                bar.update(1)
                bar.set_postfix_str(f"{record.object} {record.task} {record.method} #{record.trial}")
        if report is not None:
            append_json_line(workers_path, {**report.to_json(), "time": time.time()})

    config_dict = config.to_dict()
    pool = WorkerPool(config.run.backend, config.run.workers, here=lambda: _Worker(config, objects, objects_dir),
                      in_process=Recipe(_process_worker, (config_dict, objects_dir)), on_ray=Recipe(_ray_worker, (config_dict, packed)),
                      ray_address=config.run.ray_address, on_worker_death=lambda unit, exc: _crashed_unit(config, objects, unit, exc))
    try:
        with pool:
            for _, result, report in pool.as_finished(pending):
                finish(result, report)
    finally:
        writer.close()
        if bar is not None:
            bar.close()
    return new_records
