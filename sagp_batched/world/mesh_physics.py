"""The physical object a repaired surface stands for: repair, the solid that gives volume, mass and inertia, and the
quasi-static resting poses with the link frame each one defines.
"""
from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import QhullError

from .mesh_settings import MeshImportSettings
from .mesh_sources import _Unusable

# A solid smaller than this (1 mm^3) has no volume worth simulating.
MIN_VOLUME_M3 = 1e-9
# At most this share of a surface's faces may be dropped as stray scraps to leave a closed surface (scans such as
# YCB's carry a few triangles hanging off an edge, which make an otherwise closed surface non-manifold).
MAX_STRAY_FACE_SHARE = 0.001


def _repaired(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    if not np.isfinite(mesh.vertices).all():
        raise _Unusable("broken: vertices that are not finite numbers")
    mesh = mesh.copy()
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise _Unusable("broken: every triangle is degenerate")
    trimesh.repair.fix_normals(mesh)  # first: fill_holes winds its new faces by their neighbours'
    face_count = len(mesh.faces)
    trimesh.repair.fill_holes(mesh)
    if len(mesh.faces) != face_count:
        trimesh.repair.fix_normals(mesh)
    return mesh if mesh.is_watertight else _without_stray_faces(mesh)


def _without_stray_faces(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` less the few faces that keep it from being closed, where what remains is closed; else ``mesh``."""
    parts = trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)), min_len=1)
    closed = [part for part in parts if len(part) >= 4 and trimesh.Trimesh(mesh.vertices, mesh.faces[part]).is_watertight]
    kept = np.concatenate(closed) if closed else np.zeros(0, dtype=np.int64)
    if len(kept) == 0 or len(mesh.faces) - len(kept) > MAX_STRAY_FACE_SHARE * len(mesh.faces):
        return mesh
    cleaned = mesh.copy()
    cleaned.update_faces(np.sort(kept))
    cleaned.remove_unreferenced_vertices()
    return cleaned if cleaned.is_watertight else mesh


def _solid_of(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, bool]:
    """The solid whose volume, centre of mass and inertia stand for ``mesh`` (the mesh where it is watertight,
    else its convex hull), and whether the mesh is watertight."""
    # A flat hull's centre of mass divides by its zero volume: the volume check below reports it.
    with np.errstate(invalid="ignore", divide="ignore"):
        try:
            hull = mesh.convex_hull
        except QhullError as exc:
            raise _Unusable("no volume: fewer than four points off one plane") from exc
        hull_volume = hull.volume
    if hull_volume < MIN_VOLUME_M3:
        raise _Unusable(f"no volume: its convex hull holds {hull_volume:.3g} m^3")
    watertight = bool(mesh.is_watertight and mesh.volume > MIN_VOLUME_M3)
    return (mesh if watertight else hull), watertight


def _rest_transform(hull_vertices: np.ndarray, rotation: np.ndarray, centre_of_mass: np.ndarray) -> np.ndarray:
    """(4, 4) source -> rest frame for one resting orientation: z up, the long side of the footprint's
    smallest rectangle along x, the centre of mass on the +x side, the AABB's bottom centre at the origin."""
    rotated = hull_vertices @ rotation.T
    planar, _ = trimesh.bounds.oriented_bounds_2D(rotated[:, :2])
    yaw = np.eye(3)
    yaw[:2, :2] = planar[:2, :2]
    if (yaw @ rotation @ centre_of_mass)[0] < -1e-9:
        yaw = np.diag([-1.0, -1.0, 1.0]) @ yaw
    transform = np.eye(4)
    transform[:3, :3] = yaw @ rotation
    placed = hull_vertices @ transform[:3, :3].T
    lower, upper = placed.min(axis=0), placed.max(axis=0)
    transform[:3, 3] = [-(lower[0] + upper[0]) / 2.0, -(lower[1] + upper[1]) / 2.0, -lower[2]]
    return transform


def _resting_poses(solid: trimesh.Trimesh, settings: MeshImportSettings) -> list[tuple[float, np.ndarray]]:
    """(probability, (4, 4) source -> rest frame) of the solid's quasi-static resting poses, most probable first
    (ties: the lower centre of mass first), at most ``max_resting_poses``, none below the probability floor but the first."""
    hull = solid.convex_hull
    centre = solid.center_mass
    # compute_stable_poses draws centres of mass until one lies strictly inside the hull: it never returns otherwise.
    if not np.all(np.einsum("ij,ij->i", centre - hull.triangles_center, hull.face_normals) < 0):
        raise _Unusable("broken: its centre of mass is not inside its convex hull")
    rotations, probabilities = trimesh.poses.compute_stable_poses(solid, center_mass=centre)
    poses = []
    for rotation, probability in zip(rotations, probabilities):
        transform = _rest_transform(hull.vertices, rotation[:3, :3], centre)
        poses.append((float(probability), transform, float((transform[:3, :3] @ centre + transform[:3, 3])[2])))
    poses.sort(key=lambda pose: (-round(pose[0], 9), pose[2]))
    poses = _merged_by_up_direction(poses, settings.resting_pose_merge_deg)
    kept = [poses[0]] + [pose for pose in poses[1:] if pose[0] >= settings.min_resting_pose_probability]
    return [(probability, transform) for probability, transform, _ in kept[: settings.max_resting_poses]]


def _merged_by_up_direction(poses: list[tuple[float, np.ndarray, float]], merge_deg: float) -> list[tuple[float, np.ndarray, float]]:
    """One pose for each way up: a rounded body's faceted hull gives one pose per facet, a few degrees
    apart, which a capture would take for different resting poses though the object rolls between them.
    A pose whose up direction (in the source frame) lies within ``merge_deg`` of a more probable one's
    adds its probability to that one; the order stays most probable first."""
    kept: list[list] = []
    cosine = np.cos(np.radians(merge_deg))
    for probability, transform, height in poses:
        up = transform[2, :3]  # the source-frame direction the rest frame's z takes
        same = next((pose for pose in kept if float(up @ pose[1][2, :3]) >= cosine), None)
        if same is None:
            kept.append([probability, transform, height])
        else:
            same[0] += probability
    kept.sort(key=lambda pose: (-round(pose[0], 9), pose[2]))
    return [tuple(pose) for pose in kept]
