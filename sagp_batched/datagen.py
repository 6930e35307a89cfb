"""Labelled grasp datasets: for each object and resting pose, capture once, plan, and label grasps by simulation.

``ObjectLabeller.label`` makes one object's labels in one PyBullet client; ``generate_dataset`` runs
it over an object set (in this process or in worker processes), writes each finished object at once
(``dataset``) and resumes where a stopped run left off.

What a label is: the outcome of simulating the grasp (``labelling``): held after the lift and the
shake, or dropped, with the object's motion during closing and shaking. The grasps are the planner's
antipodal candidates across its verdicts (``verdicts.classify_grasps``): the feasible ones and those it
rejects, so the dataset has both classes and measures the planner's calibration. A grasp whose
simulation could not run (in ``arm`` mode: no arm solution for a grasp the planner rejected) is kept
apart as untested, never written as a failure.
"""
from __future__ import annotations

import dataclasses
import math
import time
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .config import Config
from .dataset import LabelledGrasps, ObjectPhysics, UntestedGrasps
from .export import acronym_gripper_transforms_object, planner_frames_from_acronym
from .objects import ObjectSpec
from .types import GraspCandidates, PerceptionFailure
from .verdicts import FEASIBLE, ClassifiedGrasps, classify_grasps

# The tasks a dataset's zone ratings are asked for: t3 is t1 among distractors, which a dataset
# of single objects does not place.
DATASET_TASKS: tuple[str, ...] = ("t1", "t2")
# The report's coverage figure: grasps closer than this, and turned less, count as one.
DISTINCT_TRANSLATION_M = 0.01
DISTINCT_ROTATION_DEG = 20.0
# PyBullet's lateral friction where a URDF gives none.
PYBULLET_DEFAULT_FRICTION = 0.5


def object_physics(spec: ObjectSpec) -> ObjectPhysics:
    """What the simulator was given for ``spec``: an imported object's figures from its import
    metadata (the solid's volume and full inertia, the density that made its mass), else the
    URDF's mass, COM, inertia and friction with the volume of its collision hulls (the solid
    PyBullet collides) and density = mass / volume."""
    from .mesh_import import METADATA_FILE

    metadata_path = Path(spec.urdf_path).with_name(METADATA_FILE)
    if metadata_path.is_file():
        import json

        metadata = json.loads(metadata_path.read_text())
        return ObjectPhysics(float(metadata["mass_kg"]), float(metadata["density_kg_m3"]), float(metadata["friction"]),
                             tuple(metadata["com_m"]), tuple(tuple(row) for row in metadata["inertia_kg_m2"]),
                             float(metadata["volume_m3"]))
    return _urdf_physics(spec)


