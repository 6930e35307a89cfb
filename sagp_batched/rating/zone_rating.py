"""The validated zone rating every backend returns, and the errors of the rating layer."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from ..types import general_zone, is_zone_name

# Published stage 4: rating levels and their affordance value phi.
PHI: dict[str, float] = {"good": 1.0, "acceptable": 0.5, "bad": -0.5, "dangerous": -1.0}
RATING_LEVELS: tuple[str, ...] = tuple(PHI)
# Direction the gripper comes from: "top" (moving down), "side" (any horizontal approach), a named
# side of the object (the gripper moves toward it from outside), "any", or "vector" with a world vector.
APPROACH_NAMES: tuple[str, ...] = ("top", "side", "front", "back", "left", "right", "any", "vector")
GRASP_STYLES: tuple[str, ...] = ("pinch", "power", "wrap", "hook", "any")
# "ok": the answer validated as given; "repaired": safe repairs were made (listed in ``issues``);
# "neutral": nothing trustworthy was left, the rating is neutral (SAGP falls back to geometry).
OUTCOMES: tuple[str, ...] = ("ok", "repaired", "neutral")
# How a model was asked to answer: "json_schema" (the server constrained the answer to the zone
# answer's JSON schema), "plain" (the prompt alone asked for JSON); "" when no model answer was read
# (a prior, the oracle, no answer at all, or a rating cached before the mode was recorded).
OUTPUT_MODES: tuple[str, ...] = ("json_schema", "plain", "")
# Text that reaches a trial record or the cache from outside (a model's answer, a server's error) is
# cut to this many characters: an issue quotes what was wrong, it does not carry it.
MAX_ISSUE_CHARS = 200
# A neutral rating's reason joins the issues of one answer, each of them clipped.
MAX_REASON_CHARS = 1000


def clipped(text: str, limit: int = MAX_ISSUE_CHARS) -> str:
    """``text`` cut to ``limit`` characters, saying how long it was when cut."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


class RatingError(RuntimeError):
    """A rating request is malformed (unknown task, bad image) or a backend is misconfigured."""


class VLMRequestError(RuntimeError):
    """A model backend gave no answer (timeout, HTTP error, generation failure) after its retries."""


@dataclass(frozen=True)
class RatingProvenance:
    backend: str  # "transformers" | "openai" | "prior"
    model: str
    prompt_version: str
    latency_s: float
    outcome: str  # one of OUTCOMES
    output_mode: str = ""  # one of OUTPUT_MODES
    # Where an answer was read from does not change which answer it is.
    cached: bool = field(default=False, compare=False)


