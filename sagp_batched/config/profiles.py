"""The whole configuration (``Config``, one field a section) and its loading: defaults, then a named or given
profile's tables, then overrides."""
from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

from .execution import ExecutionConfig, LabellingConfig, TaskConfig
from .motion import MotionConfig
from .planning import IKConfig, MemoryConfig, PlannerConfig, ScoreWeights
from .run import DatasetConfig, RunConfig
from .semantics import RatingConfig, ZonesConfig
from .settings import ConfigError, _merge
from .world import CameraConfig, PerceptionConfig, SceneConfig

# The checkout's top-level profiles/ folder, installed as this package by pyproject.toml.
PROFILES_PACKAGE = "sagp_batched.profiles"


@dataclass
class Config:
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    ik: IKConfig = field(default_factory=IKConfig)
    weights: ScoreWeights = field(default_factory=ScoreWeights)
    motion: MotionConfig = field(default_factory=MotionConfig)
    execution: ExecutionConfig = field(default_factory=ExecutionConfig)
    zones: ZonesConfig = field(default_factory=ZonesConfig)
    rating: RatingConfig = field(default_factory=RatingConfig)
    labelling: LabellingConfig = field(default_factory=LabellingConfig)
    tasks: TaskConfig = field(default_factory=TaskConfig)
    run: RunConfig = field(default_factory=RunConfig)
    dataset: DatasetConfig = field(default_factory=DatasetConfig)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def override(self, section: str, **values: Any) -> "Config":
        """A copy with ``values`` replacing fields of ``section``; ``None`` values are ignored."""
        return _merge(self, {section: {k: v for k, v in values.items() if v is not None}}, "")


def named_profiles() -> dict[str, Traversable]:
    """The profiles that ship inside the package (``profiles/NAME.toml`` in the checkout), by name."""
    try:
        folder = resources.files(PROFILES_PACKAGE)
    except ModuleNotFoundError as exc:
        raise ConfigError(f"the package's named profiles ({PROFILES_PACKAGE}) are not installed: "
                          "reinstall the package (pip install -e .)") from exc
    return {entry.name.removesuffix(".toml"): entry for entry in folder.iterdir() if entry.name.endswith(".toml")}


def resolve_profile_path(name_or_path: str | Path) -> Traversable:
    """A profile given by name (``paper``, ``ci``, ``datagen``) or by a path to a TOML file."""
    candidate = Path(name_or_path).expanduser()
    given_as_path = candidate.suffix == ".toml" or candidate.exists()
    if given_as_path and candidate.is_file():
        return candidate
    profiles = named_profiles()
    if not given_as_path and str(name_or_path) in profiles:
        return profiles[str(name_or_path)]
    missing = f"no TOML file at {candidate}" if given_as_path else "no such named profile"
    raise ConfigError(f"profile '{name_or_path}' not found: {missing} (named profiles: {', '.join(sorted(profiles))})")


def read_profile(profile: str | Path) -> tuple[Traversable, dict[str, Any]]:
    """The profile's file and its tables as TOML gives them (nothing merged or checked yet); raises ``ConfigError``."""
    path = resolve_profile_path(profile)
    try:
        return path, tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(f"profile {path} is not UTF-8 text (byte {exc.start}: {exc.object[exc.start:exc.end]!r})") from exc
    except OSError as exc:
        raise ConfigError(f"cannot read profile {path}: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"profile {path} is not valid TOML: {exc}") from exc


def load_config(profile: str | Path | None = None, overrides: dict[str, dict[str, Any]] | None = None) -> Config:
    """Defaults, then the profile's tables, then ``overrides`` ({section: {field: value}})."""
    config = Config()
    if profile is not None:
        path, data = read_profile(profile)
        try:
            config = _merge(config, data, "")
        except ConfigError as exc:
            raise ConfigError(f"profile {path}: {exc}", exc.setting) from exc
    if overrides:
        config = _merge(config, {s: {k: v for k, v in d.items() if v is not None} for s, d in overrides.items()}, "")
    return config
