"""Collision geometry of an imported object: convex hulls whose union approximates its surface (CoACD where it
imports, else PyBullet's V-HACD; the hull itself for a convex surface), and the narrowest width of a convex part.
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

from .mesh_files import _read_obj_parts, _write_obj
from .mesh_settings import MeshImportSettings
from .mesh_sources import _Unusable
from .objects import ObjectSetError

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
        raise ObjectSetError("decomposer 'coacd' is not installed: pip install 'sagp-batched[mesh]' (or use 'vhacd')")
    return requested


def _decomposer_version(decomposer: str) -> str:
    return importlib.metadata.version("coacd" if decomposer == "coacd" else "pybullet")


def _coacd_hulls(mesh: trimesh.Trimesh, settings: MeshImportSettings) -> list[trimesh.Trimesh]:
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(mesh.vertices, mesh.faces),
        threshold=settings.concavity_threshold,
        max_convex_hull=settings.max_convex_hulls,
        resolution=settings.coacd_resolution,
        mcts_iterations=settings.coacd_mcts_iterations,
        mcts_nodes=settings.coacd_mcts_nodes,
        mcts_max_depth=settings.coacd_mcts_max_depth,
        seed=0,
    )
    return [trimesh.Trimesh(vertices, faces) for vertices, faces in parts]


def _vhacd_hulls(mesh: trimesh.Trimesh, settings: MeshImportSettings, work_dir: Path) -> list[trimesh.Trimesh]:
    source, output = work_dir / "vhacd_in.obj", work_dir / "vhacd_out.obj"
    _write_obj(source, [mesh], with_normals=False)
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


def _decompose(mesh: trimesh.Trimesh, settings: MeshImportSettings, decomposer: str, work_dir: Path) -> tuple[list[trimesh.Trimesh], str]:
    """Convex hulls whose union approximates ``mesh``, and the method that made them."""
    if mesh.is_convex:
        return [mesh.convex_hull], "convex hull"
    try:
        hulls = _coacd_hulls(mesh, settings) if decomposer == "coacd" else _vhacd_hulls(mesh, settings, work_dir)
    except Exception as exc:  # both decomposers are native code that reports failures as generic errors
        raise _Unusable(f"collision decomposition ({decomposer}) failed: {type(exc).__name__}: {exc}") from exc
    hulls = [hull for hull in hulls if len(hull.faces) >= 4]
    if not hulls:
        raise _Unusable(f"collision decomposition ({decomposer}) produced no hull")
    return hulls, decomposer