@dataclass(frozen=True)
class ZoneRating:
    """Ratings of the coarse zones of one object for one task.

    ``ratings`` maps zone names to levels of ``RATING_LEVELS``; a zone without a rating is unrated
    (phi 0). ``approach_vector_world`` is set only when ``approach == "vector"``. ``max_tilt_deg`` is the
    orientation constraint (None: unconstrained).
    """

    ratings: dict[str, str]
    preferred: frozenset[str]
    avoid: frozenset[str]
    approach: str
    grasp_style: str
    max_tilt_deg: float | None
    provenance: RatingProvenance
    approach_vector_world: tuple[float, float, float] | None = None
    issues: tuple[str, ...] = ()
    raw_text: str = field(default="", compare=False)

    @property
    def is_neutral(self) -> bool:
        return self.provenance.outcome == "neutral"

    def level(self, zone: str) -> str | None:
        """The rating level of ``zone``: its own, else (for ``protrusion_<n>``) that of ``protrusion``; None if unrated."""
        if zone in self.ratings:
            return self.ratings[zone]
        general = general_zone(zone)
        return self.ratings.get(general) if general else None

    def prefers(self, zone: str) -> bool:
        """``zone`` is in the preferred set, itself or through ``protrusion`` (unless avoided by name)."""
        return zone in self.preferred or (general_zone(zone) in self.preferred and zone not in self.avoid)

    def avoids(self, zone: str) -> bool:
        """``zone`` is in the avoid set, itself or through ``protrusion`` (unless preferred by name)."""
        return zone in self.avoid or (general_zone(zone) in self.avoid and zone not in self.preferred)

    def provenance_dict(self) -> dict[str, Any]:
        """Where the rating came from, for trial records: backend, model, prompt version, latency, outcome,
        output mode, cache, issues."""
        return {**dataclasses.asdict(self.provenance), "issues": list(self.issues)}

    def to_dict(self) -> dict[str, Any]:
        return {
            "ratings": dict(sorted(self.ratings.items())),
            "preferred": sorted(self.preferred),
            "avoid": sorted(self.avoid),
            "approach": self.approach,
            "approach_vector_world": list(self.approach_vector_world) if self.approach_vector_world else None,
            "grasp_style": self.grasp_style,
            "max_tilt_deg": self.max_tilt_deg,
            "issues": list(self.issues),
            "provenance": {
                "backend": self.provenance.backend,
                "model": self.provenance.model,
                "prompt_version": self.provenance.prompt_version,
                "latency_s": self.provenance.latency_s,
                "outcome": self.provenance.outcome,
                "output_mode": self.provenance.output_mode,
            },
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], cached: bool = False) -> "ZoneRating":
        """Strict inverse of ``to_dict``; raises ``RatingError`` on anything out of vocabulary.

        A stored rating without ``provenance.output_mode`` (written before it was recorded) reads as ""."""
        try:
            ratings = {str(k): str(v) for k, v in data["ratings"].items()}
            preferred = frozenset(data["preferred"])
            avoid = frozenset(data["avoid"])
            provenance = RatingProvenance(cached=cached, **data["provenance"])
            vector = data["approach_vector_world"]
            rating = cls(
                ratings=ratings, preferred=preferred, avoid=avoid, approach=data["approach"],
                grasp_style=data["grasp_style"],
                max_tilt_deg=None if data["max_tilt_deg"] is None else float(data["max_tilt_deg"]),
                provenance=provenance, approach_vector_world=tuple(float(x) for x in vector) if vector else None,
                issues=tuple(data["issues"]),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise RatingError(f"stored rating is malformed: {exc!r}") from exc
        bad = [
            *(f"zone {z}" for z in [*ratings, *preferred, *avoid] if not is_zone_name(z)),
            *(f"level {v}" for v in ratings.values() if v not in PHI),
            *([f"approach {rating.approach}"] if rating.approach not in APPROACH_NAMES else []),
            *([f"grasp style {rating.grasp_style}"] if rating.grasp_style not in GRASP_STYLES else []),
            *([f"outcome {provenance.outcome}"] if provenance.outcome not in OUTCOMES else []),
            *([f"output mode {provenance.output_mode}"] if provenance.output_mode not in OUTPUT_MODES else []),
            *(["vector approach without a vector"] if (rating.approach == "vector") != (rating.approach_vector_world is not None) else []),
        ]
        if bad:
            raise RatingError(f"stored rating holds values out of vocabulary: {', '.join(bad)}")
        return rating


def neutral_rating(backend: str, model: str, prompt_version: str, latency_s: float, reason: str, raw_text: str = "") -> ZoneRating:
    """The rating that says nothing: no zone rated, no sets, any approach, no orientation constraint.

    ``reason`` is clipped to ``MAX_REASON_CHARS``: it may quote a server's or a model's words."""
    return ZoneRating(
        ratings={}, preferred=frozenset(), avoid=frozenset(), approach="any", grasp_style="any", max_tilt_deg=None,
        provenance=RatingProvenance(backend, model, prompt_version, latency_s, "neutral"),
        issues=(clipped(reason, MAX_REASON_CHARS),), raw_text=raw_text,
    )
