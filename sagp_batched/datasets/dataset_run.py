"""A dataset run: objects planned and their grasps simulated across workers, each object written as it finishes.

Work comes in two kinds: an object's plan (``ObjectLabeller.plan_object``: every capture reset,
captured, classified and rated once), then its grasps in chunks (``ObjectLabeller.simulate``), so
one object's simulation spreads over every worker and a worker plans the next object while others
simulate. Labels do not depend on the chunking or on which worker simulates a chunk: each grasp's
simulation starts from its capture's settled state alone. The driver alone writes the dataset.
"""
from __future__ import annotations

import collections
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from ..config import Config
from ..formats.frames import grasp_poses_from_acronym
from ..run_directory import WorkerReport
from ..workers import Recipe, WorkerPool
from ..world.objects import ObjectSet
from .object_labeller import ObjectLabeller, ObjectLabels, ObjectPlan, object_labels, object_physics

# The report's coverage figure: grasps closer than this, and turned less, count as one.
DISTINCT_TRANSLATION_M = 0.01
DISTINCT_ROTATION_DEG = 20.0


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
                yield object_labels(plan, outcomes, config.dataset.engines)


def _write_object(out_dir: Path, spec, labels: ObjectLabels, mode: str, protocol: str) -> dict:
    """Write one object's files and return its progress line (what the report and a resume read)."""
    from sagp_batched_kernels.pose_nms import distinct_grasp_count

    from .cross_engine import object_engine_agreement
    from .dataset_directory import append_progress, copy_object_mesh
    from ..formats.acronym import write_object_file
    from ..formats.graspgen import write_graspgen_file

    clock = time.perf_counter()
    for sub in ("grasps", "graspgen", "meshes"):
        (out_dir / sub).mkdir(exist_ok=True)
    mesh_file, scale, mesh_to_link = copy_object_mesh(spec, out_dir / "meshes")
    grasps = labels.grasps
    write_object_file(out_dir / "grasps" / f"{spec.id}.h5", spec.id, mesh_file, scale, mesh_to_link, object_physics(spec),
                      grasps, labels.untested, mode, protocol, labels.rater)
    write_graspgen_file(out_dir / "graspgen" / f"{spec.id}.json", mesh_file, scale, grasps)
    poses = grasp_poses_from_acronym(grasps.transforms)
    distinct = distinct_grasp_count(poses.position, poses.rotation, DISTINCT_TRANSLATION_M, math.radians(DISTINCT_ROTATION_DEG))
    write_s = time.perf_counter() - clock
    entry = {
        "object": spec.id, "mesh": mesh_file, "labelled": len(grasps), "held": int(grasps.held.sum()),
        "untested": len(labels.untested.reason), "distinct_1cm_20deg": distinct, "rater": labels.rater,
        "decided_by_geometry": grasps.decided_by.count("geometry"),
        "held_octants": held_octants(spec, grasps.contacts[grasps.held]),
        "unanimous": int(((grasps.held_fraction == 0.0) | (grasps.held_fraction == 1.0)).sum()),
        "hull_fidelity": spec.import_record.fidelity_summary() if spec.import_record is not None else None,
        "neutral_tasks": labels.neutral_tasks, "skipped_captures": labels.skipped_poses,
        "by_verdict": {v: [int(sum(h for h, w in zip(grasps.held, grasps.verdict) if w == v)), grasps.verdict.count(v)]
                       for v in sorted(set(grasps.verdict))},
        "times_s": {**labels.times_s, "write": write_s}, "engine_seconds": labels.engine_seconds,
        "engine_agreement": object_engine_agreement(grasps.engine_held, grasps.engine_failure,
                                                    np.array([by == "simulation" for by in grasps.decided_by], dtype=bool), grasps.verdict),
    }
    append_progress(out_dir, entry)
    return entry


def held_octants(spec, contacts_object: np.ndarray) -> int:
    """Of the eight octants of the object's bounding box (link frame), how many hold the contact
    midpoint of a held grasp: whether positives spread over the object or gather on one part."""
    from .grasp_geometry import object_surface

    points = object_surface(spec).points.numpy()
    centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
    sides = (contacts_object.reshape(-1, 2, 3).mean(axis=1) > centre).astype(int)
    return len({tuple(side) for side in sides})


def measure_agreement(config: Config, objects: ObjectSet, object_ids: list[str], n_grasps: int) -> dict:
    """Hand-vs-arm agreement on ``n_grasps`` grasps of each object of ``object_ids`` (``ObjectLabeller.compare_modes``)."""
    labeller = ObjectLabeller(config, objects)
    try:
        by_object = {object_id: labeller.compare_modes(object_id, n_grasps) for object_id in object_ids}
    finally:
        labeller.close()
    totals = {key: sum(row[key] for row in by_object.values()) for key in ("compared", "both_tested", "agree", "hand_held", "arm_held")}
    return {**totals, "grasps_per_object": n_grasps, "by_object": by_object}


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

            write_json(out_dir / AGREEMENT_FILE, measure_agreement(config, objects, list(agreement_objects or []), agreement_grasps))
        manifest = write_dataset_report(out_dir, config, objects, object_ids)
    return DatasetResult(out_dir, new_objects, manifest)


def _label_pending(config: Config, objects: ObjectSet, out_dir: Path, pending: list[str], packed: Any, progress: bool,
                   on_object: Callable[[dict], None] | None) -> list[str]:
    """Label the ``pending`` objects, each written (``_write_object``) as soon as it is done, the
    workers' reports appended to ``workers.jsonl``; the objects written, in that order."""
    from ..run_directory import WORKERS_FILE, append_json_line

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
            entry = _write_object(out_dir, objects.get(labels.object_id), labels, config.dataset.mode, config.dataset.protocol)
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
