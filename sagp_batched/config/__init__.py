"""One configuration type for the whole pipeline, filled from ``profiles/*.toml``.

Every number of the method lives here with the published value as default; a choice the method leaves
open carries a one-line reason. A profile is a TOML file whose tables mirror these dataclasses
(``[scene]``, ``[camera]``, ``[perception]``, ``[planner]``, ``[memory]``, ``[ik]``, ``[weights]``, ``[motion]``, ``[execution]``,
``[zones]``, ``[rating]``, ``[labelling]`` with ``[labelling.shake]``, ``[run]``, ``[dataset]``); command-line flags
override profile values through ``override``.
Each field declares the values it may hold (``setting``: bounds, shape, choices), checked whenever a
section is made, so a profile value and a flag are refused by the same check, by name, before any work.

The machinery is in ``settings``; the sections by concept in ``world`` (scene, camera, perception), ``planning``
(planner, its memory bounds, IK, weights), ``motion`` (the motion planning checks and execution runs), ``semantics`` (zones, rating), ``execution`` (execution, labelling, tasks) and ``run``
(run, dataset); ``Config`` and the profile loading in ``profiles``.
"""
from .execution import ExecutionConfig, LabellingConfig, MuJoCoConfig, ShakeConfig, TaskConfig
from .motion import MotionConfig
from .planning import GEOMETRY_ONLY_WEIGHTS, MAX_PAIRS, PAIR_SAMPLING_MODES, PLANNER_SEARCHES, IKConfig, MemoryConfig, PlannerConfig, ScoreWeights
from .profiles import PROFILES_PACKAGE, Config, load_config, named_profiles, resolve_profile_path
from .run import MAX_TRIALS, MAX_WORKERS, RUN_BACKENDS, DatasetConfig, RunConfig
from .semantics import PROTRUSION_RULES, RATING_BACKENDS, RatingConfig, ZonesConfig
from .settings import Allowed, ConfigError, setting
from .world import MAX_IMAGE_SIDE_PX, NORMAL_ORIENTATIONS, CameraConfig, PerceptionConfig, SceneConfig

__all__ = [
    "GEOMETRY_ONLY_WEIGHTS", "MAX_IMAGE_SIDE_PX", "MAX_PAIRS", "MAX_TRIALS", "MAX_WORKERS", "NORMAL_ORIENTATIONS",
    "PAIR_SAMPLING_MODES", "PLANNER_SEARCHES", "PROFILES_PACKAGE", "PROTRUSION_RULES", "RATING_BACKENDS", "RUN_BACKENDS", "Allowed",
    "CameraConfig", "Config", "ConfigError", "DatasetConfig", "ExecutionConfig", "IKConfig", "LabellingConfig",
    "MemoryConfig", "MotionConfig", "MuJoCoConfig", "PerceptionConfig", "PlannerConfig", "RatingConfig", "RunConfig", "SceneConfig", "ScoreWeights", "ShakeConfig",
    "TaskConfig", "ZonesConfig", "load_config", "named_profiles", "resolve_profile_path", "setting",
]
