"""The settings machinery every section is built on: the declared values a field may hold (``setting``,
``Allowed``), the check a section runs whenever it is made (``_Section``), and the merge of a profile's or a
flag's values into a section (``_merge``, ``_coerce``), each refusal a ``ConfigError``.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from typing import Any, ClassVar

class ConfigError(ValueError):
    """A profile or override names an unknown key or holds a value of the wrong type or out of range.

    ``setting`` is the ``section.field`` a range check refused, so a caller can name the flag that set it.
    """

    def __init__(self, message: str, setting: str | None = None):
        super().__init__(message)
        self.setting = setting


_ALLOWED = "allowed"


@dataclass(frozen=True)
class Allowed:
    """The values a setting may hold. Every number, a tuple's included, must be finite and within the
    bounds given; ``shape`` fixes a tuple's entry counts level by level (None: any count); ``ordered``
    asks a (low, high) pair for low <= high; ``choices`` lists a string's known values."""

    at_least: float | None = None
    above: float | None = None
    at_most: float | None = None
    below: float | None = None
    shape: tuple[int | None, ...] = ()
    ordered: bool = False
    choices: tuple[str, ...] = ()
    non_empty: bool = False
    unique: bool = False

    def check(self, value: Any, setting: str) -> None:
        """Raises ``ConfigError`` naming ``setting`` (and the entry, for a tuple's) if ``value`` is not allowed."""
        if self.choices:
            if value not in self.choices:
                raise ConfigError(f"{setting}: unknown value {value!r} (known: {', '.join(self.choices)})", setting)
        elif isinstance(value, str):
            if self.non_empty and not value.strip():
                raise ConfigError(f"{setting} must not be empty", setting)
        elif isinstance(value, tuple):
            self._check_entries(value, setting, setting, self.shape)
        else:
            self._check_number(value, setting, setting)

    def _check_entries(self, entries: tuple, where: str, setting: str, shape: tuple[int | None, ...]) -> None:
        if shape and shape[0] is not None and len(entries) != shape[0]:
            raise ConfigError(f"{where} must hold {shape[0]} entries, got {len(entries)}: {list(entries)!r}", setting)
        if self.non_empty and not entries:
            raise ConfigError(f"{where} must list at least one entry, got an empty list", setting)
        if self.unique:
            repeated = next((entry for i, entry in enumerate(entries) if entry in entries[:i]), None)
            if repeated is not None:
                raise ConfigError(f"{where} lists {repeated!r} more than once", setting)
        for i, entry in enumerate(entries):
            if isinstance(entry, tuple):
                self._check_entries(entry, f"{where}[{i}]", setting, shape[1:])
            elif not isinstance(entry, str):
                self._check_number(entry, f"{where}[{i}]", setting)
        if self.ordered and entries[0] > entries[1]:
            raise ConfigError(f"{where} must be a (low, high) pair with low <= high, got {list(entries)!r}", setting)

    def _check_number(self, value: Any, where: str, setting: str) -> None:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ConfigError(f"{where} must be a number, got {value!r}", setting)
        within = (
            math.isfinite(value)
            and (self.at_least is None or value >= self.at_least)
            and (self.above is None or value > self.above)
            and (self.at_most is None or value <= self.at_most)
            and (self.below is None or value < self.below)
        )
        if not within:
            bounds = self.describe_bounds()
            wanted = bounds if math.isfinite(value) else " ".join(filter(None, ("a finite number", bounds)))
            raise ConfigError(f"{where} must be {wanted}, got {value!r}", setting)

    def describe_bounds(self) -> str:
        """The bounds in words ("between 1 and 100", "> 0"); empty when any finite number will do."""
        if self.at_least is not None and self.at_most is not None:
            return f"between {self.at_least:,} and {self.at_most:,}"
        lower = f">= {self.at_least:,}" if self.at_least is not None else f"> {self.above:,}" if self.above is not None else ""
        upper = f"<= {self.at_most:,}" if self.at_most is not None else f"< {self.below:,}" if self.below is not None else ""
        return " and ".join(filter(None, (lower, upper)))


def setting(default: Any = dataclasses.MISSING, *, default_factory: Any = dataclasses.MISSING, **allowed: Any) -> Any:
    """A config field defaulting to ``default`` (or to what ``default_factory()`` returns when the section is
    made: a value that depends on the machine) whose values must be as ``Allowed(**allowed)`` says."""
    return field(default=default, default_factory=default_factory, metadata={_ALLOWED: Allowed(**allowed)})


class _Section:
    """A table of the config. Its fields declared with ``setting`` are checked whenever it is made (the
    defaults, a profile, a flag, ``dataclasses.replace``, a direct call), so all go through one check."""

    SECTION: ClassVar[str]

    def __post_init__(self) -> None:
        for declared in dataclasses.fields(self):  # type: ignore[arg-type]
            allowed = declared.metadata.get(_ALLOWED)
            if allowed is not None:
                allowed.check(getattr(self, declared.name), f"{self.SECTION}.{declared.name}")



def _coerce(value: Any, template: Any, where: str) -> Any:
    if isinstance(template, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if isinstance(template, (int, float)) and not isinstance(template, bool):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        if isinstance(template, int) and not float(value).is_integer():
            raise ConfigError(f"{where}: expected a whole number, got {value!r}")
        return type(template)(value)
    if isinstance(template, tuple):
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        # Entries take the type of the default's entries: [1, 2] for a pair of floats is (1.0, 2.0), ["a"] for one is refused.
        if not template:
            return tuple(value)
        return tuple(_coerce(entry, template[0], f"{where}[{i}]") for i, entry in enumerate(value))
    if isinstance(template, str) and not isinstance(value, str):
        raise ConfigError(f"{where}: expected a string, got {value!r}")
    return value


def _merge(obj: Any, updates: dict[str, Any], prefix: str) -> Any:
    known = {f.name: f for f in dataclasses.fields(obj)}
    changes = {}
    for key, value in updates.items():
        where = f"{prefix}{key}"
        if key not in known:
            raise ConfigError(f"unknown setting '{where}' (known: {', '.join(sorted(known))})")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ConfigError(f"'{where}' must be a table")
            changes[key] = _merge(current, value, f"{where}.")
        elif current is None:
            # The settings that default to None (run.objects_dir, run.ray_address) name a path or an address.
            if not isinstance(value, str):
                raise ConfigError(f"{where}: expected a string, got {value!r}")
            changes[key] = value
        else:
            changes[key] = _coerce(value, current, where)
    return dataclasses.replace(obj, **changes)
