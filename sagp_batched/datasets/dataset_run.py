"""A dataset run: objects planned and their grasps simulated across workers, each object written as it finishes.

Work comes in two kinds: an object's plan (``ObjectLabeller.plan_object``: every capture reset,
captured, classified and rated once), then its grasps in chunks (``ObjectLabeller.simulate``), so
one object's simulation spreads over every worker and a worker plans the next object while others
simulate. Labels do not depend on the chunking or on which worker simulates a chunk: each grasp's
simulation starts from its capture's settled state alone. The driver alone writes the dataset.
"""
from __future__ import annotations

import collections
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from ..config import Config
from ..robot.description import robot_of
from ..run_directory import WorkerReport
from ..workers import Recipe, WorkerPool
from ..world.objects import ObjectSet
from .object_labeller import ObjectLabeller, mode_agreement
from .object_plan import ObjectLabels, ObjectPlan, object_labels


@dataclass
class DatasetResult:
    out_dir: Path
    new_objects: list[str]
    manifest: dict


def dataset_object_ids(config: Config, objects: ObjectSet) -> list[str]:
    """The objects a dataset labels: ``run.objects``, where "all" is every object of the set."""
    requested = list(config.run.objects)
    if requested == ["all"]:
        return list(objects.ids)
    for object_id in requested:
        objects.get(object_id)  # raises UnknownObjectError naming the id
    return requested


# --- workers: each holds one ObjectLabeller (one PyBullet client) for the whole run -------------------
class _DatasetWorker:
    """One worker's labeller; a unit is ("plan", (object id, grasps)) or ("simulate", chunk)."""

    def __init__(self, labeller: ObjectLabeller, objects_dir: str | None):
        self.labeller = labeller
        self.objects_dir = objects_dir

    def run(self, unit: tuple[str, Any]) -> Any:
        kind, payload = unit
        if kind == "plan":
            object_id, n_grasps = payload
            return self.labeller.plan_object(object_id, n_grasps)
        return self.labeller.simulate(payload)

    def close(self) -> None:
        self.labeller.close()


def _process_worker(config_dict: dict, objects: ObjectSet) -> _DatasetWorker:
    from ..config import load_config

    return _DatasetWorker(ObjectLabeller(load_config(overrides=config_dict), objects), None)


def _ray_worker(config_dict: dict, packed: Any) -> _DatasetWorker:
    """A Ray actor's worker: its objects arrive by value from the object store (``object_transfer``) and are
    written to this node's own cache, so no node needs the driver's objects folder."""
    from ..config import load_config
    from ..world.object_transfer import materialise, materialised_dir

    objects = materialise(packed)
    return _DatasetWorker(ObjectLabeller(load_config(overrides=config_dict), objects), str(materialised_dir(packed)))


def labelled_objects(config: Config, objects: ObjectSet, object_ids: list[str], packed: Any = None,
                     on_report: Callable[[WorkerReport], None] | None = None) -> Iterator[ObjectLabels]:
    """Each object's labels as soon as its plan and every chunk of it are done (objects in any order).
    ``packed``: the objects packed for Ray (``object_transfer.pack_objects``); ``on_report`` hears each
    worker process's report after each piece of work."""
    dataset, config_dict = config.dataset, config.to_dict()
    workers = WorkerPool(config.run.backend, config.run.workers, here=lambda: _DatasetWorker(ObjectLabeller(config, objects), None),
                         in_process=Recipe(_process_worker, (config_dict, objects)), on_ray=Recipe(_ray_worker, (config_dict, packed)),
                         ray_address=config.run.ray_address)
    to_plan = collections.deque(object_ids)
    unfinished: dict[str, tuple[ObjectPlan, list, int]] = {}

    def plan_next() -> None:
        if to_plan:
            workers.submit(("plan", (to_plan.popleft(), dataset.grasps_per_object)))

    with workers:
        # Planning stays about one object per worker ahead of the simulation: the pool never idles
        # while plans and outcomes waiting to be joined stay few.
        for _ in range(max(1, config.run.workers)):
            plan_next()
        while len(workers):
            (kind, _), result, report = workers.next_done()
            if report is not None and on_report is not None:
                on_report(report)
            if kind == "plan":
                chunks = result.chunks(dataset.mode, dataset.grasps_per_chunk)
                unfinished[result.object_id] = (result, [], len(chunks))
                for chunk in chunks:
                    workers.submit(("simulate", chunk))
                plan_next()
                object_id = result.object_id
            else:
                object_id = result.chunk.object_id
                unfinished[object_id][1].append(result)
            plan, outcomes, n_chunks = unfinished[object_id]
            if len(outcomes) == n_chunks:
                del unfinished[object_id]
                yield object_labels(plan, outcomes, robot_of(config).gripper, config.dataset.engines)


