"""A labelled grasp dataset on disk, in the layouts grasp-learning code reads.

Layout of a dataset directory::

    grasps/<object>.h5          one file per object (and scale), ACRONYM's layout plus SAGP's fields
    graspgen/<object>.json      the same grasps in GraspGen's JSON: object file and scale, transforms,
                                boolean object_in_gripper
    meshes/<object>/<mesh>      the mesh each file names (``object/file`` is relative to meshes/)
    splits/train.txt, valid.txt object mesh paths (relative to meshes/), GraspGen's split files
    manifest.json               objects, counts, conventions, the rater, the settings
    objects.jsonl               one line per finished object: what a resumed run skips

The keys, dtypes, units and frames of the files are ``sagp_batched.formats``' (``formats.acronym``,
``formats.graspgen``), which writes them.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from ..formats.frames import mesh_reference
from ..world.objects import ObjectSpec, objects_root

OBJECTS_PROGRESS_FILE = "objects.jsonl"


def copy_object_mesh(spec: ObjectSpec, meshes_dir: Path) -> tuple[str, float, np.ndarray]:
    """Copy the object's visual mesh to ``meshes_dir/<object>/``: its path there, its scale and its
    (4, 4) mesh-to-link transform (identity for YCB and imported objects)."""
    mesh_file, _, scale, mesh_to_link = mesh_reference(spec)
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
