"""A labelled grasp dataset on disk, in the layouts grasp-learning code reads.

Layout of a dataset directory::

    grasps/<object>.h5          one file per object (and scale), ACRONYM's layout plus SAGP's fields
    graspgen/<object>.json      the same grasps in GraspGen's JSON: object file and scale, transforms,
                                boolean object_in_gripper
    meshes/<object>/<mesh>      the mesh each file names (``object/file`` is relative to meshes/)
    splits/train.txt, valid.txt object mesh paths (relative to meshes/), GraspGen's split files
    manifest.json               objects, counts, conventions, the rater, the settings
    objects.jsonl               one line per finished object: what a resumed run skips

HDF5 keys (ACRONYM's names and dtypes: float64 arrays, int64 outcomes, UTF-8 strings):

- ``grasps/transforms`` (N, 4, 4): ACRONYM's Franka gripper frame in the object's link frame
  (z = approach, x = closing axis, origin at the gripper base 0.105 m behind the contacts), see
  ``export.acronym_gripper_transforms_object``; ``grasps/panda_hand_transforms`` the same as
  PyBullet ``panda_hand`` poses.
- ``grasps/qualities/flex/object_in_gripper`` (N,): 1 held after the shake, 0 dropped. Every row of
  ``grasps/`` was simulated; a grasp whose simulation could not run is kept under ``untested/``
  with its reason, never here.
- ``grasps/qualities/<engine>/{object_in_gripper, held_fraction, failure_reason}`` (N,): each engine's own
  label (``engines`` lists them, ``[dataset] engines``); ``flex/object_in_gripper`` is held in all of them
  (``cross_engine``).
- ``grasps/qualities/flex/held_fraction`` (N,): the share of the grasp's simulations (its pose and its
  perturbed copies, ``labelling``) that held; ``grasps/decided_by``: "simulation", or "geometry" where the
  open hand already intersects the object or the table at the grasp (labelled a collision, not simulated).
- ``grasps/qualities/flex/object_motion_during_{closing,shaking}_{linear,angular}`` (N,): metres
  and radians, as ``labelling`` measures them.
- ``object/{file, scale, mass, density, friction, com, inertia, volume}``, ``gripper/type``.
- SAGP's fields: ``grasps/verdict`` (names of ``verdicts.VERDICTS``) and ``grasps/verdict_reason``,
  ``grasps/failure_reason``, ``grasps/width``, ``grasps/contacts``, ``grasps/resting_pose``,
  ``grasps/zone``, ``grasps/zone_rating/<task>`` (the zone's level for the task from the rater named
  in ``rater``, "" where unrated), ``grasps/qualities/terms/{geom,reach}``, ``mode``, ``protocol``.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..world.objects import ObjectSpec, objects_root
from .export import object_mesh_reference

OBJECTS_PROGRESS_FILE = "objects.jsonl"


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

    def __len__(self) -> int:
        return len(self.held)

    @classmethod
    def empty(cls, tasks: tuple[str, ...], engines: tuple[str, ...] = ()) -> "LabelledGrasps":
        """No grasps (an object none of whose captures could be labelled), with every field's shape."""
        none = np.zeros(0)
        return cls(np.zeros((0, 4, 4)), none, np.zeros((0, 2, 3)), np.zeros(0, dtype=np.int64), [], [], np.zeros(0, dtype=bool), none, [], [],
                   none, none, none, none, none, none, [], {task: [] for task in tasks},
                   {engine: np.zeros(0, dtype=bool) for engine in engines}, {engine: none for engine in engines}, {engine: [] for engine in engines})

    @classmethod
    def concatenate(cls, parts: list["LabelledGrasps"]) -> "LabelledGrasps":
        values = {}
        for item in dataclasses.fields(cls):
            pieces = [getattr(part, item.name) for part in parts]
            if isinstance(pieces[0] if pieces else None, dict):  # per task or engine: joined key by key
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


def copy_object_mesh(spec: ObjectSpec, meshes_dir: Path) -> tuple[str, float, np.ndarray]:
    """Copy the object's visual mesh to ``meshes_dir/<object>/``: its path there, its scale and its
    (4, 4) mesh-to-link transform (identity for YCB and imported objects)."""
    mesh_file, _, scale, mesh_to_link = object_mesh_reference(spec)
    source = objects_root(Path(spec.urdf_path).resolve()) / mesh_file  # an absolute mesh_file stays itself
    target = meshes_dir / spec.id / source.name
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, target)
    return f"{spec.id}/{source.name}", scale, mesh_to_link


def split_of(object_id: str, valid_fraction: float) -> str:
    """"train" or "valid" for an object, from a hash of its id: stable across runs and machines."""
    bucket = int(hashlib.sha256(object_id.encode()).hexdigest()[:8], 16) / 0xFFFFFFFF
    return "valid" if bucket < valid_fraction else "train"


def write_splits(out_dir: Path, mesh_files: dict[str, str], valid_fraction: float) -> dict[str, list[str]]:
    """GraspGen's split files: each object's mesh path (relative to meshes/) in train.txt or valid.txt."""
    splits: dict[str, list[str]] = {"train": [], "valid": []}
    for object_id, mesh_file in sorted(mesh_files.items()):
        splits[split_of(object_id, valid_fraction)].append(mesh_file)
    (out_dir / "splits").mkdir(exist_ok=True)
    for name, files in splits.items():
        (out_dir / "splits" / f"{name}.txt").write_text("".join(f"{file}\n" for file in files), encoding="utf-8")
    return splits


def read_progress(out_dir: Path) -> dict[str, dict[str, Any]]:
    """Object id -> its progress line, for the objects a previous run finished (torn lines skipped)."""
    path = out_dir / OBJECTS_PROGRESS_FILE
    finished: dict[str, dict[str, Any]] = {}
    if not path.exists():
        return finished
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            entry = json.loads(line)
        except ValueError:
            continue  # the line a killed run was writing: that object runs again
        if isinstance(entry, dict) and isinstance(entry.get("object"), str):
            finished[entry["object"]] = entry
    return finished


def append_progress(out_dir: Path, entry: dict[str, Any]) -> None:
    """Record a finished object, synced, after its files are in place."""
    with (out_dir / OBJECTS_PROGRESS_FILE).open("a", encoding="utf-8") as file:
        file.write(json.dumps(entry, sort_keys=True) + "\n")
        file.flush()
        os.fsync(file.fileno())
