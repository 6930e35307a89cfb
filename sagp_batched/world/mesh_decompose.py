"""Collision geometry of an imported object: convex hulls whose union approximates its surface (CoACD, a dependency;
PyBullet's V-HACD where CoACD does not import or fails, or where chosen; the hull itself for a convex surface), and
the narrowest width of a convex part.
"""
from __future__ import annotations

import functools
import importlib.metadata
import math
import os
import sys
from pathlib import Path

import numpy as np
import pybullet
import trimesh

from .._open3d import o3d
from .mesh_files import _read_obj_parts, write_obj_parts
from .mesh_settings import MeshImportSettings
from .mesh_sources import _Unusable
from .objects import ObjectSetError

# CoACD's tree search draws random cuts: a fixed seed makes an object's hulls, and so its labels, repeatable.
COACD_SEED = 0
# Directions besides the hull's face normals along which the narrowest width is sought.
WIDTH_PROBE_DIRECTIONS = 512


def _narrowest_width(points: np.ndarray, face_normals: np.ndarray) -> float:
    """The smallest extent of ``points`` over the hull's face normals and a spread of directions on the sphere."""
    golden = math.pi * (3.0 - math.sqrt(5.0))
    k = np.arange(WIDTH_PROBE_DIRECTIONS) + 0.5
    z = 1.0 - 2.0 * k / WIDTH_PROBE_DIRECTIONS
    radius = np.sqrt(1.0 - z * z)
    sphere = np.column_stack([radius * np.cos(golden * k), radius * np.sin(golden * k), z])
    along = points @ np.concatenate([face_normals, sphere]).T
    return float((along.max(axis=0) - along.min(axis=0)).min())


@functools.lru_cache(maxsize=None)
def _coacd_importable() -> bool:
    try:
        import coacd  # noqa: F401
    except (ImportError, OSError):
        return False
    return True


def _resolve_decomposer(requested: str) -> str:
    if requested == "auto":
        return "coacd" if _coacd_importable() else "vhacd"
    if requested == "coacd" and not _coacd_importable():
        raise ObjectSetError("decomposer 'coacd' is not installed (it is one of sagp-batched's dependencies: pip install coacd), "
                             "or choose 'vhacd'")
    return requested


def _decomposer_version(decomposer: str) -> str:
    return importlib.metadata.version("coacd" if decomposer == "coacd" else "pybullet")


def coacd_hulls(mesh: trimesh.Trimesh, settings: MeshImportSettings) -> list[trimesh.Trimesh]:
    # A shape made of several closed bodies (overlapping primitives, a scene's parts) is cut body by body: a cut of
    # the whole can leave pieces of two bodies on one side, and their hull would bridge the gap between them.
    bodies = list(mesh.split(only_watertight=False)) if mesh.is_watertight else [mesh]
    hulls = []
    for body in bodies:
        hulls.extend([body.convex_hull] if body.is_convex else _coacd_body(body, settings))
    # CoACD's threads may hand back a body's parts in any order: a fixed order keeps the collision file, and the
    # order PyBullet meets contacts in, the same from one import to the next.
    return sorted(hulls, key=lambda hull: tuple(np.round(hull.vertices.mean(axis=0), 9)) + (len(hull.vertices),))


def _coacd_body(body: trimesh.Trimesh, settings: MeshImportSettings) -> list[trimesh.Trimesh]:
    import coacd

    coacd.set_log_level("error")
    surface = _fewer_faces(body, settings.coacd_input_faces)
    mode = settings.coacd_preprocess_mode
    if mode == "open":
        # CoACD's own test also remeshes a closed surface with a few self-intersecting triangles (common in scans),
        # and its voxel remeshing thickens thin walls by up to a voxel.
        mode = "off" if surface.is_watertight else "on"
    parts = coacd.run_coacd(
        coacd.Mesh(surface.vertices, surface.faces),
        threshold=_concavity_threshold(body, settings),
        max_convex_hull=settings.max_convex_hulls,
        preprocess_mode=mode,
        preprocess_resolution=settings.coacd_preprocess_resolution,
        resolution=settings.coacd_resolution,
        mcts_iterations=settings.coacd_mcts_iterations,
        mcts_nodes=settings.coacd_mcts_nodes,
        mcts_max_depth=settings.coacd_mcts_max_depth,
        decimate=settings.coacd_max_hull_vertices is not None,
        max_ch_vertex=settings.coacd_max_hull_vertices or 256,
        seed=COACD_SEED,
    )
    return [trimesh.Trimesh(vertices, faces) for vertices, faces in parts]


