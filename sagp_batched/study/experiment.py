"""One trial of the study: perceive, plan once, rank by each method, execute, record.

A *unit* is one (object, task, trial): the scene, the cloud and the candidate set are shared by
every method of the unit, so all methods rank the identical candidates, as the published comparison requires.
Each method's result is one ``TrialRecord`` (``records.py``). A unit returns its records with the
contents of the files they name (the grasp export, the attempt images), and the study's driver writes
both into the run directory: a worker never writes there, wherever it runs.
"""
from __future__ import annotations

import io
import signal
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np
from PIL import Image

from ..config import Config
from ..execution.pick import execute_ranked
from ..formats.acronym import trial_file_bytes
from ..grasps import GraspCandidates
from ..planning import plan
from ..rating import get_rater
from ..robot.description import robot_of
from ..rating.zone_rating import ZoneRating, clipped, neutral_rating
from ..seeds import candidate_seed
from ..semantics.vlm_direct import get_vd_client
from ..semantics.zone_descriptions import describe_zones
from ..semantics.zone_marks import rating_image
from ..semantics.zones import assign_zones
from ..types import GraspAttempt, PerceivedCloud, PerceptionFailure
from ..world.objects import ObjectSet, ObjectSpec
from ..world.perception import capture
from ..world.scene import Scene
from .judging import judge_task, place_grasp
from .methods import RankingInputs, get_method
from .records import STAGE_TIMES, ExecutedGrasps, PlanSummary, TrialRecord, TrialUnit


class TrialTimeout(RuntimeError):
    """A trial ran past ``config.run.trial_timeout_s``."""


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


GRASPS_DIR = "grasps"
FRAMES_DIR = "frames"


@dataclass
class UnitResult:
    """What one unit produced: its records, and the files they name as run-relative POSIX path -> contents."""

    records: list[TrialRecord] = field(default_factory=list)
    files: dict[str, bytes] = field(default_factory=dict)


