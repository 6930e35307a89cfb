"""Grasp dataset export in the ACRONYM layout (Eppner et al., ICRA 2021).

ACRONYM's HDF5 files are read by grasp-learning code (Contact-GraspNet, GraspGen, the `acronym`
tools): ``grasps/transforms`` (N, 4, 4) gripper poses in the object's frame,
``grasps/qualities/flex/object_in_gripper`` (N,) outcomes, and the object as ``object/file`` (a mesh
path relative to the mesh root the reader is given) times ``object/scale``. We keep that layout, so
those loaders read our files unchanged, and add SAGP's own fields beside it. Every row of
``grasps/`` was simulated: its ``object_in_gripper`` is an outcome (1 held, 0 dropped), never a
default. The candidates no method executed are kept apart, under ``candidates/``, with the same
per-grasp fields, so a loader that reads ``grasps/`` never takes an untested grasp for a failure.

- ``grasps/transforms``: the grasp in ACRONYM's Franka gripper frame, in the object's URDF link
  frame, metres: z = approach, x = closing axis (the fingers open along +-x), origin at the gripper
  base, so both contacts lie between the finger pads at z = 0.105 m and x = -+width/2 (see
  ``acronym_gripper_transforms_object``).
- ``grasps/panda_hand_transforms``: the same grasps as poses of PyBullet's ``panda_hand`` frame
  (fingers close along its y axis), i.e. ``transforms @ Rz(-90 deg)``: what the planner commanded,
  for replaying in PyBullet. The planner's grasp frame itself (origin at the contact midpoint,
  y = closing axis, z = approach) is ``panda_hand`` moved 0.105 m along z.
- ``grasps/qualities/flex/object_in_gripper``: 1 where an executed attempt held the object, else 0.
- ``grasps/executed/<method>``: -1 not executed by that method, 0 failed, 1 held.
- ``grasps/candidate_index``: each simulated grasp's row in ``candidates/``.
- ``grasps/qualities/<method>/{score,afford,avoid,task}`` and ``grasps/qualities/terms/{geom,reach}``.
- ``grasps/width``, ``grasps/zone`` (names), ``grasps/contacts`` (N, 2, 3) in the object frame.
- ``candidates/``: the same fields (but the outcomes) for every scored candidate of the trial, in the
  planner's order, and ``candidates/tested``: -1 untested, 0 dropped, 1 held.
- ``object/file``: the URDF's visual mesh relative to the objects root (the directory holding
  ``objects.json``, e.g. ``025_mug/textured.obj``; ``pybullet_data`` for the built-in set; "" for an
  object without a visual mesh). ``object/scale``: the URDF's mesh scale when uniform (1.0 for every
  YCB object), else 1.0. ``object/mesh_to_link`` (4, 4): the visual ``<origin>`` times the per-axis
  mesh scale, which maps mesh vertices into the link frame; loaders that apply only ``object/scale``
  get the link frame exactly when it is a uniform scale (every YCB object; not pybullet_data's lego,
  domino or jenga). ``object/urdf`` (relative, same root), ``object/mass``, ``object/id``;
  ``gripper/type`` = "panda".
"""
from __future__ import annotations

import io
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..grasps import GraspCandidates, GraspPoses
from ..robot.description import load_robot
from ..robot.hand import hand_to_grasp_target_m
from ..run_directory import write_file_atomically
from ..types import GraspAttempt, PerceivedCloud
from ..world.objects import ObjectSpec, objects_root

# ACRONYM's Franka gripper is the same hand as panda_hand (finger joints 0.0584 m above the base,
# pads reaching ~0.105 m), but its fingers open along x where panda_hand's close along y. Turning
# the planner's frame +90 deg about its approach (z) maps its closing axis (y) onto x:
# columns (x, y, z) = (closing, approach x closing, approach) = (y_p, -x_p, z_p) = R_planner @ Rz(+90).
# The gripper is symmetric, so the sign only fixes which contact lies at -x (contact 0) and +x.
ACRONYM_FROM_PLANNER_ROTATION = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
# A candidate no simulation has run: kept under ``candidates/`` only, never as a grasp label.
UNTESTED = -1


