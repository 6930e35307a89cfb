"""Model output is untrusted input: extract, repair where safe, validate, or say it is neutral.

Every deviation is logged and recorded in the rating's ``issues``; nothing is invented: a missing
field takes its neutral value (no zone rated, empty sets, any approach, no constraint). Reading the
answer is bounded work (``json_answer``); items the validation drops are counted, not listed, and
what an issue quotes from the answer is clipped (``types.clipped``).
"""
from __future__ import annotations

import logging
import math
from collections.abc import Collection
from typing import Any

from .json_answer import MAX_ANSWER_CHARS, MAX_NUMBER_CHARS, excerpt, extract_json_object
from .zone_rating import APPROACH_NAMES, GRASP_STYLES, PHI, RatingProvenance, ZoneRating, clipped, neutral_rating

log = logging.getLogger(__name__)


class _Issues:
    """The deviations of one answer: each repair noted once (clipped), and each kind of dropped item
    counted with its first example, since an answer can hold thousands of them."""

    def __init__(self, repairs: list[str]):
        self.notes = [clipped(note) for note in repairs]
        self._dropped: dict[str, list[Any]] = {}

    def note(self, text: str) -> None:
        self.notes.append(clipped(text))

    def drop(self, kind: str, example: object) -> None:
        self._dropped.setdefault(kind, [0, excerpt(example)])[0] += 1

    def all(self) -> list[str]:
        return self.notes + [f"{kind} dropped: {count} (first {example})" for kind, (count, example) in self._dropped.items()]


def _zone_name(value: object, known_zones: Collection[str]) -> str | None:
    """``value`` as one of ``known_zones`` (case and surrounding blanks aside), else None."""
    if not isinstance(value, str):
        return None
    name = value.strip().lower()
    return name if name in known_zones else None


def _zone_list(value: Any, field_name: str, known_zones: Collection[str], issues: _Issues) -> set[str]:
    if value is None:
        issues.note(f"missing field '{field_name}', taken as empty")
        return set()
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list):
        issues.note(f"'{field_name}' is not a list of zone names, taken as empty")
        return set()
    zones = set()
    for item in value:
        zone = _zone_name(item, known_zones)
        if zone is None:
            issues.drop(f"unknown zones in '{field_name}'", item)
        else:
            zones.add(zone)
    return zones


def _ratings(value: Any, known_zones: Collection[str], issues: _Issues) -> dict[str, str]:
    if not isinstance(value, dict):
        issues.note("missing or malformed field 'ratings', no zone rated")
        return {}
    ratings: dict[str, str] = {}
    ambiguous: set[str] = set()
    for zone, level in value.items():
        zone_name = _zone_name(zone, known_zones)
        level_name = level.strip().lower() if isinstance(level, str) else None
        if zone_name is None:
            issues.drop("unknown zones in 'ratings'", zone)
        elif level_name not in PHI:
            issues.drop("unknown levels in 'ratings'", level)
        elif ratings.setdefault(zone_name, level_name) != level_name:
            ambiguous.add(zone_name)
    if ambiguous:
        # Two levels for one zone (written in two cases) say nothing about it: it stays unrated.
        issues.note(f"zones rated twice with different levels left unrated: {sorted(ambiguous)}")
        for zone_name in ambiguous:
            del ratings[zone_name]
    return ratings


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _number(value: Any) -> float | None:
    """``value`` as a float: a JSON number, or a short string that spells one; else None."""
    if _is_number(value):
        return float(value)
    if isinstance(value, str) and len(value) <= MAX_NUMBER_CHARS:
        try:
            return float(value)
        except ValueError:
            return None
    return None


def _approach(value: Any, issues: _Issues) -> tuple[str, tuple[float, float, float] | None]:
    if value is None:
        issues.note("missing field 'approach', taken as any")
        return "any", None
    if isinstance(value, list):
        vector = tuple(float(x) for x in value) if len(value) == 3 and all(map(_is_number, value)) else ()
        norm = math.sqrt(sum(x * x for x in vector)) if vector else 0.0
        if math.isfinite(norm) and norm > 0.0:
            return "vector", tuple(x / norm for x in vector)  # type: ignore[return-value]
        issues.note(f"approach {excerpt(value)} is not a non-zero 3-vector, taken as any")
        return "any", None
    name = value.strip().lower() if isinstance(value, str) else None
    if name in APPROACH_NAMES and name != "vector":
        return name, None
    issues.note(f"unknown approach {excerpt(value)}, taken as any")
    return "any", None


