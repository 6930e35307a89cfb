"""Zone raters: one interface, a model-backed rater, the offline prior, and a persistent cache."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import tempfile
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from ..config import RatingConfig
from ..types import SIDE_ZONES
from .parse import parse_zone_rating
from .prompt import (
    ZONE_ANSWER_SCHEMA_NAME,
    answer_zone_names,
    build_zone_prompt,
    checked_image,
    prompt_version,
    task_description,
    zone_answer_schema,
)
from .zone_rating import RatingError, RatingProvenance, VLMRequestError, ZoneRating, neutral_rating
from .vlm import VLMClient, answer_endpoint, get_vlm_client

log = logging.getLogger(__name__)


class Rater(ABC):
    """Rates the coarse zones of an object for a task."""

    backend: str
    model: str
    prompt_version: str
    # The server its answers come from where backend and model do not name the source (an
    # OpenAI-compatible endpoint serves whatever it serves under a model's name); "" otherwise.
    endpoint: str = ""
    # A rater that reads the simulation's ground truth (the object's pose) is an upper bound, never a model.
    uses_ground_truth: bool = False

    @abstractmethod
    def rate(
        self,
        object_id: str,
        object_name: str,
        task: str,
        crop_rgb: np.ndarray,
        zone_descriptions: Mapping[str, str],
        zone_points_object: Mapping[str, np.ndarray] | None = None,
    ) -> ZoneRating:
        """A validated rating; never raises for a bad model answer (that gives a neutral rating).

        ``zone_points_object`` (zone name -> (M, 3) points in the object's own frame) is handed
        only to raters that use the ground truth."""


class VLMRater(Rater):
    """Asks a vision-language model with the structured zone prompt and validates its answer.

    The answer is asked to match ``zone_answer_schema()`` where the backend can enforce it; the
    rating's ``provenance.output_mode`` records whether it did. The parser validates either way.

    The client is built on the first question, so a run whose ratings are all cached never loads
    a model. ``zone_marks``: the images it is given carry the zones (``zone_marks.draw_zone_marks``),
    so the prompt points at them and is versioned apart from the plain-crop prompt. ``endpoint``:
    the server ``connect`` reaches, if any (``vlm.answer_endpoint``).
    """

    def __init__(
        self, backend: str, model: str, upright_max_tilt_deg: float, connect: Callable[[], VLMClient], zone_marks: bool = False,
        endpoint: str = "",
    ):
        self.backend = backend
        self.model = model
        self.endpoint = endpoint
        self.upright_max_tilt_deg = upright_max_tilt_deg
        self.zone_marks = zone_marks
        self.prompt_version = prompt_version(zone_marks)
        self._connect = connect
        self._client: VLMClient | None = None

    @property
    def client(self) -> VLMClient:
        if self._client is None:
            self._client = self._connect()
        return self._client

    def rate(self, object_id, object_name, task, crop_rgb, zone_descriptions, zone_points_object=None):
        prompt = build_zone_prompt(object_name, task, zone_descriptions, marked=self.zone_marks)
        image = checked_image(crop_rgb)
        client = self.client
        start = time.perf_counter()
        try:
            answer = client.generate_json(image, prompt, ZONE_ANSWER_SCHEMA_NAME, zone_answer_schema())
        except VLMRequestError as exc:
            log.warning("no rating for %s/%s from %s: %s", object_id, task, self.model, exc)
            return neutral_rating(self.backend, self.model, self.prompt_version, time.perf_counter() - start, f"no answer: {exc}")
        latency = time.perf_counter() - start
        rating = parse_zone_rating(answer.text, self.backend, self.model, self.prompt_version, latency, self.upright_max_tilt_deg,
                                   answer_zone_names(zone_descriptions))
        return dataclasses.replace(rating, provenance=dataclasses.replace(rating.provenance, output_mode=answer.output_mode))


class PriorRater(Rater):
    """Zone ratings written down from how people hold each object: a prior, not a model.

    The table lives in ``sagp_batched/data/zone_priors.json``; an object or task it lacks gets the
    neutral rating, under which SAGP ranks by geometry and reachability alone.
    """

    backend = "prior"

    def __init__(self, table_path: str | Path | None = None):
        if table_path is None:
            text = resources.files("sagp_batched").joinpath("data/zone_priors.json").read_text()
            self.model = "zone_priors.json"
        else:
            text = Path(table_path).read_text()
            self.model = Path(table_path).name
        table = json.loads(text)
        # The content hash makes an edited table a new cache key even if its version was not bumped.
        self.prompt_version = f"prior-{table['version']}-{hashlib.sha256(text.encode()).hexdigest()[:12]}"
        self._objects: dict[str, Any] = table["objects"]
        for object_id, tasks in self._objects.items():
            for task, entry in tasks.items():
                if task.startswith("_"):
                    continue
                task_description(task)
                self._entry_rating(entry, f"{object_id}/{task}")

    def _entry_rating(self, entry: dict[str, Any], where: str) -> ZoneRating:
        data = {
            **{"approach_vector_world": None, "issues": [], "max_tilt_deg": None}, **entry,
            "provenance": {"backend": self.backend, "model": self.model, "prompt_version": self.prompt_version,
                           "latency_s": 0.0, "outcome": "ok"},
        }
        try:
            return ZoneRating.from_dict(data)
        except RatingError as exc:
            raise RatingError(f"zone prior {where} is invalid: {exc}") from exc

    def rate(self, object_id, object_name, task, crop_rgb, zone_descriptions, zone_points_object=None):
        task_description(task)
        entry = self._objects.get(object_id, {}).get(task)
        if entry is None:
            return neutral_rating(self.backend, self.model, self.prompt_version, 0.0, f"no prior for {object_id}/{task}")
        return self._entry_rating(entry, f"{object_id}/{task}")


class CachedRater(Rater):
    """Persistent cache around a rater, one JSON file per (object, task, backend, model, prompt version,
    and endpoint where the rater has one); an entry is served only for the key it records.

    Files are written atomically (temporary file + rename) and carry a SHA-256 of their rating; an
    entry that fails to parse, to match its hash or to validate is logged and asked again. Neutral
    ratings are not stored: they record a failure to rate, which the next run should retry. Beside
    each entry, with the same stem, lies the image the rater was given (``.png``), so a user can see
    what the model was shown.
    ``queries`` counts the questions that reached the wrapped rater.
    """

    def __init__(self, inner: Rater, cache_dir: str | Path):
        self.inner = inner
        self.backend, self.model, self.prompt_version, self.endpoint = inner.backend, inner.model, inner.prompt_version, inner.endpoint
        self.cache_dir = Path(cache_dir).expanduser()
        self.queries = 0

    def _key(self, object_id: str, task: str) -> dict[str, str]:
        """What an entry answers; the endpoint joins it only where there is one, so the key of an
        endpoint-less backend is its object, task, backend, model and prompt version alone."""
        key = {"object_id": object_id, "task": task, "backend": self.backend, "model": self.model,
               "prompt_version": self.prompt_version}
        return {**key, "endpoint": self.endpoint} if self.endpoint else key

    def _path(self, object_id: str, task: str) -> Path:
        digest = hashlib.sha256(json.dumps(list(self._key(object_id, task).values())).encode()).hexdigest()[:24]
        return self.cache_dir / f"{object_id}__{task}__{self.backend}__{digest}.json"

    @staticmethod
    def _digest(rating: dict[str, Any]) -> str:
        return hashlib.sha256(json.dumps(rating, sort_keys=True).encode()).hexdigest()

    def _load(self, path: Path, key: dict[str, str]) -> ZoneRating | None:
        if not path.is_file():
            return None
        try:
            stored = json.loads(path.read_text())
            if stored["sha256"] != self._digest(stored["rating"]):
                raise RatingError("hash mismatch")
            if stored["key"] != key:
                raise RatingError(f"entry answers {stored['key']!r:.300}, not {key!r}")
            return ZoneRating.from_dict(stored["rating"], cached=True)
        except (ValueError, KeyError, TypeError, RatingError) as exc:
            log.warning("unusable rating cache entry %s (%s); asking again", path, exc)
            return None

    def _write_atomically(self, path: Path, write: Callable[[Any], None]) -> None:
        """``write(binary_handle)`` into a temporary file of ``cache_dir``, then rename it to ``path``."""
        self.cache_dir.mkdir(parents=True, exist_ok=True)
        descriptor, temporary = tempfile.mkstemp(dir=self.cache_dir, prefix=".tmp-", suffix=path.suffix)
        try:
            with os.fdopen(descriptor, "wb") as handle:
                write(handle)
            os.replace(temporary, path)
        except BaseException:
            Path(temporary).unlink(missing_ok=True)
            raise

    def _store(self, path: Path, key: dict[str, str], rating: ZoneRating, image: np.ndarray) -> None:
        record = rating.to_dict()
        payload = {"key": key, "sha256": self._digest(record), "rating": record}
        # The image first: an entry on disk always has the picture it was rated from beside it.
        shown = Image.fromarray(checked_image(image))
        self._write_atomically(path.with_suffix(".png"), lambda handle: shown.save(handle, format="PNG"))
        self._write_atomically(path, lambda handle: handle.write(json.dumps(payload, indent=1).encode()))

    def rate(self, object_id, object_name, task, crop_rgb, zone_descriptions, zone_points_object=None):
        task_description(task)
        key, path = self._key(object_id, task), self._path(object_id, task)
        cached = self._load(path, key)
        if cached is not None:
            return cached
        self.queries += 1
        rating = self.inner.rate(object_id, object_name, task, crop_rgb, zone_descriptions)
        if not rating.is_neutral:
            self._store(path, key, rating, crop_rgb)
        return rating


class OracleRater(Rater):
    """UPPER BOUND, not a model: rates each zone from how much of it lies in the object's annotated
    functional and avoid regions (``functional_regions``), using the simulation's ground-truth pose.

    It answers how far the zone layer can carry a perfect rater. A zone mostly (>= half its points)
    in the functional region is good and preferred, mostly in the avoid region dangerous and
    avoided, partly (>= ``partial_share``) in the avoid region and not as much in the functional
    region bad, else acceptable. A zone holding a share of both says nothing about either; calling
    it bad would, under the danger-dominates scoring, mark the good part it holds down with the
    bad one. Side halves (left, right, front, back) are acceptable: each crosses every third, so a
    half rated by its content would lend that rating to every third it crosses (the half of a
    lying clamp that holds its handles would make its middle as good as its handle end). An object
    without annotations gets the neutral rating. Its ratings depend on the trial's zones, so they
    are never cached.
    """

    backend = "oracle"
    model = "annotated functional regions (upper bound)"
    uses_ground_truth = True
    majority_share = 0.5
    partial_share = 0.2

    def __init__(self, upright_max_tilt_deg: float):
        from ..world.functional_regions import load_regions

        self.regions = load_regions()
        self.prompt_version = f"oracle-{hashlib.sha256(json.dumps(sorted(self.regions)).encode()).hexdigest()[:12]}"
        self.upright_max_tilt_deg = upright_max_tilt_deg

    def rate(self, object_id, object_name, task, crop_rgb, zone_descriptions, zone_points_object=None):
        task_description(task)
        if object_id not in self.regions:
            return neutral_rating(self.backend, self.model, self.prompt_version, 0.0, f"no annotated regions for {object_id}")
        if zone_points_object is None:
            raise RatingError("the oracle rater needs the zones' points in the object frame")
        start = time.perf_counter()
        annotation = self.regions[object_id]
        ratings, preferred, avoid = {}, set(), set()
        for zone, points in zone_points_object.items():
            if len(points) == 0:
                continue
            if zone in SIDE_ZONES:
                ratings[zone] = "acceptable"
                continue
            functional = float(annotation.contains("functional", points).mean())
            avoided = float(annotation.contains("avoid", points).mean())
            if functional >= self.majority_share:
                ratings[zone] = "good"
                preferred.add(zone)
            elif avoided >= self.majority_share:
                ratings[zone] = "dangerous"
                avoid.add(zone)
            else:
                ratings[zone] = "bad" if avoided >= self.partial_share and functional < self.partial_share else "acceptable"
        return ZoneRating(
            ratings=ratings, preferred=frozenset(preferred), avoid=frozenset(avoid), approach="any", grasp_style="any",
            # The functional task's own tolerance (keep the object upright), not privileged knowledge.
            max_tilt_deg=self.upright_max_tilt_deg if task == "t2" else None,
            provenance=RatingProvenance(self.backend, self.model, self.prompt_version, time.perf_counter() - start, "ok"),
        )


def get_rater(config: RatingConfig) -> Rater:
    """The rater of ``config.backend`` (``prior``, ``transformers``, ``openai``, or the upper-bound
    ``oracle``), cached if ``config.use_cache`` (never the oracle, whose ratings follow each trial's zones)."""
    if config.backend == "oracle":
        return OracleRater(config.upright_max_tilt_deg)
    if config.backend == "prior":
        rater: Rater = PriorRater()
    elif config.backend in ("transformers", "openai"):
        rater = VLMRater(
            config.backend, config.model, config.upright_max_tilt_deg, lambda: get_vlm_client(config), config.zone_marks,
            answer_endpoint(config),
        )
    else:
        raise RatingError(f"unknown rating backend '{config.backend}' (known: prior, transformers, openai, oracle)")
    return CachedRater(rater, config.cache_dir) if config.use_cache else rater
