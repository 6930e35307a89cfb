"""Grasp dataset export in the ACRONYM layout (Eppner et al., ICRA 2021).

ACRONYM's HDF5 files are read by grasp-learning code (Contact-GraspNet, GraspGen, the `acronym`
tools): ``grasps/transforms`` (N, 4, 4) gripper poses in the object's frame and
``grasps/qualities/flex/object_in_gripper`` (N,) outcomes. We keep that layout, so those loaders
read our files unchanged, and add SAGP's own fields beside it:

- ``grasps/transforms``: pose of the Franka hand frame (``panda_hand``, as in ACRONYM's Franka
  gripper) in the object's URDF link frame, metres.
- ``grasps/qualities/flex/object_in_gripper``: 1 where an executed attempt held the object, else 0.
- ``grasps/executed/<method>``: -1 not executed by that method, 0 failed, 1 held.
- ``grasps/qualities/<method>/score`` and ``grasps/qualities/terms/{geom,reach,afford,avoid,task}``.
- ``grasps/width``, ``grasps/zone`` (names), ``grasps/contacts`` (N, 2, 3) in the object frame.
- ``object/file``, ``object/scale``, ``object/mass``, ``object/id``; ``gripper/type`` = "panda".
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from .objects import ObjectSpec
from .types import GraspAttempt, GraspCandidates, PerceivedCloud

# panda_grasptarget sits 0.105 m along the hand's z axis (pybullet_data franka_panda/panda.urdf).
HAND_TO_GRASPTARGET_M = 0.105


def grasp_transforms_object(cloud: PerceivedCloud, candidates: GraspCandidates) -> np.ndarray:
    """(C, 4, 4) hand-frame poses in the object's link frame."""
    world_from_object = _pose(cloud)
    rotation = candidates.rotation_world.double().numpy()
    hand_position = candidates.position_world.double().numpy() - HAND_TO_GRASPTARGET_M * rotation[:, :, 2]
    world_from_hand = np.tile(np.eye(4), (len(candidates), 1, 1))
    world_from_hand[:, :3, :3] = rotation
    world_from_hand[:, :3, 3] = hand_position
    return np.linalg.inv(world_from_object)[None] @ world_from_hand


def write_acronym(
    path: Path,
    spec: ObjectSpec,
    cloud: PerceivedCloud,
    candidates: GraspCandidates,
    scored_by_method: dict[str, GraspCandidates],
    executed_by_method: dict[str, tuple[Sequence[int], Sequence[GraspAttempt]]],
) -> None:
    """Write every scored candidate of one trial; the file is replaced atomically.

    ``candidates`` is the planner's output; ``scored_by_method`` holds each method's re-ranked
    copy and ``executed_by_method`` the indices (into that copy) it executed, with their outcomes.
    """
    import h5py

    n = len(candidates)
    transforms = grasp_transforms_object(cloud, candidates)
    object_from_world = np.linalg.inv(_pose(cloud))
    contacts = candidates.contacts_world.double().numpy()
    contacts_object = contacts @ object_from_world[:3, :3].T + object_from_world[:3, 3]
    held = np.zeros(n, dtype=np.int8)
    tmp = path.with_suffix(".tmp")
    with h5py.File(tmp, "w") as f:
        f["grasps/transforms"] = transforms
        f["grasps/width"] = candidates.width_m.numpy()
        f["grasps/contacts"] = contacts_object
        names = np.array([candidates.zone_names[z] if 0 <= z < len(candidates.zone_names) else "" for z in candidates.zone.tolist()], dtype=object)
        f.create_dataset("grasps/zone", data=names, dtype=h5py.string_dtype())
        for term, values in (("geom", candidates.s_geom), ("reach", candidates.s_reach)):
            f[f"grasps/qualities/terms/{term}"] = values.numpy()
        for method, scored in scored_by_method.items():
            # Methods re-rank the candidates: put their values back in the planner's order.
            ids = scored.candidate_id.numpy()
            for term, values in (("score", scored.score), ("afford", scored.s_afford), ("avoid", scored.s_avoid), ("task", scored.s_task)):
                aligned = np.empty(n, dtype=np.float32)
                aligned[ids] = values.numpy()
                f[f"grasps/qualities/{method}/{term}"] = aligned
            executed = np.full(n, -1, dtype=np.int8)
            order, attempts = executed_by_method.get(method, ((), ()))
            for index, attempt in zip(order, attempts):
                executed[ids[index]] = int(attempt.success)
                held[ids[index]] |= int(attempt.success)
            f[f"grasps/executed/{method}"] = executed
        f["grasps/qualities/flex/object_in_gripper"] = held
        f["object/file"] = str(spec.urdf_path)
        f["object/id"] = spec.id
        f["object/scale"] = 1.0
        f["object/mass"] = float(spec.mass_kg)
        f["gripper/type"] = "panda"
    tmp.replace(path)


def _pose(cloud: PerceivedCloud) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat(cloud.object_quat_xyzw).as_matrix()
    pose[:3, 3] = cloud.object_position_world
    return pose