def _max_tilt(data: dict[str, Any], upright_max_tilt_deg: float, issues: _Issues) -> float | None:
    if "max_tilt_deg" not in data:
        if data.get("keep_upright") is True:
            return upright_max_tilt_deg
        issues.note("missing field 'max_tilt_deg', taken as unconstrained")
        return None
    value = data["max_tilt_deg"]
    words = value.strip().lower() if isinstance(value, str) else None
    if value is None or words in ("none", "null", ""):
        return None
    if words in ("upright", "keep upright"):
        return upright_max_tilt_deg
    tilt = _number(value)
    if tilt is None:
        issues.note(f"max_tilt_deg {excerpt(value)} is not a number, taken as unconstrained")
        return None
    if not math.isfinite(tilt) or not 0.0 <= tilt <= 180.0:
        issues.note(f"max_tilt_deg {excerpt(value)} is outside [0, 180], taken as unconstrained")
        return None
    return tilt


def _raw_text(answer: object) -> str:
    """What a rating keeps of the answer it was read from: the text itself when it was readable,
    else a short quote."""
    if isinstance(answer, str) and len(answer) <= MAX_ANSWER_CHARS:
        return answer
    return excerpt(answer) if isinstance(answer, (str, bytes, bytearray)) else ""


def parse_zone_rating(
    answer: object, backend: str, model: str, prompt_version: str, latency_s: float, upright_max_tilt_deg: float,
    known_zones: Collection[str],
) -> ZoneRating:
    """A validated ``ZoneRating`` from a model's raw answer (any value: text, bytes, None, ...);
    neutral (marked so) when nothing is usable. Never raises.

    ``known_zones``: the zone names the model was asked about (``prompt.answer_zone_names``);
    any other name is dropped and counted."""
    raw_text = _raw_text(answer)
    data, repairs = extract_json_object(answer)
    if data is None:
        reason = "; ".join(repairs)
        log.warning("%s/%s answer unusable (%s); neutral rating", backend, model, reason)
        return neutral_rating(backend, model, prompt_version, latency_s, reason, raw_text=raw_text)

    issues = _Issues(repairs)
    ratings = _ratings(data.get("ratings"), known_zones, issues)
    preferred = _zone_list(data.get("preferred"), "preferred", known_zones, issues)
    avoid = _zone_list(data.get("avoid"), "avoid", known_zones, issues)
    contradictory = preferred & avoid
    if contradictory:
        # Avoiding is the safe reading of a contradiction: a preferred zone is a bonus, an avoid zone a hazard.
        issues.note(f"zones both preferred and avoided kept as avoid only: {sorted(contradictory)}")
        preferred -= contradictory
    if not ratings and not preferred and not avoid:
        reason = "; ".join(issues.all() + ["no valid zone rating or zone set in the answer"])
        log.warning("%s/%s answer unusable (%s); neutral rating", backend, model, reason)
        return neutral_rating(backend, model, prompt_version, latency_s, reason, raw_text=raw_text)

    approach, vector = _approach(data.get("approach"), issues)
    style_value = data.get("grasp_style")
    style = style_value.strip().lower() if isinstance(style_value, str) else None
    if style not in GRASP_STYLES:
        issues.note(f"grasp style {excerpt(style_value)} unknown or missing, taken as any")
        style = "any"
    max_tilt = _max_tilt(data, upright_max_tilt_deg, issues)
    found = issues.all()
    outcome = "repaired" if found else "ok"
    if found:
        log.info("%s/%s answer repaired: %s", backend, model, "; ".join(found))
    return ZoneRating(
        ratings=ratings, preferred=frozenset(preferred), avoid=frozenset(avoid), approach=approach,
        grasp_style=style, max_tilt_deg=max_tilt,
        provenance=RatingProvenance(backend, model, prompt_version, latency_s, outcome),
        approach_vector_world=vector, issues=tuple(found), raw_text=raw_text,
    )