def grasps_file(object_id: str, task: str, trial: int) -> str:
    """The run-relative path of a unit's grasp export (``run.export_grasps``)."""
    return f"{GRASPS_DIR}/{object_id}_{task}_{trial:04d}.h5"


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
            self._scene = Scene(self.config, gui=self.config.run.gui)
        return self._scene

    @property
    def rater(self):
        if self._rater is None:
            self._rater = get_rater(self.config.rating)
        return self._rater

    def run_unit(self, unit: TrialUnit) -> UnitResult:
        """Run every method of ``unit``: a record per method, and the files the records name.

        A failure inside the unit (an exception or the time limit) is recorded on every method
        of the unit without a record yet, and the caller goes on with the next unit.
        """
        spec = self.objects.get(unit.object_id)
        result = UnitResult()
        try:
            with time_limit(self.config.run.trial_timeout_s):
                self._run_unit(spec, unit, result)
        except Exception as exc:  # recorded, never lost: the run goes on with the next unit
            message = f"{type(exc).__name__}: {exc}"
            recorded = {record.method for record in result.records}
            for method in unit.methods:
                if method not in recorded:
                    result.records.append(TrialRecord.build(spec, unit, method, self.config, error=message,
                                                            traceback=traceback.format_exc(limit=8)))
        # The images are in ``result.files`` as PNG once encoded; the raw arrays would only be carried back to
        # the driver for nothing (a record never writes them).
        for record in result.records:
            for attempt in record.executed.attempts if record.executed is not None else ():
                attempt.frames = {}
        return result

    def _distractors_for(self, unit: TrialUnit) -> list[ObjectSpec]:
        if unit.task != "t3":
            return []
        return list(self.objects.distractors())

    def _run_unit(self, spec: ObjectSpec, unit: TrialUnit, result: UnitResult) -> None:
        config, scene = self.config, self.scene
        emit = result.records.append
        scene.reset(spec, unit.trial, distractors=self._distractors_for(unit))

        start = time.perf_counter()
        try:
            cloud = capture(scene, config)
        except PerceptionFailure as failure:
            for method in unit.methods:
                emit(TrialRecord.build(spec, unit, method, config, failure_reason=f"perception:{failure.reason}"))
            return
        perception_s = time.perf_counter() - start

        start = time.perf_counter()
        planned = plan(cloud, config, seed=candidate_seed(config, unit.trial))
        candidates = planned.candidates
        decomposition, candidates = assign_zones(cloud, candidates, config.zones)
        geometry_s = time.perf_counter() - start

        # Rated for every method, GO included: PZA and AC of GO are measured against the same zones.
        rating, rating_failure, rating_s = self._rate(spec, unit, cloud, decomposition)

        ranked_by_method: dict[str, GraspCandidates] = {}
        attempts_by_method: dict[str, list] = {}
        executed: dict[int, GraspAttempt] = {}  # candidate id -> its attempt, shared by the methods that try it
        for method in unit.methods:
            declared = get_method(method)
            if rating_failure is not None and declared.uses_rating:
                emit(TrialRecord.build(spec, unit, method, config, error=rating_failure[0], traceback=rating_failure[1]))
                continue
            method_start = time.perf_counter()
            ranked = declared.rank(
                RankingInputs(candidates, cloud, rating, decomposition, spec.name, unit.task, config, self._model_client)
            )
            ranked_by_method[method] = ranked
            method_rating_s = rating_s if declared.plan_time_counts_rating else 0.0
            times = (perception_s, geometry_s, method_rating_s, geometry_s + method_rating_s + time.perf_counter() - method_start)
            summary = PlanSummary(planned.counts.as_dict(), dict(zip(STAGE_TIMES, times)), rating.provenance_dict())
            if len(ranked) == 0:
                emit(TrialRecord.build(spec, unit, method, config, plan=summary, failure_reason="no_candidates"))
                continue
            executed_grasps = self._execute(ranked, cloud, rating, unit, method, executed, result.files)
            attempts_by_method[method] = executed_grasps.attempts
            emit(TrialRecord.build(spec, unit, method, config, plan=summary, executed=executed_grasps))
        if config.run.export_grasps:
            result.files[grasps_file(spec.id, unit.task, unit.trial)] = trial_file_bytes(
                spec, cloud, candidates, ranked_by_method, attempts_by_method, robot_of(config).gripper)

    def _rate(self, spec: ObjectSpec, unit: TrialUnit, cloud: PerceivedCloud, decomposition) -> tuple[ZoneRating, tuple[str, str] | None, float]:
        """(rating, (error, traceback) when the rater raised, seconds) of the unit's zones. A failed
        rating is neutral: it fails the methods that rank by the rating only, the others run on."""
        config = self.config
        start = time.perf_counter()
        rating_failure: tuple[str, str] | None = None
        try:
            # Only a ground-truth rater (the oracle, an upper bound) is handed the object's true pose.
            zone_points = _zone_points_object(cloud, decomposition) if self.rater.uses_ground_truth else None
            # What the model sees: the crop with the zones drawn on it (set-of-mark prompting), or the plain crop.
            shown = rating_image(cloud, decomposition, config.rating)
            rating = self.rater.rate(spec.id, spec.name, unit.task, shown, describe_zones(decomposition), zone_points)
        except TrialTimeout:
            raise
        except Exception as exc:  # recorded on the methods that need the rating
            rating_failure = (f"rating failed: {type(exc).__name__}: {clipped(str(exc))}", traceback.format_exc(limit=8))
            # Named after the rater where it was built (a failed build leaves the configured backend and model).
            rater = self._rater
            rating = neutral_rating(getattr(rater, "backend", config.rating.backend), getattr(rater, "model", config.rating.model),
                                    getattr(rater, "prompt_version", ""), time.perf_counter() - start, rating_failure[0])
        return rating, rating_failure, time.perf_counter() - start

    def _execute(self, ranked: GraspCandidates, cloud: PerceivedCloud, rating: ZoneRating, unit: TrialUnit, method: str,
                 executed: dict[int, GraspAttempt], files: dict[str, bytes]) -> ExecutedGrasps:
        """Execute the leading grasps of ``ranked`` (reusing the unit's attempts in ``executed``) and judge the
        last one tried; the attempts' images (``run.save_frames``) go into ``files``."""
        config = self.config
        attempts = execute_ranked(self.scene, config, ranked, record_frames=config.run.save_frames, executed=executed)
        final_index = len(attempts) - 1
        final, final_grasp = attempts[-1], ranked[final_index]
        placement = place_grasp(unit.object_id, final_grasp, ranked[final_index:final_index + 1].transform(cloud.object_from_world, "object")[0], rating)
        outcome = judge_task(
            unit.task, final.success, placement.in_preferred_zone, final.orientation_change_deg,
            final.diagnostics.distractors_max_displacement_m, config.tasks,
        )
        frames = _encode_frames(attempts, unit, method, files) if config.run.save_frames else None
        return ExecutedGrasps([ranked[i] for i in range(len(attempts))], attempts, placement, outcome, frames)

    def _model_client(self):
        """The rater's own model client, so VLM-Direct never loads a second copy of the model."""
        rater = getattr(self.rater, "inner", self.rater)
        return rater.client if hasattr(rater, "client") else get_vd_client(self.config.rating)


def _encode_frames(attempts: list[GraspAttempt], unit: TrialUnit, method: str, files: dict[str, bytes]) -> dict[str, str]:
    """PNG images of every attempt, into ``files``: at contact and after the lift, or at the moment it
    failed (``failed_<phase>``), since failures are what a user looks at. Keys are the final attempt's
    moments, and ``attempt<k>_<moment>`` for the earlier attempts; values are the run-relative paths."""
    saved = {}
    for number, attempt in enumerate(attempts, start=1):
        prefix = "" if number == len(attempts) else f"attempt{number}_"
        for moment, image in attempt.frames.items():
            path = f"{FRAMES_DIR}/{unit.object_id}_{unit.task}_{method}_{unit.trial:04d}_{prefix}{moment}.png"
            encoded = io.BytesIO()
            Image.fromarray(np.asarray(image, dtype=np.uint8)).save(encoded, format="PNG")
            files[path] = encoded.getvalue()
            saved[f"{prefix}{moment}"] = path
    return saved