def _concavity_threshold(body: trimesh.Trimesh, settings: MeshImportSettings) -> float:
    return min(settings.concavity_threshold, 2.0 * settings.coacd_max_concavity_m / float(body.extents.max()))


def _fewer_faces(mesh: trimesh.Trimesh, faces: int | None) -> trimesh.Trimesh:
    """``mesh`` decimated to at most ``faces`` triangles (quadric error: it keeps the shape, dropping only detail);
    ``mesh`` itself where decimating would open a closed surface."""
    if faces is None or len(mesh.faces) <= faces:
        return mesh
    legacy = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.faces))
    simplified = legacy.simplify_quadric_decimation(faces)
    fewer = trimesh.Trimesh(np.asarray(simplified.vertices), np.asarray(simplified.triangles))
    return fewer if fewer.is_watertight or not mesh.is_watertight else mesh


def _vhacd_hulls(mesh: trimesh.Trimesh, settings: MeshImportSettings, work_dir: Path) -> list[trimesh.Trimesh]:
    source, output = work_dir / "vhacd_in.obj", work_dir / "vhacd_out.obj"
    write_obj_parts(source, [mesh], with_normals=False)
    # pybullet.vhacd prints its progress on file descriptor 1 itself, past Python's sys.stdout.
    sys.stdout.flush()
    saved_stdout = os.dup(1)
    with open(os.devnull, "wb") as devnull:
        os.dup2(devnull.fileno(), 1)
        try:
            pybullet.vhacd(str(source), str(output), str(work_dir / "vhacd.log"), resolution=settings.vhacd_resolution)
        finally:
            os.dup2(saved_stdout, 1)
            os.close(saved_stdout)
    hulls = _read_obj_parts(output) if output.is_file() else []
    for path in (source, output, work_dir / "vhacd.log"):
        path.unlink(missing_ok=True)
    return hulls


def _decompose(mesh: trimesh.Trimesh, settings: MeshImportSettings, decomposer: str,
               work_dir: Path) -> tuple[list[trimesh.Trimesh], str, str | None]:
    """Convex hulls whose union approximates ``mesh``, the method that made them, and why V-HACD stood in for
    CoACD (None where it did not): with the automatic choice a CoACD failure falls back to V-HACD."""
    if mesh.is_convex:
        return [mesh.convex_hull], "convex hull", None
    try:
        return _hulls_by(mesh, settings, decomposer, work_dir), decomposer, None
    except _Unusable as failure:
        if decomposer != "coacd" or settings.decomposer != "auto":
            raise
        return _hulls_by(mesh, settings, "vhacd", work_dir), "vhacd", str(failure)


def _hulls_by(mesh: trimesh.Trimesh, settings: MeshImportSettings, decomposer: str, work_dir: Path) -> list[trimesh.Trimesh]:
    try:
        hulls = coacd_hulls(mesh, settings) if decomposer == "coacd" else _vhacd_hulls(mesh, settings, work_dir)
    except Exception as exc:  # both decomposers are native code that reports failures as generic errors
        raise _Unusable(f"collision decomposition ({decomposer}) failed: {type(exc).__name__}: {exc}") from exc
    hulls = [hull for hull in hulls if len(hull.faces) >= 4]
    if not hulls:
        raise _Unusable(f"collision decomposition ({decomposer}) produced no hull")
    return hulls
