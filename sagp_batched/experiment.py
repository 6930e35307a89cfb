"""One trial of the study: perceive, plan once, rank by each method, execute, record.

A *unit* is one (object, task, trial): the scene, the cloud and the candidate set are shared by
every method of the unit, so all methods rank the identical candidates, as the published comparison requires.
Each method's result is one JSON-ready record.
"""
from __future__ import annotations

import dataclasses
import signal
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from .config import Config
from .functional_regions import region_membership
from .judging import judge_task
from .methods import RankingInputs, get_method
from .objects import ObjectSet, ObjectSpec
from .types import GraspCandidates, PerceivedCloud, PerceptionFailure



class TrialTimeout(RuntimeError):
    """A trial ran past ``config.run.trial_timeout_s``."""


@dataclass(frozen=True)
class TrialUnit:
    object_id: str
    task: str
    trial: int
    methods: tuple[str, ...]

    def keys(self) -> list[tuple[str, str, str, int]]:
        return [(self.object_id, self.task, method, self.trial) for method in self.methods]


def record_key(record: dict[str, Any]) -> tuple[str, str, str, int]:
    return (record["object"], record["task"], record["method"], int(record["trial"]))


def candidate_seed(config: Config, trial: int) -> int:
    """Seed of a trial's candidate set: fixed per trial so every method sees the same set."""
    return config.planner.seed + config.scene.seed_base + trial


@contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Raise TrialTimeout in this (main) thread after ``seconds``; a no-op off the main thread."""
    try:
        previous = signal.signal(signal.SIGALRM, _raise_timeout)
    except ValueError:  # signals only work in the main thread (e.g. inside some Ray workers)
        yield
        return
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _raise_timeout(signum: int, frame: Any) -> None:
    raise TrialTimeout("trial exceeded its time limit")


def _zone_points_object(cloud: PerceivedCloud, decomposition) -> dict[str, np.ndarray]:
    """Each zone's cloud points in the object frame: what a ground-truth (oracle) rater rates."""
    points_object = cloud.in_object_frame(decomposition.points_world.numpy())
    return {name: points_object[decomposition.memberships[:, index].numpy()] for index, name in enumerate(decomposition.zone_names)}


def base_record(spec: ObjectSpec, unit: TrialUnit, method: str, config: Config) -> dict[str, Any]:
    return {
        "object": spec.id,
        "category": spec.category,
        "asymmetric": spec.asymmetric,
        "task": unit.task,
        "method": method,
        "trial": unit.trial,
        "seed": config.scene.seed_base + unit.trial,
        "candidate_seed": candidate_seed(config, unit.trial),
        "success": False,
        "task_success": False,
        "attempts": 0,
        "attempt_log": [],
        "grasp": None,
        "failure_reason": None,
        "in_preferred_zone": None,
        "in_avoid_zone": None,
        "in_functional_region": None,
        "in_avoid_region": None,
        "orientation_change_deg": None,
        "orientation_kept": None,
        "distractors_max_displacement_m": None,
        "n_candidates": {"sampled": None, "antipodal": None, "collision_free": None, "ik_feasible": None},
        "times_s": {"perception": None, "geometry": None, "rating": None, "total_plan": None},
        "rating": None,
        "skipped": False,
        "error": None,
    }


