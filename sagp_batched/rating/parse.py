"""Model output is untrusted input: extract, repair where safe, validate, or say it is neutral.

Every deviation is logged and recorded in the rating's ``issues``; nothing is invented: a missing
field takes its neutral value (no zone rated, empty sets, any approach, no constraint).
"""
from __future__ import annotations

import json
import logging
import math
import re
from typing import Any

from ..types import is_zone_name
from .types import APPROACH_NAMES, GRASP_STYLES, PHI, RatingProvenance, ZoneRating, neutral_rating

log = logging.getLogger(__name__)

_FENCE = re.compile(r"```(?:json|JSON)?\s*(.*?)(?:```|$)", re.DOTALL)
_CLOSERS = {"{": "}", "[": "]"}


def _close_truncated(text: str) -> str | None:
    """``text`` (starting at '{') closed after its last complete member, or None if it cannot be.

    Hand-written because json has no partial parser: scan strings and brackets, cut at the last
    comma outside a string (dropping the member being written when the answer was cut off), and
    append the closers of the brackets still open there.
    """
    stack: list[str] = []
    in_string = escaped = False
    last_cut: tuple[int, list[str]] | None = None
    for i, char in enumerate(text):
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
            continue
        if char == '"':
            in_string = True
        elif char in _CLOSERS:
            stack.append(_CLOSERS[char])
        elif char in "}]":
            if not stack or stack.pop() != char:
                return None
            if not stack:
                return text[: i + 1]
        elif char == ",":
            last_cut = (i, list(stack))
    candidates = []
    if not in_string:
        candidates.append(text.rstrip() + "".join(reversed(stack)))
    if last_cut is not None:
        candidates.append(text[: last_cut[0]] + "".join(reversed(last_cut[1])))
    for candidate in candidates:
        try:
            json.loads(candidate)
        except json.JSONDecodeError:
            continue
        return candidate
    return None


def extract_json_object(text: str) -> tuple[dict[str, Any] | None, list[str]]:
    """The first JSON object in a model's answer, and the repairs it needed (fences, prose, truncation)."""
    issues: list[str] = []
    fenced = _FENCE.search(text)
    if fenced:
        issues.append("answer was wrapped in a code fence")
        text = fenced.group(1)
    start = text.find("{")
    if start < 0:
        return None, issues + ["answer holds no JSON object"]
    if text[:start].strip():
        issues.append("prose before the JSON object was ignored")
    body = text[start:]
    try:
        value, end = json.JSONDecoder().raw_decode(body)
    except json.JSONDecodeError:
        closed = _close_truncated(body)
        if closed is None:
            return None, issues + ["answer's JSON object is malformed beyond repair"]
        issues.append("truncated JSON object was closed after its last complete member")
        value, end = json.loads(closed), len(closed)
    if body[end:].strip():
        issues.append("text after the JSON object was ignored")
    if not isinstance(value, dict):
        return None, issues + [f"answer's JSON is a {type(value).__name__}, not an object"]
    return value, issues


def _zone_list(value: Any, field_name: str, issues: list[str]) -> set[str]:
    if value is None:
        issues.append(f"missing field '{field_name}', taken as empty")
        return set()
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, (list, tuple)):
        issues.append(f"'{field_name}' is not a list of zone names, taken as empty")
        return set()
    zones = set()
    for item in value:
        name = str(item).strip().lower()
        if is_zone_name(name):
            zones.add(name)
        else:
            issues.append(f"unknown zone '{item}' in '{field_name}' dropped")
    return zones


def _approach(value: Any, issues: list[str]) -> tuple[str, tuple[float, float, float] | None]:
    if value is None:
        issues.append("missing field 'approach', taken as any")
        return "any", None
    if isinstance(value, (list, tuple)):
        try:
            vector = tuple(float(x) for x in value)
        except (TypeError, ValueError):
            vector = ()
        norm = math.sqrt(sum(x * x for x in vector)) if len(vector) == 3 else 0.0
        if len(vector) == 3 and math.isfinite(norm) and norm > 0.0:
            return "vector", tuple(x / norm for x in vector)  # type: ignore[return-value]
        issues.append(f"approach {value!r} is not a non-zero 3-vector, taken as any")
        return "any", None
    name = str(value).strip().lower()
    if name in APPROACH_NAMES and name != "vector":
        return name, None
    issues.append(f"unknown approach '{value}', taken as any")
    return "any", None


