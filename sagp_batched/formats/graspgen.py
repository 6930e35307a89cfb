"""GraspGen's JSON layout (``graspgen/<object>.json`` of a dataset): one object's grasps as GraspGen's loaders read them.

| key | JSON type | meaning |
|---|---|---|
| `object.file` | string | the object's mesh, relative to the mesh root the reader is given (a dataset's ``meshes/``) |
| `object.scale` | number | the mesh's uniform scale |
| `gripper.name` | string | the gripper, as GraspGen names it: "franka_panda", "robotiq_2f_85", "robotiq_2f_140" |
| `gripper.width`, `gripper.depth` | numbers | its opening and its grasp depth (base to grasp target), metres |
| `grasps.transforms` | (N, 4, 4) nested lists of numbers | gripper poses (``frames``: z = approach, x = closing axis, origin at the gripper base), metres, in the object's link frame |
| `grasps.object_in_gripper` | (N,) booleans | true where the grasp held the object in our simulation |

GraspGen's gripper frame is ACRONYM's; the transforms are already in it, so the file gives no offset from the
gripper's own model. ``grasp_file.read_grasp_file`` reads these files; one that names no gripper is the Franka's.
"""
from __future__ import annotations

import json
from pathlib import Path

from ..robot.gripper_description import GripperDescription
from ..run_directory import write_file_atomically
from .object_grasps import LabelledGrasps


def write_graspgen_file(path: Path, mesh_file: str, mesh_scale: float, grasps: LabelledGrasps, gripper: GripperDescription) -> None:
    """One object's labelled grasps (made by ``gripper``) in GraspGen's JSON layout at ``path``, replaced atomically."""
    document = {
        "object": {"file": mesh_file, "scale": float(mesh_scale)},
        "gripper": {"name": gripper.file_name, "width": gripper.open_width_m, "depth": gripper.grasp_depth_m},
        "grasps": {"transforms": grasps.transforms.tolist(), "object_in_gripper": [bool(h) for h in grasps.held]},
    }
    write_file_atomically(path, json.dumps(document).encode("utf-8"))