def _acronym_hand_offset_m() -> float:
    """How far ACRONYM's gripper origin (the Franka hand's) lies behind the contacts: the files
    describe the Franka Panda's gripper (``gripper/type``) whichever robot ran the grasps."""
    return hand_to_grasp_target_m(load_robot("panda"))


def acronym_gripper_transforms_object(poses_object: GraspPoses) -> np.ndarray:
    """(C, 4, 4) grasp poses in ACRONYM's Franka gripper convention, from grasp poses in the
    object's link frame (``candidates.transform(cloud.object_from_world, "object").poses()``).

    The planner's grasp frame: columns of ``rotation`` (C, 3, 3) are (closing x approach,
    closing axis, approach); origin at the contact midpoint ``position`` (C, 3), metres.
    Returned: rotation ``R_planner @ Rz(+90 deg)`` (x = closing axis from contact 0 to contact 1,
    z = approach) and origin ``midpoint - 0.105 m * approach`` (the gripper base, which is
    ``panda_hand``'s origin), so contact k lies at ``(-+width/2, 0, 0.105)`` in the gripper frame.
    """
    if poses_object.frame != "object":
        raise ValueError(f"ACRONYM grasps are written in the object frame, got poses in the {poses_object.frame} frame")
    rotation_planner = poses_object.rotation.numpy()
    # The executed grasp closed its fingers at the grasp target, 0.105 m along panda_hand's z axis
    # in the robot's URDF, so the exported poses put the contacts there too.
    hand_offset = _acronym_hand_offset_m()
    transforms = np.tile(np.eye(4), (len(poses_object), 1, 1))
    transforms[:, :3, :3] = rotation_planner @ ACRONYM_FROM_PLANNER_ROTATION
    transforms[:, :3, 3] = poses_object.position.numpy() - hand_offset * rotation_planner[:, :, 2]
    return transforms


def grasp_poses_from_acronym(acronym_transforms_object: np.ndarray) -> GraspPoses:
    """The planner's grasp poses (centre, frame with y = closing axis, z = approach) of (C, 4, 4)
    ACRONYM gripper poses in the object frame: the inverse of ``acronym_gripper_transforms_object``."""
    rotation = acronym_transforms_object[:, :3, :3] @ ACRONYM_FROM_PLANNER_ROTATION.T
    centre = acronym_transforms_object[:, :3, 3] + _acronym_hand_offset_m() * acronym_transforms_object[:, :3, 2]
    return GraspPoses(torch.as_tensor(centre, dtype=torch.float64), torch.as_tensor(rotation, dtype=torch.float64), "object")


def panda_hand_transforms_object(acronym_transforms_object: np.ndarray) -> np.ndarray:
    """(C, 4, 4) ``panda_hand`` poses in the object frame from (C, 4, 4) ACRONYM gripper poses there.

    Same origin; rotated back -90 deg about the approach so y is the closing axis again.
    """
    gripper_from_hand = np.eye(4)
    gripper_from_hand[:3, :3] = ACRONYM_FROM_PLANNER_ROTATION.T
    return acronym_transforms_object @ gripper_from_hand


