"""Comparing a simulation's or a solver's output with values recorded in the repository.

A recorded value was printed on one machine; another processor (or another OpenBLAS, MKL or torch
kernel path on the same one) rounds differently and gives floats ~1e-11 away, so recorded floats
are compared within a tolerance that each test names and explains, while the fields that are not
floats (booleans, failure reasons, counts, ids) stay exact. A field that moves beyond its tolerance
fails with its name, the recorded and the new value and how far it moved, so a real change is still
caught and can be judged (and, when intended, re-recorded).

Tests that compare with recorded values carry ``@pytest.mark.recorded``; ``tests/test_recorded.py``
re-runs them under another float path, which the machine that recorded them cannot otherwise show.
Comparisons of two runs in one process (determinism) are not recorded values and stay exact.
"""
from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

Tolerance = float | Mapping[str, float]


def assert_close_to_recorded(
    actual: Mapping[str, Any] | Sequence[Any],
    recorded: Mapping[str, Any] | Sequence[Any],
    *,
    atol: Tolerance,
    rtol: Tolerance = 0.0,
    names: Sequence[str] | None = None,
    label: str = "value",
) -> None:
    """Every field of ``actual`` is its ``recorded`` value: floats within ``atol + rtol * |recorded|``,
    everything else (bools, None, strings, ints) exactly.

    ``actual`` and ``recorded`` are both mappings (the keys name the fields) or both sequences of
    one length (``names`` names the fields). A field that is itself a tuple or list is compared
    element by element as ``name[i]``. ``atol`` and ``rtol`` are one number for every field or a
    mapping from field name to number (a field it leaves out gets 0). Raises AssertionError naming
    ``label`` and every field that moved, e.g. ``attempt (0.05, 0.0): descent_tracking_error_rad
    moved by 3.2e-04 (recorded 0.0511, now 0.0514), tolerance 1.0e-06``.
    """
    problems: list[str] = []
    for name, now, then in _fields(actual, recorded, names, label):
        _compare(name, name, now, then, atol, rtol, problems)
    if problems:
        raise AssertionError("\n".join(f"{label}: {problem}" for problem in problems))


def _fields(actual, recorded, names, label):
    if isinstance(recorded, Mapping):
        if not isinstance(actual, Mapping):
            raise AssertionError(f"{label}: recorded as a mapping, now a {type(actual).__name__}")
        if set(actual) != set(recorded):
            raise AssertionError(f"{label}: fields are now {sorted(actual)}, recorded {sorted(recorded)}")
        return [(str(key), actual[key], recorded[key]) for key in recorded]
    actual, recorded = list(actual), list(recorded)
    if names is None:
        names = [f"[{index}]" for index in range(len(recorded))]
    if not len(actual) == len(recorded) == len(names):
        raise AssertionError(f"{label}: {len(actual)} fields now, {len(recorded)} recorded, {len(names)} named")
    return list(zip(names, actual, recorded))


def _tolerance(tolerance: Tolerance, field: str) -> float:
    return float(tolerance.get(field, 0.0)) if isinstance(tolerance, Mapping) else float(tolerance)


def _is_float(value) -> bool:
    return isinstance(value, (float, np.floating))


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _compare(name, field, now, then, atol, rtol, problems):
    if isinstance(then, (tuple, list)):
        if not isinstance(now, (tuple, list, np.ndarray)) or len(now) != len(then):
            problems.append(f"{name} is now {now!r}, recorded {then!r}")
            return
        for index, (now_item, then_item) in enumerate(zip(now, then)):
            _compare(f"{name}[{index}]", field, now_item, then_item, atol, rtol, problems)
        return
    if not _is_float(then):
        same_kind = isinstance(now, (bool, np.bool_)) == isinstance(then, (bool, np.bool_))
        if not (same_kind and now == then):
            problems.append(f"{name} is now {now!r}, recorded {then!r} (compared exactly)")
        return
    if not _is_number(now):
        problems.append(f"{name} is now {now!r}, recorded the number {then!r}")
        return
    now, then = float(now), float(then)
    if not (math.isfinite(then) and math.isfinite(now)):
        if not (now == then or (math.isnan(then) and math.isnan(now))):
            problems.append(f"{name} is now {now!r}, recorded {then!r}")
        return
    tolerance = _tolerance(atol, field) + _tolerance(rtol, field) * abs(then)
    moved = abs(now - then)
    if not moved <= tolerance:
        problems.append(f"{name} moved by {moved:.1e} (recorded {then!r}, now {now!r}), tolerance {tolerance:.1e}")
