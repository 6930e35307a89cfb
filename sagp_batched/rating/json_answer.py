"""Untrusted model answers to JSON, as bounded work that raises nothing.

An answer longer than ``MAX_ANSWER_CHARS`` is refused before it is read; one nested deeper than
``MAX_DEPTH`` is refused before ``json`` (which recurses once a level) decodes it; a number literal
longer than ``MAX_NUMBER_CHARS`` (Python refuses ``int`` of a long one), a float out of range and
the NaN and Infinity JSON does not allow are refused while decoding; the repair of a cut-off answer
is one pass over it and at most two decodes.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

from .zone_rating import clipped

# A full zone answer is ~600 characters; 16K leaves a model room to ramble around it.
MAX_ANSWER_CHARS = 16_384
# UTF-8 takes at most 4 bytes a character: more bytes cannot spell an answer within the limit.
MAX_ANSWER_BYTES = 4 * MAX_ANSWER_CHARS
# The zone answer nests two deep (the answer, its ratings or zone lists).
MAX_DEPTH = 8
# No field of an answer needs more digits than a tilt in degrees or a candidate's number.
MAX_NUMBER_CHARS = 32
EXCERPT_CHARS = 60

_FENCE = re.compile(r"```(?:json|JSON)?\s*(.*?)(?:```|$)", re.DOTALL)
_CLOSERS = {"{": "}", "[": "]"}


class _Unusable(Exception):
    """The answer cannot be read within the limits, or is not JSON at all; the message says why."""


def excerpt(value: object) -> str:
    """A short printable quote of a value from an answer, for an issue: ASCII only, so no control,
    bidirectional or unpaired surrogate character reaches a log or a record."""
    if isinstance(value, (str, bytes, bytearray)):
        return clipped(ascii(value[: EXCERPT_CHARS + 1]), EXCERPT_CHARS)
    return clipped(ascii(value), EXCERPT_CHARS)


def _answer_text(answer: object) -> str:
    """``answer`` as text to read (bytes as UTF-8), refused when it is none or too long to read."""
    if isinstance(answer, (bytes, bytearray)):
        if len(answer) > MAX_ANSWER_BYTES:
            raise _Unusable(f"answer is {len(answer)} bytes, over the limit of {MAX_ANSWER_BYTES}")
        try:
            answer = bytes(answer).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise _Unusable(f"answer is bytes that are not UTF-8 text (byte {exc.start})") from None
    if not isinstance(answer, str):
        raise _Unusable(f"answer is of type {clipped(type(answer).__name__, EXCERPT_CHARS)}, not text")
    if len(answer) > MAX_ANSWER_CHARS:
        raise _Unusable(f"answer is {len(answer)} characters, over the limit of {MAX_ANSWER_CHARS}")
    return answer


@dataclass(frozen=True)
class _Shape:
    """What one pass over a JSON text says about the value it starts with."""

    end: int | None  # where the first value closes; None if the text ends first (cut off)
    broken: bool  # a closing bracket that closes nothing or the wrong bracket
    in_string: bool  # the text ends inside a string
    closers: str  # the brackets to append to close what is open where the text ends
    last_cut: tuple[int, str] | None  # the last comma outside a string, and the closers there


def _shape(text: str) -> _Shape:
    """One pass over ``text`` (which starts with '{' or '['): strings, brackets and commas.

    Refuses a value nested deeper than ``MAX_DEPTH``: that bound also keeps the closers copied at
    each comma short, so the pass is linear in the text's length."""
    stack: list[str] = []
    in_string = escaped = False
    last_cut: tuple[int, str] | None = None
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
            if len(stack) == MAX_DEPTH:
                raise _Unusable(f"answer nests deeper than {MAX_DEPTH} levels")
            stack.append(_CLOSERS[char])
        elif char in "}]":
            if not stack or stack.pop() != char:
                return _Shape(None, True, False, "", None)
            if not stack:
                return _Shape(i + 1, False, False, "", None)
        elif char == ",":
            last_cut = (i, "".join(reversed(stack)))
    return _Shape(None, False, in_string, "".join(reversed(stack)), last_cut)


def _bounded_int(literal: str) -> int:
    if len(literal) > MAX_NUMBER_CHARS:
        raise _Unusable(f"answer holds a number of {len(literal)} digits (limit {MAX_NUMBER_CHARS})")
    return int(literal)