class TrialRunner:
    """Runs units in one process with one PyBullet client and one rater, built on first use."""

    def __init__(self, config: Config, objects: ObjectSet):
        self.config = config
        self.objects = objects
        self._scene = None
        self._rater = None

    @property
    def scene(self):
        if self._scene is None:
            from .scene import Scene

            self._scene = Scene(self.config, gui=self.config.run.gui)
        return self._scene

    @property
    def rater(self):
        if self._rater is None:
            from .rating import get_rater

            self._rater = get_rater(self.config.rating)
        return self._rater

    def run_unit(self, unit: TrialUnit, emit: Callable[[dict[str, Any]], None]) -> None:
        """Run every method of ``unit``; ``emit`` each finished record at once.

        A failure inside the unit (an exception or the time limit) is recorded on every method
        of the unit not yet emitted, and the caller goes on with the next unit.
        """
        spec = self.objects.get(unit.object_id)
        emitted: set[str] = set()

        def emit_once(record: dict[str, Any]) -> None:
            emitted.add(record["method"])
            emit(record)

        try:
            with time_limit(self.config.run.trial_timeout_s):
                self._run_unit(spec, unit, emit_once)
        except Exception as exc:  # recorded, never lost: the run goes on with the next unit
            message = f"{type(exc).__name__}: {exc}"
            for method in unit.methods:
                if method in emitted:
                    continue
                record = base_record(spec, unit, method, self.config)
                record["error"] = message
                record["traceback"] = traceback.format_exc(limit=8)
                emit(record)

    def _distractors_for(self, unit: TrialUnit) -> list[ObjectSpec]:
        if unit.task != "t3":
            return []
        return list(self.objects.distractors())

    def _run_unit(self, spec: ObjectSpec, unit: TrialUnit, emit: Callable[[dict[str, Any]], None]) -> None:
        from .execution import execute_ranked
        from .perception import capture
        from .planner import plan
        from .zones import assign_zones

        config = self.config
        scene = self.scene
        scene.reset(spec, unit.trial, distractors=self._distractors_for(unit))

        start = time.perf_counter()
        try:
            cloud = capture(scene, config)
        except PerceptionFailure as failure:
            for method in unit.methods:
                record = base_record(spec, unit, method, config)
                record["failure_reason"] = f"perception:{failure.reason}"
                emit(record)
            return
        perception_s = time.perf_counter() - start

        start = time.perf_counter()
        candidates = plan(cloud, config, seed=candidate_seed(config, unit.trial))
        decomposition, candidates = assign_zones(cloud, candidates, config.zones)
        geometry_s = time.perf_counter() - start

        # Rated for every method, GO included: PZA and AC of GO are measured against the same zones.
        start = time.perf_counter()
        # Only a ground-truth rater (the oracle, an upper bound) is handed the object's true pose.
        zone_points = _zone_points_object(cloud, decomposition) if self.rater.uses_ground_truth else None
        # What the model sees: the crop with the zones drawn on it (set-of-mark prompting), or the plain crop.
        from .zone_marks import rating_image

        shown = rating_image(cloud, decomposition, config.rating)
        rating = self.rater.rate(spec.id, spec.name, unit.task, shown, decomposition.describe(), zone_points)
        rating_s = time.perf_counter() - start

        scored_by_method: dict[str, GraspCandidates] = {}
        executed_by_method: dict[str, tuple[list[int], list]] = {}
        for method in unit.methods:
            record = base_record(spec, unit, method, config)
            record["n_candidates"] = {key: candidates.counts.get(key) for key in record["n_candidates"]}
            method_start = time.perf_counter()
            ranked, order = get_method(method).rank(
                RankingInputs(candidates, cloud, rating, decomposition, spec.name, unit.task, config, self._model_client)
            )
            scored_by_method[method] = ranked
            ranking_s = time.perf_counter() - method_start
            method_rating_s = rating_s if method != "go" else 0.0
            record["times_s"] = {
                "perception": perception_s,
                "geometry": geometry_s,
                "rating": method_rating_s,
                "total_plan": geometry_s + method_rating_s + ranking_s,
            }
            record["rating"] = rating.provenance_dict()
            if len(order) == 0:
                record["failure_reason"] = "no_candidates"
                emit(record)
                continue
            attempts = execute_ranked(scene, config, ranked, order, record_frames=config.run.save_frames)
            executed_by_method[method] = (order, attempts)
            self._fill_outcome(record, ranked, order, attempts, cloud, rating, decomposition, unit)
            if config.run.save_frames:
                record["frames"] = self._save_frames(attempts, record)
            emit(record)
        if config.run.export_grasps:
            from .export import write_acronym

            grasps_dir = Path(config.run.out).expanduser() / "grasps"
            grasps_dir.mkdir(parents=True, exist_ok=True)
            write_acronym(grasps_dir / f"{spec.id}_{unit.task}_{unit.trial:04d}.h5", spec, cloud, candidates,
                          scored_by_method, executed_by_method)

    def _save_frames(self, attempts, record: dict[str, Any]) -> dict[str, str]:
        """PNG images of every attempt: at contact and after the lift, or at the moment it failed
        (``failed_<phase>``), since failures are what a user looks at. Keys are the final
        attempt's moments, and ``attempt<k>_<moment>`` for the earlier attempts; paths are
        relative to the run."""
        from PIL import Image

        out_dir = Path(self.config.run.out).expanduser()
        frames_dir = out_dir / "frames"
        frames_dir.mkdir(parents=True, exist_ok=True)
        saved = {}
        for number, attempt in enumerate(attempts, start=1):
            prefix = "" if number == len(attempts) else f"attempt{number}_"
            for moment, image in attempt.details.get("frames", {}).items():
                path = frames_dir / f"{record['object']}_{record['task']}_{record['method']}_{record['trial']:04d}_{prefix}{moment}.png"
                Image.fromarray(np.asarray(image, dtype=np.uint8)).save(path)
                saved[f"{prefix}{moment}"] = str(path.relative_to(out_dir))
        return saved

    def _model_client(self):
        """The rater's own model client, so VLM-Direct never loads a second copy of the model."""
        from .vlm_direct import get_vd_client

        rater = getattr(self.rater, "inner", self.rater)
        return rater.client if hasattr(rater, "client") else get_vd_client(self.config.rating)

    def _fill_outcome(self, record, candidates: GraspCandidates, order, attempts, cloud, rating, decomposition, unit) -> None:
        record["attempts"] = len(attempts)
        record["attempt_log"] = [
            {"candidate": int(candidates.candidate_id[i]), "success": a.success, "failure_reason": a.failure_reason,
             **_jsonable(a.details)}
            for i, a in zip(order, attempts)
        ]
        final_index = int(order[len(attempts) - 1])
        final = attempts[-1]
        grasp = candidates.record(final_index)
        grasp["midpoint_object"] = cloud.in_object_frame(np.asarray(grasp["position"])).tolist()
        record["grasp"] = grasp
        record["success"] = bool(final.success)
        record["failure_reason"] = final.failure_reason
        # PZA uses the published single zone of the contact midpoint; AC ("outside every avoid zone")
        # uses every zone the midpoint lies in (its third or protrusion, and its sides), as S_avoid does.
        zone_names = decomposition.candidate_zone_names(candidates.position_world[final_index:final_index + 1])[0]
        grasp["zones"] = list(zone_names)
        record["in_preferred_zone"] = grasp["zone"] is not None and rating.prefers(grasp["zone"])
        record["in_avoid_zone"] = any(rating.avoids(name) for name in zone_names)
        # FRA/FAR measure the grasp against the object's annotated parts, not the pipeline's own zones.
        record.update(region_membership(record["object"], np.asarray(grasp["midpoint_object"])))
        outcome = judge_task(
            unit.task, record["success"], bool(record["in_preferred_zone"]), final.orientation_change_deg,
            final.details.get("distractors_max_displacement_m", 0.0), self.config.tasks,
        )
        record.update(dataclasses.asdict(outcome))


def _jsonable(details: dict[str, Any]) -> dict[str, Any]:
    """Attempt details without images (frames are written as files, not into JSON)."""
    out = {}
    for key, value in details.items():
        if key == "frames":
            continue
        if isinstance(value, (np.floating, np.integer)):
            value = value.item()
        if isinstance(value, np.ndarray):
            value = value.tolist()
        out[key] = value
    return out