def generate_dataset(config: Config, objects: ObjectSet, out_dir: Path, *, progress: bool = True,
                     on_note: Callable[[str], None] | None = None, on_object: Callable[[dict], None] | None = None,
                     agreement_objects: list[str] | None = None, agreement_grasps: int = 0) -> DatasetResult:
    """Label ``config.dataset.grasps_per_object`` grasps of every object of ``config.run.objects`` into
    ``out_dir``; a re-run into the same directory skips the objects already written. ``on_object``
    hears each written object's progress line. With ``agreement_grasps``, the hand-vs-arm agreement
    on that many grasps of each of ``agreement_objects`` is measured too (``agreement.json``, in the report)."""
    from .. import provenance
    from .dataset_directory import read_progress
    from .dataset_report import write_dataset_report
    from ..run_directory import CONFIG_FILE, PROVENANCE_FILE, RunLock, check_same_run, write_json

    on_note = on_note or (lambda note: None)
    object_ids = dataset_object_ids(config, objects)
    packed = None
    if config.run.backend == "ray":
        from ..world.object_transfer import pack_objects

        # Read before anything is written: a file that cannot be packed stops the run with no directory made.
        packed = pack_objects(objects, object_ids)
    out_dir.mkdir(parents=True, exist_ok=True)
    checksum = objects.checksum()
    with RunLock(out_dir):
        check_same_run(out_dir, config, checksum, objects.source)
        write_json(out_dir / CONFIG_FILE, config.to_dict())
        write_json(out_dir / PROVENANCE_FILE, provenance.collect(
            config.to_dict(), dataset_seed=config.dataset.seed,
            objects={"source": objects.source, "checksum": checksum, "ids": object_ids,
                     "skipped": [list(item) for item in getattr(objects, "skipped", [])]},
        ))
        finished = read_progress(out_dir)
        pending = [object_id for object_id in object_ids if object_id not in finished]
        if finished:
            on_note(f"{len(finished)} object(s) already in {out_dir} are kept; {len(pending)} to label")
        new_objects = _label_pending(config, objects, out_dir, pending, packed, progress, on_object)
        if agreement_grasps:
            from .dataset_report import AGREEMENT_FILE

            write_json(out_dir / AGREEMENT_FILE, mode_agreement(config, objects, list(agreement_objects or []), agreement_grasps))
        manifest = write_dataset_report(out_dir, config, objects, object_ids)
    return DatasetResult(out_dir, new_objects, manifest)


def _label_pending(config: Config, objects: ObjectSet, out_dir: Path, pending: list[str], packed: Any, progress: bool,
                   on_object: Callable[[dict], None] | None) -> list[str]:
    """Label the ``pending`` objects, each written (``dataset_directory.write_object``) as soon as it is done, the
    workers' reports appended to ``workers.jsonl``; the objects written, in that order."""
    from ..run_directory import WORKERS_FILE, append_json_line
    from .dataset_directory import write_object

    bar = None
    if progress:
        import sys

        from tqdm import tqdm

        bar = tqdm(total=len(pending), unit="object", file=sys.stderr, dynamic_ncols=True)
    new_objects = []
    def on_report(report: WorkerReport) -> None:
        append_json_line(out_dir / WORKERS_FILE, {**report.to_json(), "time": time.time()})

    try:
        for labels in labelled_objects(config, objects, pending, packed, on_report):
            entry = write_object(out_dir, objects.get(labels.object_id), labels, config.dataset.mode, config.dataset.protocol,
                                     robot_of(config).gripper)
            new_objects.append(labels.object_id)
            if on_object is not None:
                on_object(entry)
            if bar is not None:
                bar.update(1)
                bar.set_postfix_str(labels.object_id)
    finally:
        if bar is not None:
            bar.close()
    return new_objects