def _bounded_float(literal: str) -> float:
    if len(literal) > MAX_NUMBER_CHARS:
        raise _Unusable(f"answer holds a number of {len(literal)} characters (limit {MAX_NUMBER_CHARS})")
    value = float(literal)
    if not math.isfinite(value):
        raise _Unusable(f"answer holds the number {literal}, beyond the range of a float")
    return value


def _refuse_constant(name: str) -> None:
    raise _Unusable(f"answer holds {name}, which JSON does not allow")


class _Decoder:
    """``json`` decoding within the number limits; a key given twice with two values is ambiguous
    and dropped (neither is taken), one given twice with the same value kept once. Both are counted."""

    def __init__(self) -> None:
        self._json = json.JSONDecoder(
            object_pairs_hook=self._object, parse_int=_bounded_int, parse_float=_bounded_float,
            parse_constant=_refuse_constant,
        )
        self.ambiguous = self.repeated = 0

    def decode(self, text: str) -> Any:
        self.ambiguous = self.repeated = 0
        return self._json.decode(text)

    def _object(self, pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        members: dict[str, Any] = {}
        ambiguous: set[str] = set()
        for key, value in pairs:
            if key not in members:
                members[key] = value
            elif members[key] == value:
                self.repeated += 1
            else:
                ambiguous.add(key)
        for key in ambiguous:
            del members[key]
        self.ambiguous += len(ambiguous)
        return members

    def issues(self) -> list[str]:
        return [
            *([f"keys given twice with different values dropped as ambiguous: {self.ambiguous}"] if self.ambiguous else []),
            *([f"keys given twice with the same value kept once: {self.repeated}"] if self.repeated else []),
        ]


def _decode_first_value(body: str) -> tuple[Any, int, list[str]]:
    """The JSON value ``body`` starts with, where it ends in ``body``, and the repairs it needed.

    ``json`` has no partial parser, so a cut-off value is closed by hand: as it stands (closing
    the brackets still open), else cut at the last comma outside a string (dropping the member
    being written when the answer was cut off)."""
    shape = _shape(body)
    decoder = _Decoder()
    if shape.end is not None:
        try:
            return decoder.decode(body[: shape.end]), shape.end, decoder.issues()
        except json.JSONDecodeError:
            raise _Unusable("answer's JSON is malformed beyond repair") from None
    candidates = []
    # A value cut off in a string or a number (15 of 150) is not complete as it stands.
    if not shape.broken and not shape.in_string and body.rstrip()[-1] not in "0123456789":
        candidates.append(body.rstrip() + shape.closers)
    if not shape.broken and shape.last_cut is not None:
        candidates.append(body[: shape.last_cut[0]] + shape.last_cut[1])
    for candidate in candidates:
        try:
            value = decoder.decode(candidate)
        except json.JSONDecodeError:
            continue
        return value, len(body), ["truncated JSON was closed after its last complete member", *decoder.issues()]
    raise _Unusable("answer's JSON is malformed beyond repair")


def extract_json_value(answer: object, opening: str) -> tuple[Any, list[str]]:
    """The first JSON value starting with ``opening`` ('{' or '[') in a model's answer (text or
    UTF-8 bytes), and the repairs it needed (fences, prose, truncation, repeated keys); None and why
    when there is none, it is malformed, or the answer is not readable within the limits."""
    issues: list[str] = []
    try:
        text = _answer_text(answer)
        fenced = _FENCE.search(text)
        if fenced:
            issues.append("answer was wrapped in a code fence")
            text = fenced.group(1)
        start = text.find(opening)
        if start < 0:
            return None, issues + [f"answer holds no JSON {'object' if opening == '{' else 'list'}"]
        if text[:start].strip():
            issues.append("prose before the JSON was ignored")
        value, end, repairs = _decode_first_value(text[start:])
    except _Unusable as unusable:
        return None, issues + [str(unusable)]
    issues += repairs
    if text[start + end:].strip():
        issues.append("text after the JSON was ignored")
    return value, issues


def extract_json_object(answer: object) -> tuple[dict[str, Any] | None, list[str]]:
    """The first JSON object in a model's answer, and the repairs it needed (``extract_json_value``)."""
    value, issues = extract_json_value(answer, "{")
    if value is not None and not isinstance(value, dict):
        return None, issues + [f"answer's JSON is a {type(value).__name__}, not an object"]
    return value, issues
