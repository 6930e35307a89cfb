"""GraspGen's JSON layout (``graspgen/<object>.json`` of a dataset): one object's grasps as GraspGen's loaders read them.

| key | JSON type | meaning |
|---|---|---|
| `object.file` | string | the object's mesh, relative to the mesh root the reader is given (a dataset's ``meshes/``) |
| `object.scale` | number | the mesh's uniform scale |
| `grasps.transforms` | (N, 4, 4) nested lists of numbers | Franka gripper poses (``frames``: z = approach, x = closing axis, origin at the gripper base), metres, in the object's link frame |
| `grasps.object_in_gripper` | (N,) booleans | true where the grasp held the object in our simulation |

GraspGen's files name no gripper; its Franka gripper's frame is ACRONYM's. ``grasp_file.read_grasp_file`` reads them.
"""
from __future__ import annotations

import json
from pathlib import Path

from ..run_directory import write_file_atomically
from .object_grasps import LabelledGrasps


def write_graspgen_file(path: Path, mesh_file: str, mesh_scale: float, grasps: LabelledGrasps) -> None:
    """One object's labelled grasps in GraspGen's JSON layout at ``path``, replaced atomically."""
    document = {
        "object": {"file": mesh_file, "scale": float(mesh_scale)},
        "grasps": {"transforms": grasps.transforms.tolist(), "object_in_gripper": [bool(h) for h in grasps.held]},
    }
    write_file_atomically(path, json.dumps(document).encode("utf-8"))
