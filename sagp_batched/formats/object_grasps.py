"""One object's grasps as a dataset's object file holds them (``acronym.write_object_file``): the simulated grasps
with their labels (``LabelledGrasps``), the grasps whose simulation could not run (``UntestedGrasps``) and what the
simulator was given for the object (``ObjectPhysics``). Frames and units are those of the file (``acronym``)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class ObjectPhysics:
    """What the simulator was given for an object: the values ACRONYM's ``object`` group holds."""

    mass_kg: float
    density_kg_m3: float
    friction: float
    com_m: tuple[float, float, float]  # in the link frame
    inertia_kg_m2: tuple[tuple[float, float, float], ...]  # (3, 3) about the COM, link axes
    volume_m3: float


@dataclass
class LabelledGrasps:
    """One object's simulated grasps, in its link frame: N rows of arrays, one per grasp."""

    transforms: np.ndarray  # (N, 4, 4) ACRONYM gripper poses
    width_m: np.ndarray  # (N,)
    contacts: np.ndarray  # (N, 2, 3)
    resting_pose: np.ndarray  # (N,) int64 which resting pose (and capture) the grasp was planned on
    verdict: list[str]  # planner verdict names
    verdict_reason: list[str]
    held: np.ndarray  # (N,) bool
    # (N,) share of the grasp's simulations (its pose and its perturbed copies) that held; 0 where geometry decided
    held_fraction: np.ndarray
    decided_by: list[str]  # "simulation", or "geometry" where the open hand intersects the object or the table at the grasp
    failure_reason: list[str]  # "" where held
    motion_closing_linear_m: np.ndarray
    motion_closing_angular_rad: np.ndarray
    motion_shaking_linear_m: np.ndarray
    motion_shaking_angular_rad: np.ndarray
    s_geom: np.ndarray
    s_reach: np.ndarray
    zone: list[str]
    zone_rating: dict[str, list[str]]  # task -> per-grasp level ("" unrated)
    # Per engine that labelled the grasps (``cross_engine``): its own held, held fraction and failure ("" held).
    engine_held: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    engine_held_fraction: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    engine_failure: dict[str, list[str]] = dataclasses.field(default_factory=dict)
    # (N, 7) the object's centre-of-mass pose in the hand's grasp-target frame (position, xyzw quaternion) at the
    # close's end and at the verdict (``protocols.GraspLabel``), NaN where not reached; None: not recorded (all NaN).
    object_in_hand_after_closing: np.ndarray | None = None
    object_in_hand_at_verdict: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.held)

    @classmethod
    def empty(cls, tasks: tuple[str, ...], engines: tuple[str, ...] = ()) -> "LabelledGrasps":
        """No grasps (an object none of whose captures could be labelled), with every field's shape."""
        none = np.zeros(0)
        return cls(np.zeros((0, 4, 4)), none, np.zeros((0, 2, 3)), np.zeros(0, dtype=np.int64), [], [], np.zeros(0, dtype=bool), none, [], [],
                   none, none, none, none, none, none, [], {task: [] for task in tasks},
                   {engine: np.zeros(0, dtype=bool) for engine in engines}, {engine: none for engine in engines}, {engine: [] for engine in engines},
                   np.zeros((0, 7)), np.zeros((0, 7)))

    @classmethod
    def concatenate(cls, parts: list["LabelledGrasps"]) -> "LabelledGrasps":
        values = {}
        for item in dataclasses.fields(cls):
            pieces = [getattr(part, item.name) for part in parts]
            if any(piece is None for piece in pieces):  # an optional record some part lacks: not recorded
                values[item.name] = None
            elif isinstance(pieces[0] if pieces else None, dict):  # per task or engine: joined key by key
                values[item.name] = {key: _joined([p[key] for p in pieces]) for key in pieces[0]}
            else:
                values[item.name] = _joined(pieces)
        return cls(**values)


def _joined(pieces: list) -> Any:
    """Lists joined end to end, arrays concatenated."""
    if pieces and isinstance(pieces[0], list):
        return sum(pieces, [])
    return np.concatenate(pieces) if pieces else np.zeros(0)


@dataclass(frozen=True)
class UntestedGrasps:
    """Grasps chosen for labelling whose simulation could not run: kept apart, never as labels."""

    transforms: np.ndarray  # (U, 4, 4)
    reason: list[str]