def _max_tilt(data: dict[str, Any], upright_max_tilt_deg: float, issues: list[str]) -> float | None:
    if "max_tilt_deg" not in data:
        if data.get("keep_upright") is True:
            return upright_max_tilt_deg
        issues.append("missing field 'max_tilt_deg', taken as unconstrained")
        return None
    value = data["max_tilt_deg"]
    if value is None or (isinstance(value, str) and value.strip().lower() in ("none", "null", "")):
        return None
    if isinstance(value, str) and value.strip().lower() in ("upright", "keep upright"):
        return upright_max_tilt_deg
    try:
        tilt = float(value)
    except (TypeError, ValueError):
        issues.append(f"max_tilt_deg {value!r} is not a number, taken as unconstrained")
        return None
    if not math.isfinite(tilt) or not 0.0 <= tilt <= 180.0:
        issues.append(f"max_tilt_deg {value!r} is outside [0, 180], taken as unconstrained")
        return None
    return tilt


def parse_zone_rating(
    text: str, backend: str, model: str, prompt_version: str, latency_s: float, upright_max_tilt_deg: float
) -> ZoneRating:
    """A validated ``ZoneRating`` from a model's raw answer; neutral (marked so) when nothing is usable."""
    data, issues = extract_json_object(text)
    if data is None:
        log.warning("%s/%s answer unusable (%s); neutral rating", backend, model, "; ".join(issues))
        return neutral_rating(backend, model, prompt_version, latency_s, "; ".join(issues), raw_text=text)

    ratings: dict[str, str] = {}
    raw_ratings = data.get("ratings")
    if not isinstance(raw_ratings, dict):
        issues.append("missing or malformed field 'ratings', no zone rated")
        raw_ratings = {}
    for zone, level in raw_ratings.items():
        zone_name, level_name = str(zone).strip().lower(), str(level).strip().lower()
        if not is_zone_name(zone_name):
            issues.append(f"unknown zone '{zone}' in 'ratings' dropped")
        elif level_name not in PHI:
            issues.append(f"unknown level '{level}' for zone '{zone_name}' dropped")
        else:
            ratings[zone_name] = level_name
    preferred = _zone_list(data.get("preferred"), "preferred", issues)
    avoid = _zone_list(data.get("avoid"), "avoid", issues)
    contradictory = preferred & avoid
    if contradictory:
        # Avoiding is the safe reading of a contradiction: a preferred zone is a bonus, an avoid zone a hazard.
        issues.append(f"zones both preferred and avoided kept as avoid only: {sorted(contradictory)}")
        preferred -= contradictory
    if not ratings and not preferred and not avoid:
        reason = "; ".join(issues + ["no valid zone rating or zone set in the answer"])
        log.warning("%s/%s answer unusable (%s); neutral rating", backend, model, reason)
        return neutral_rating(backend, model, prompt_version, latency_s, reason, raw_text=text)

    approach, vector = _approach(data.get("approach"), issues)
    style = str(data.get("grasp_style", "")).strip().lower()
    if style not in GRASP_STYLES:
        issues.append(f"grasp style {data.get('grasp_style')!r} unknown or missing, taken as any")
        style = "any"
    max_tilt = _max_tilt(data, upright_max_tilt_deg, issues)
    outcome = "repaired" if issues else "ok"
    if issues:
        log.info("%s/%s answer repaired: %s", backend, model, "; ".join(issues))
    return ZoneRating(
        ratings=ratings, preferred=frozenset(preferred), avoid=frozenset(avoid), approach=approach,
        grasp_style=style, max_tilt_deg=max_tilt,
        provenance=RatingProvenance(backend, model, prompt_version, latency_s, outcome),
        approach_vector_world=vector, issues=tuple(issues), raw_text=text,
    )