def _urdf_physics(spec: ObjectSpec) -> ObjectPhysics:
    import trimesh

    link = ElementTree.parse(spec.urdf_path).getroot().find("link")
    inertial = link.find("inertial")
    mass = float(inertial.find("mass").get("value")) if inertial is not None else spec.mass_kg
    origin = inertial.find("origin") if inertial is not None else None
    com = tuple(float(v) for v in (origin.get("xyz") if origin is not None else "0 0 0").split())
    inertia_element = inertial.find("inertia") if inertial is not None else None
    values = {key: float(inertia_element.get(key, 0.0)) if inertia_element is not None else 0.0
              for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    inertia = ((values["ixx"], values["ixy"], values["ixz"]), (values["ixy"], values["iyy"], values["iyz"]),
               (values["ixz"], values["iyz"], values["izz"]))
    friction_element = link.find("contact/lateral_friction")
    friction = float(friction_element.get("value")) if friction_element is not None else PYBULLET_DEFAULT_FRICTION
    mesh_element = link.find("collision/geometry/mesh")
    volume = 0.0
    if mesh_element is not None:
        scale = np.array([float(v) for v in (mesh_element.get("scale") or "1 1 1").split()])
        mesh = trimesh.load(Path(spec.urdf_path).parent / mesh_element.get("filename"), force="mesh")
        mesh.apply_scale(scale)
        volume = float(sum(part.convex_hull.volume for part in mesh.split(only_watertight=False)))
    density = mass / volume if volume > 0 else math.nan
    return ObjectPhysics(mass, density, friction, com, inertia, volume)  # type: ignore[arg-type]


@dataclass
class ObjectLabels:
    """One object's labelled and untested grasps, with what making them cost."""

    object_id: str
    grasps: LabelledGrasps
    untested: UntestedGrasps
    rater: str
    neutral_tasks: dict[str, str]  # task -> why its rating is neutral (the rater does not know the object)
    skipped_poses: list[str] = field(default_factory=list)
    times_s: dict[str, float] = field(default_factory=dict)  # reset, capture, plan, simulate


class GraspSimulator:
    """Simulates grasps on a reset ``Scene`` in one mode: ``hand`` (``labelling.label_grasps_hand``:
    the hand alone, each grasp in a world of its own with the object where it settled) or ``arm``
    (``labelling.label_grasps_arm``: the Panda from the scene's settled state; a grasp the planner
    rejected runs without its plan, as execution solves it, and one the arm cannot reach is untested)."""

    def __init__(self, scene, config: Config, mode: str):
        self.scene, self.config, self.mode = scene, config, mode

    def simulate(self, candidates: GraspCandidates, feasible: torch.Tensor) -> list:
        """A ``GraspLabel`` per grasp of ``candidates``, or the reason it could not be simulated."""
        from .labelling import label_grasps_arm, label_grasps_hand

        if self.mode == "hand":
            return list(label_grasps_hand(self.scene, candidates, self.config))
        grasps = [candidates[i] if bool(feasible[i]) else dataclasses.replace(candidates[i], joint_path=None) for i in range(len(candidates))]
        labels = label_grasps_arm(self.scene, grasps, self.config)
        return [label if label is not None else "untested: the arm found no motion that reaches it" for label in labels]


def _failure(label) -> str:
    return "" if label.held else f"{label.failure_reason}@{label.failed_at}"


def _motion(value: float | None) -> float:
    """A motion the grasp never reached (it failed before that phase) is NaN, not 0."""
    return math.nan if value is None else float(value)


def _zone_levels(candidates: GraspCandidates, ratings: dict) -> tuple[list[str], dict[str, list[str]]]:
    names = candidates.primary_zone_names()
    levels = {task: [(rating.level(name) or "") if name else "" for name in names] for task, rating in ratings.items()}
    return names, levels


class ObjectLabeller:
    """Labels objects in one PyBullet client: a scene, a rater and the chosen simulation mode."""

    def __init__(self, config: Config):
        from .rating import get_rater
        from .scene import Scene

        self.config = config
        self.scene = Scene(config)
        self.rater = get_rater(config.rating)
        self._simulators = {}

    def simulator(self, mode: str) -> GraspSimulator:
        """The simulator of ``mode`` ("hand" or "arm"), built on first use and kept."""
        if mode not in self._simulators:
            self._simulators[mode] = GraspSimulator(self.scene, self.config, mode)
        return self._simulators[mode]

    def close(self) -> None:
        self.scene.close()

    def label(self, spec: ObjectSpec, n_grasps: int) -> ObjectLabels:
        """``n_grasps`` grasps of ``spec`` (split over its resting poses), each simulated once."""
        dataset = self.config.dataset
        n_poses = dataset.captures_per_object
        shares = [n_grasps // n_poses + (1 if k < n_grasps % n_poses else 0) for k in range(n_poses)]
        parts, untested, skipped, neutral = [], [], [], {}
        times = dict.fromkeys(("reset", "capture", "plan", "simulate"), 0.0)
        for pose_index, share in enumerate(shares):
            # A later capture offers the same grasps again in the object's frame: only new ones are picked.
            picked = np.concatenate([p.transforms for p in parts] + [u.transforms for u in untested] + [np.zeros((0, 4, 4))])
            taken = tuple(torch.as_tensor(a, dtype=torch.float64) for a in planner_frames_from_acronym(picked))
            result = self._label_pose(spec, pose_index, share, times, taken)
            if isinstance(result, str):
                skipped.append(result)
                continue
            labelled, rejected, pose_neutral = result
            parts.append(labelled)
            untested.append(rejected)
            neutral.update(pose_neutral)
        grasps = LabelledGrasps.concatenate(parts) if parts else LabelledGrasps.empty(DATASET_TASKS)
        untested_all = UntestedGrasps(np.concatenate([u.transforms for u in untested]) if untested else np.zeros((0, 4, 4)),
                                      sum((u.reason for u in untested), []))
        rater = f"{self.rater.backend}:{getattr(self.rater, 'model', '')}"
        return ObjectLabels(spec.id, grasps, untested_all, rater, neutral, skipped, times)

    def _capture_and_classify(self, spec: ObjectSpec, pose_index: int, n_grasps: int, times: dict[str, float], taken=None):
        """Place ``spec`` for capture ``pose_index``, capture it and classify ``n_grasps`` of its grasps;
        the reason instead where the capture failed."""
        from .perception import capture

        config, dataset = self.config, self.config.dataset
        clock = time.perf_counter()
        # Capture k places the object in its k-th stable resting pose, where it lists several.
        self.scene.reset(spec, trial=dataset.seed + pose_index, resting_pose=pose_index % max(1, len(spec.resting_poses)))
        times["reset"] += time.perf_counter() - clock
        clock = time.perf_counter()
        try:
            cloud = capture(self.scene, config)
        except PerceptionFailure as failure:
            return f"capture {pose_index}: {failure.reason}"
        times["capture"] += time.perf_counter() - clock
        clock = time.perf_counter()
        classified = classify_grasps(cloud, config, dataset.seed + pose_index, n_grasps, taken_object=taken)
        times["plan"] += time.perf_counter() - clock
        return cloud, classified

    def compare_modes(self, spec: ObjectSpec, n_grasps: int) -> dict[str, int]:
        """The same ``n_grasps`` grasps of ``spec``'s first capture simulated in hand and in arm mode:
        how many were compared, executed in both, agreed, and held in each."""
        captured = self._capture_and_classify(spec, 0, n_grasps, dict.fromkeys(("reset", "capture", "plan"), 0.0))
        if isinstance(captured, str):
            return {"compared": 0, "both_tested": 0, "agree": 0, "hand_held": 0, "arm_held": 0, "skipped": captured}
        _, classified = captured
        feasible = classified.verdict == FEASIBLE
        hand = self.simulator("hand").simulate(classified.candidates, feasible)
        arm = self.simulator("arm").simulate(classified.candidates, feasible)
        both = [(h, a) for h, a in zip(hand, arm) if not isinstance(h, str) and not isinstance(a, str)]
        return {"compared": len(hand), "both_tested": len(both), "agree": sum(h.held == a.held for h, a in both),
                "hand_held": sum(h.held for h, _ in both), "arm_held": sum(a.held for _, a in both)}

    def _label_pose(self, spec: ObjectSpec, pose_index: int, n_grasps: int, times: dict[str, float], taken):
        from .zone_marks import rating_image
        from .zones import assign_zones

        config = self.config
        captured = self._capture_and_classify(spec, pose_index, n_grasps, times, taken)
        if isinstance(captured, str):
            return captured
        cloud, classified = captured
        clock = time.perf_counter()
        decomposition, zoned = assign_zones(cloud, classified.candidates, config.zones)
        shown = rating_image(cloud, decomposition, config.rating)
        ratings = {task: self.rater.rate(spec.id, spec.name, task, shown, decomposition.describe()) for task in DATASET_TASKS}
        neutral = {task: (rating.issues[0] if rating.issues else "neutral") for task, rating in ratings.items() if rating.is_neutral}
        times["plan"] += time.perf_counter() - clock
        clock = time.perf_counter()
        outcomes = self.simulator(config.dataset.mode).simulate(zoned, classified.verdict == FEASIBLE)
        times["simulate"] += time.perf_counter() - clock
        labelled, rejected = _pose_labels(cloud, zoned, classified, outcomes, ratings, pose_index)
        return labelled, rejected, neutral


def _pose_labels(cloud, zoned: GraspCandidates, classified: ClassifiedGrasps, outcomes: list, ratings: dict, pose_index: int):
    """The pose's simulated grasps as labels in the object frame, and the grasps whose simulation could not run."""
    tested = [i for i, outcome in enumerate(outcomes) if not isinstance(outcome, str)]
    object_frame = zoned.transform(cloud.object_from_world)
    transforms = acronym_gripper_transforms_object(object_frame)
    untested = [i for i, outcome in enumerate(outcomes) if isinstance(outcome, str)]
    kept = torch.as_tensor(tested, dtype=torch.int64)
    chosen = zoned.select(kept)
    zone_names, levels = _zone_levels(chosen, ratings)
    verdicts = classified.verdict_names()
    simulated = [outcomes[i] for i in tested]
    labelled = LabelledGrasps(
        transforms=transforms[tested].reshape(-1, 4, 4),
        width_m=chosen.width_m.double().numpy(),
        contacts=object_frame.contacts_world[kept].numpy().reshape(-1, 2, 3),
        resting_pose=np.full(len(tested), pose_index, dtype=np.int64),
        verdict=[verdicts[i] for i in tested],
        verdict_reason=[classified.reasons[i] for i in tested],
        held=np.array([o.held for o in simulated], dtype=bool),
        failure_reason=[_failure(o) for o in simulated],
        motion_closing_linear_m=np.array([_motion(o.object_motion_during_closing_linear) for o in simulated]),
        motion_closing_angular_rad=np.array([_motion(o.object_motion_during_closing_angular) for o in simulated]),
        motion_shaking_linear_m=np.array([_motion(o.object_motion_during_shaking_linear) for o in simulated]),
        motion_shaking_angular_rad=np.array([_motion(o.object_motion_during_shaking_angular) for o in simulated]),
        s_geom=chosen.s_geom.double().numpy(),
        s_reach=chosen.s_reach.double().numpy(),
        zone=zone_names,
        zone_rating=levels,
    )
    rejected = UntestedGrasps(transforms[untested].reshape(-1, 4, 4), [f"{verdicts[i]}: {outcomes[i]}" for i in untested])
    return labelled, rejected


# --- the dataset run -----------------------------------------------------------------------------


@dataclass
class DatasetResult:
    out_dir: Path
    new_objects: list[str]
    manifest: dict


def dataset_object_ids(config: Config, objects) -> list[str]:
    """The objects a dataset labels: ``run.objects``, where "all" is every object of the set."""
    requested = list(config.run.objects)
    if requested == ["all"]:
        return list(objects.ids)
    for object_id in requested:
        objects.get(object_id)  # raises UnknownObjectError naming the id
    return requested


_WORKER_LABELLER: ObjectLabeller | None = None


def _init_worker(config_dict: dict) -> None:
    global _WORKER_LABELLER
    from .config import load_config
    from .runtime import configure_torch

    configure_torch()
    _WORKER_LABELLER = ObjectLabeller(load_config(overrides=config_dict))


def _label_in_worker(spec: ObjectSpec, n_grasps: int) -> ObjectLabels:
    return _WORKER_LABELLER.label(spec, n_grasps)


def _labels_in_processes(config: Config, specs: list[ObjectSpec]):
    import concurrent.futures
    import multiprocessing

    context = multiprocessing.get_context("spawn")  # a fresh interpreter and PyBullet client per worker
    with concurrent.futures.ProcessPoolExecutor(max_workers=config.run.workers, mp_context=context,
                                                initializer=_init_worker, initargs=(config.to_dict(),)) as pool:
        futures = [pool.submit(_label_in_worker, spec, config.dataset.grasps_per_object) for spec in specs]
        try:
            for future in concurrent.futures.as_completed(futures):
                yield future.result()
        except BaseException:  # an interrupt or a write that failed: start no further object
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _labels_on_ray(config: Config, specs: list[ObjectSpec]):
    """One actor per worker, each holding one ``ObjectLabeller`` (one PyBullet client) for the whole run."""
    from .runtime import ray_session

    with ray_session(config.run.ray_address, config.run.workers):
        import ray
        from ray.util import ActorPool

        labeller_actor = ray.remote(num_cpus=1)(_RayLabeller)
        pool = ActorPool([labeller_actor.remote(config.to_dict()) for _ in range(config.run.workers)])
        yield from pool.map_unordered(lambda actor, spec: actor.label.remote(spec, config.dataset.grasps_per_object), specs)


class _RayLabeller:
    """An ``ObjectLabeller`` built inside a Ray worker from the config's plain dict."""

    def __init__(self, config_dict: dict):
        _init_worker(config_dict)

    def label(self, spec: ObjectSpec, n_grasps: int) -> ObjectLabels:
        return _label_in_worker(spec, n_grasps)


def _labels_inline(config: Config, specs: list[ObjectSpec]):
    labeller = ObjectLabeller(config)
    try:
        for spec in specs:
            yield labeller.label(spec, config.dataset.grasps_per_object)
    finally:
        labeller.close()


def _write_object(out_dir: Path, spec: ObjectSpec, labels: ObjectLabels, mode: str) -> dict:
    """Write one object's files and return its progress line (what the report and a resume read)."""
    from sagp_batched_kernels.pose_nms import distinct_grasp_count

    from .dataset import append_progress, copy_object_mesh, write_graspgen_file, write_object_file

    clock = time.perf_counter()
    for sub in ("grasps", "graspgen", "meshes"):
        (out_dir / sub).mkdir(exist_ok=True)
    mesh_file, scale, mesh_to_link = copy_object_mesh(spec, out_dir / "meshes")
    grasps = labels.grasps
    write_object_file(out_dir / "grasps" / f"{spec.id}.h5", spec.id, mesh_file, scale, mesh_to_link, object_physics(spec),
                      grasps, labels.untested, mode, labels.rater)
    write_graspgen_file(out_dir / "graspgen" / f"{spec.id}.json", mesh_file, scale, grasps)
    centres, frames = (torch.tensor(a) for a in planner_frames_from_acronym(grasps.transforms))
    distinct = distinct_grasp_count(centres, frames, DISTINCT_TRANSLATION_M, math.radians(DISTINCT_ROTATION_DEG))
    write_s = time.perf_counter() - clock
    entry = {
        "object": spec.id, "mesh": mesh_file, "labelled": len(grasps), "held": int(grasps.held.sum()),
        "untested": len(labels.untested.reason), "distinct_1cm_20deg": distinct, "rater": labels.rater,
        "neutral_tasks": labels.neutral_tasks, "skipped_captures": labels.skipped_poses,
        "by_verdict": {v: [int(sum(h for h, w in zip(grasps.held, grasps.verdict) if w == v)), grasps.verdict.count(v)]
                       for v in sorted(set(grasps.verdict))},
        "times_s": {**labels.times_s, "write": write_s},
    }
    append_progress(out_dir, entry)
    return entry


def measure_agreement(config: Config, objects, object_ids: list[str], n_grasps: int) -> dict:
    """Hand-vs-arm agreement on ``n_grasps`` grasps of each object of ``object_ids`` (``ObjectLabeller.compare_modes``)."""
    labeller = ObjectLabeller(config)
    try:
        by_object = {object_id: labeller.compare_modes(objects.get(object_id), n_grasps) for object_id in object_ids}
    finally:
        labeller.close()
    totals = {key: sum(row[key] for row in by_object.values()) for key in ("compared", "both_tested", "agree", "hand_held", "arm_held")}
    return {**totals, "grasps_per_object": n_grasps, "by_object": by_object}


def generate_dataset(config: Config, objects, out_dir: Path, *, progress: bool = True, on_note=None,
                     agreement_objects: list[str] | None = None, agreement_grasps: int = 0) -> DatasetResult:
    """Label ``config.dataset.grasps_per_object`` grasps of every object of ``config.run.objects`` into
    ``out_dir``; a re-run into the same directory skips the objects already written. With
    ``agreement_grasps``, the hand-vs-arm agreement on that many grasps of each of
    ``agreement_objects`` is measured too (``agreement.json``, in the report)."""
    from . import provenance
    from .dataset import read_progress
    from .dataset_report import write_dataset_report
    from .run_directory import CONFIG_FILE, PROVENANCE_FILE, RunLock, check_same_run, write_json

    on_note = on_note or (lambda note: None)
    object_ids = dataset_object_ids(config, objects)
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
        pending = [objects.get(object_id) for object_id in object_ids if object_id not in finished]
        if finished:
            on_note(f"{len(finished)} object(s) already in {out_dir} are kept; {len(pending)} to label")
        bar = None
        if progress:
            import sys

            from tqdm import tqdm

            bar = tqdm(total=len(pending), unit="object", file=sys.stderr, dynamic_ncols=True)
        if config.run.backend == "ray":
            labels_of = _labels_on_ray
        else:
            labels_of = _labels_inline if config.run.workers == 1 else _labels_in_processes
        new_objects = []
        try:
            for labels in labels_of(config, pending):
                _write_object(out_dir, objects.get(labels.object_id), labels, config.dataset.mode)
                new_objects.append(labels.object_id)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix_str(labels.object_id)
        finally:
            if bar is not None:
                bar.close()
        if agreement_grasps:
            from .dataset_report import AGREEMENT_FILE

            write_json(out_dir / AGREEMENT_FILE, measure_agreement(config, objects, list(agreement_objects or []), agreement_grasps))
        manifest = write_dataset_report(out_dir, config, objects, object_ids)
    return DatasetResult(out_dir, new_objects, manifest)