def object_mesh_reference(spec: ObjectSpec) -> tuple[str, str, float, np.ndarray]:
    """(mesh file, URDF file, scale, (4, 4) mesh-to-link) for ACRONYM's ``object`` group.

    The mesh is the URDF's first ``<visual><geometry><mesh filename=...>``; both paths are relative
    to the objects root (see ``objects_root``). Mesh file is "" where the visual is a primitive.
    """
    urdf_path = Path(spec.urdf_path).resolve()
    root = objects_root(urdf_path)
    mesh_to_link = np.eye(4)
    mesh_file, scale = "", 1.0
    for visual in ElementTree.parse(urdf_path).getroot().iter("visual"):
        mesh = visual.find("geometry/mesh")
        if mesh is None or not mesh.get("filename"):
            continue
        mesh_path = (urdf_path.parent / mesh.get("filename").removeprefix("file://")).resolve()
        mesh_file = _relative(mesh_path, root)
        scale_xyz = np.array([float(v) for v in (mesh.get("scale") or "1 1 1").split()])
        origin = visual.find("origin")
        if origin is not None:
            xyz = [float(v) for v in (origin.get("xyz") or "0 0 0").split()]
            rpy = [float(v) for v in (origin.get("rpy") or "0 0 0").split()]
            mesh_to_link[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF: fixed-axis roll, pitch, yaw
            mesh_to_link[:3, 3] = xyz
        mesh_to_link[:3, :3] = mesh_to_link[:3, :3] * scale_xyz[None]
        if np.allclose(scale_xyz, scale_xyz[0]):
            scale = float(scale_xyz[0])
        break
    return mesh_file, _relative(urdf_path, root), scale, mesh_to_link


def write_acronym(
    path: Path,
    spec: ObjectSpec,
    cloud: PerceivedCloud,
    candidates: GraspCandidates,
    ranked_by_method: dict[str, GraspCandidates],
    attempts_by_method: dict[str, Sequence[GraspAttempt]],
) -> None:
    """Write one trial's grasps to ``path`` (``acronym_bytes``); the file is replaced atomically."""
    write_file_atomically(path, acronym_bytes(spec, cloud, candidates, ranked_by_method, attempts_by_method))


def acronym_bytes(
    spec: ObjectSpec,
    cloud: PerceivedCloud,
    candidates: GraspCandidates,
    ranked_by_method: dict[str, GraspCandidates],
    attempts_by_method: dict[str, Sequence[GraspAttempt]],
) -> bytes:
    """One trial's grasps as the bytes of an HDF5 file: the simulated ones under ``grasps/``, every
    scored candidate under ``candidates/``.

    ``candidates`` is the planner's output; ``ranked_by_method`` holds each method's ranking of
    them and ``attempts_by_method`` the outcomes of its leading grasps, in ranked order.
    """
    import h5py

    n = len(candidates)
    candidates_object = candidates.transform(cloud.object_from_world, "object")
    transforms = acronym_gripper_transforms_object(candidates_object.poses())
    mesh_file, urdf_file, mesh_scale, mesh_to_link = object_mesh_reference(spec)
    outcome = np.full(n, UNTESTED, dtype=np.int8)  # over every method's attempts: held once is held
    executed_by_method = {}
    for method, ranked in ranked_by_method.items():
        executed = np.full(n, UNTESTED, dtype=np.int8)
        for candidate, attempt in zip(ranked.candidate_id.tolist(), attempts_by_method.get(method, ())):
            executed[candidate] = int(attempt.success)
            outcome[candidate] = max(outcome[candidate], int(attempt.success))
        executed_by_method[method] = executed
    tested = np.flatnonzero(outcome != UNTESTED)
    zone_names = np.array(candidates.primary_zone_names(), dtype=object)
    rows = {
        "transforms": transforms, "panda_hand_transforms": panda_hand_transforms_object(transforms),
        "width": candidates.width_m.numpy(), "contacts": candidates_object.contacts.numpy(),
        "qualities/terms/geom": candidates.s_geom.numpy(), "qualities/terms/reach": candidates.s_reach.numpy(),
    }
    for method, ranked in ranked_by_method.items():
        # Methods re-rank the candidates: put their values back in the planner's order.
        ids = ranked.candidate_id.numpy()
        for term, values in (("score", ranked.score), ("afford", ranked.s_afford), ("avoid", ranked.s_avoid), ("task", ranked.s_task)):
            aligned = np.empty(n, dtype=np.float32)
            aligned[ids] = values.numpy()
            rows[f"qualities/{method}/{term}"] = aligned
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        for group, selection in (("grasps", tested), ("candidates", slice(None))):
            for name, values in rows.items():
                f[f"{group}/{name}"] = values[selection]
            f.create_dataset(f"{group}/zone", data=zone_names[selection], dtype=h5py.string_dtype())
        f["grasps/qualities/flex/object_in_gripper"] = outcome[tested]
        f["grasps/candidate_index"] = tested
        for method, executed in executed_by_method.items():
            f[f"grasps/executed/{method}"] = executed[tested]
        f["candidates/tested"] = outcome
        f["object/file"] = mesh_file
        f["object/scale"] = mesh_scale
        f["object/mesh_to_link"] = mesh_to_link
        f["object/urdf"] = urdf_file
        f["object/id"] = spec.id
        f["object/mass"] = float(spec.mass_kg)
        f["gripper/type"] = "panda"
    return buffer.getvalue()


def _relative(path: Path, root: Path) -> str:
    return path.relative_to(root).as_posix() if path.is_relative_to(root) else str(path)
