"""The frames of the grasp files: ACRONYM's and GraspGen's gripper frame, the gripper's base link and the planner's
grasp frame, and where an object's mesh lies in its link frame.

Grasp frames, all right-handed, in metres; `depth` is the gripper's grasp depth (`GripperDescription.grasp_depth_m`:
0.105 m for `franka_panda`, 0.1421 m for `robotiq_2f85`, 0.1952 m for `robotiq_2f140`):

| frame | origin | x | y | z |
|---|---|---|---|---|
| planner grasp (`GraspPoses`) | the grasp target, between the pads | closing x approach | closing axis | approach |
| ACRONYM / GraspGen gripper | gripper base, `depth` behind the grasp target | closing axis | approach x closing | approach |
| the gripper's base link (`panda_hand`, `robotiq_arg2f_base_link`) | gripper base (the same point) | -closing x approach | closing axis | approach |

ACRONYM's and GraspGen's gripper frames open the fingers along x where the base links close them along y: in the
gripper frame contact 0 lies at `(-width/2, 0, depth)` and contact 1 at `(+width/2, 0, depth)`. The file's
`gripper/type` (ACRONYM) or `gripper.name` (GraspGen) names the gripper (`GripperDescription.file_name`).

Mesh frames: a file names its object as a mesh (`object/file`) and a scale (`object/scale`). The *mesh frame* is the
mesh file's own coordinates; the *scaled mesh frame* is the same axes with coordinates times the scale (metres), the
frame ACRONYM's loaders put the grasps in; the *link frame* is the object's URDF link, the frame our simulation and
our files use. `mesh_to_link` (4, 4) maps mesh-frame points into the link frame and holds the mesh's scale.
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from ..description_files import read_urdf_document, urdf_file_path
from ..grasps import GraspPoses
from ..robot.gripper_description import GripperDescription
from ..world.objects import ObjectSpec, objects_root

# Turning the planner's frame +90 deg about its approach (z) maps its closing axis (y) onto x:
# columns (x, y, z) = (closing, approach x closing, approach) = (y_p, -x_p, z_p) = R_planner @ Rz(+90).
# The grippers are symmetric, so the sign only fixes which contact lies at -x (contact 0) and +x.
ACRONYM_FROM_PLANNER_ROTATION = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
# Rotation blocks further than this from orthonormal are refused: a pose that is not one cannot be simulated.
ROTATION_TOLERANCE = 1e-4


def acronym_gripper_transforms_object(poses_object: GraspPoses, gripper: GripperDescription) -> np.ndarray:
    """Grasp poses in ACRONYM's (and GraspGen's) gripper convention.

    Args:
        poses_object: C planner grasp poses in the object's link frame
            (``candidates.transform(cloud.object_from_world, "object").poses()``): columns of ``rotation``
            (C, 3, 3) are (closing x approach, closing axis, approach); ``position`` (C, 3) is the contact
            midpoint, metres.
        gripper: the gripper that makes them.

    Returns:
        (C, 4, 4) float64 gripper poses in the link frame: rotation ``R_planner @ Rz(+90 deg)`` (x = closing axis
        from contact 0 to contact 1, z = approach), origin ``midpoint - depth * approach`` (the gripper base,
        its base link's origin), so contact k lies at ``(-+width/2, 0, depth)`` in the gripper frame.

    Raises:
        ValueError: the poses are not in the object frame.
    """
    if poses_object.frame != "object":
        raise ValueError(f"ACRONYM grasps are written in the object frame, got poses in the {poses_object.frame} frame")
    rotation_planner = poses_object.rotation.numpy()
    # The simulated grasp closed its fingers at the grasp target, the grasp depth along the base link's z axis,
    # so the exported poses put the contacts there too.
    hand_offset = gripper.grasp_depth_m
    transforms = np.tile(np.eye(4), (len(poses_object), 1, 1))
    transforms[:, :3, :3] = rotation_planner @ ACRONYM_FROM_PLANNER_ROTATION
    transforms[:, :3, 3] = poses_object.position.numpy() - hand_offset * rotation_planner[:, :, 2]
    return transforms


def grasp_poses_from_acronym(acronym_transforms_object: np.ndarray, gripper: GripperDescription) -> GraspPoses:
    """The planner's grasp poses (origin at the grasp target, y = closing axis, z = approach) of (C, 4, 4)
    ACRONYM gripper poses of ``gripper`` in the object frame: the inverse of ``acronym_gripper_transforms_object``."""
    rotation = acronym_transforms_object[:, :3, :3] @ ACRONYM_FROM_PLANNER_ROTATION.T
    centre = acronym_transforms_object[:, :3, 3] + gripper.grasp_depth_m * acronym_transforms_object[:, :3, 2]
    return GraspPoses(torch.as_tensor(centre, dtype=torch.float64), torch.as_tensor(rotation, dtype=torch.float64), "object")


def base_link_transforms_object(acronym_transforms_object: np.ndarray) -> np.ndarray:
    """(C, 4, 4) base link poses (``panda_hand``'s, ``robotiq_arg2f_base_link``'s) from (C, 4, 4) ACRONYM gripper
    poses in the same frame: the same origin, rotated back -90 deg about the approach so y is the closing axis again."""
    gripper_from_hand = np.eye(4)
    gripper_from_hand[:3, :3] = ACRONYM_FROM_PLANNER_ROTATION.T
    return acronym_transforms_object @ gripper_from_hand


class MeshReference(NamedTuple):
    """Where an object's visual mesh is and how it lies in the object's link frame: ACRONYM's ``object`` group."""

    mesh_file: str
    """The URDF's first visual mesh, relative to the objects root (``objects_root``); "" for a primitive visual."""
    urdf_file: str
    """The object's URDF, relative to the same root."""
    scale: float
    """The visual's mesh scale where it is uniform (1.0 for every YCB object), else 1.0."""
    mesh_to_link: np.ndarray
    """(4, 4) float64: the visual ``<origin>`` times the per-axis mesh scale, mesh vertices -> link frame."""


def mesh_reference(spec: ObjectSpec) -> MeshReference:
    """The object's visual mesh and its mesh-to-link transform, from the URDF's first
    ``<visual><geometry><mesh filename=...>``."""
    urdf_path = Path(spec.urdf_path).resolve()
    root = objects_root(urdf_path)
    mesh_to_link = np.eye(4)
    mesh_file, scale = "", 1.0
    visuals = (visual for link in read_urdf_document(urdf_path).links for visual in link.visuals)
    for visual in visuals:
        if visual.shape != "mesh" or not visual.filename:
            continue
        mesh_file = _relative(urdf_file_path(urdf_path, visual.filename).resolve(), root)
        scale_xyz = np.array(visual.scale)
        mesh_to_link = visual.origin.copy()
        mesh_to_link[:3, :3] = mesh_to_link[:3, :3] * scale_xyz[None]
        if np.allclose(scale_xyz, scale_xyz[0]):
            scale = float(scale_xyz[0])
        break
    return MeshReference(mesh_file, _relative(urdf_path, root), scale, mesh_to_link)


def link_from_scaled_mesh(mesh_to_link: np.ndarray, scale: float) -> np.ndarray:
    """The rigid (4, 4) map from the scaled mesh's frame into the link frame: ``mesh_to_link`` less the scale.

    Raises:
        ValueError: ``mesh_to_link`` is no rigid transform times ``scale`` (a per-axis mesh scale: no frame of the
            mesh at one scale holds grasps rigidly).
    """
    scaled_to_link = mesh_to_link @ np.diag([1.0 / scale] * 3 + [1.0])
    rotation = scaled_to_link[:3, :3]
    if not (np.allclose(rotation @ rotation.T, np.eye(3), atol=ROTATION_TOLERANCE) and np.allclose(scaled_to_link[3], [0, 0, 0, 1])):
        raise ValueError(f"object/mesh_to_link is not a rigid transform times object/scale {scale:g}")
    return scaled_to_link


def _relative(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
