"""The inputs of a folder import: which files below the folder become objects, under which ids, and each one's
surface in metres (a bare mesh file, or a single-link URDF's meshes and primitives at their origins and scales).
"""
from __future__ import annotations

import collections
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ..description_files import UrdfGeometry, UrdfLink, UrdfSyntaxError, read_urdf_document, urdf_file_path

MESH_SUFFIXES = frozenset({".obj", ".stl", ".ply", ".glb"})


class _Unusable(Exception):
    """An object that cannot serve; its message is the reason listed in ``ObjectSet.skipped``."""


@dataclass(frozen=True)
class _Source:
    """A file found in the folder that may become one object."""

    object_id: str
    path: Path
    files: tuple[Path, ...]  # every file whose bytes make the object (the URDF and its meshes)
    urdf_parts: tuple[UrdfGeometry, ...] | None  # None: a bare mesh file; else meshes, boxes, cylinders and spheres
    urdf_rgba: tuple[float, float, float, float] | None
    problem: str | None  # why it cannot serve, when known before building


def _discover(directory: Path, cache_root: Path) -> list[_Source]:
    """Every URDF and every mesh file no URDF references, below ``directory``, in path order."""
    cache_root = cache_root.resolve()
    files = []
    for path in sorted(directory.rglob("*")):
        relative = path.relative_to(directory)
        if any(part.startswith(".") for part in relative.parts) or not path.is_file():
            continue
        if path.resolve().is_relative_to(cache_root):  # a cache kept inside the folder is not an input
            continue
        if path.suffix.lower() == ".urdf" or path.suffix.lower() in MESH_SUFFIXES:
            files.append(path)
    urdfs = {path for path in files if path.suffix.lower() == ".urdf"}
    referenced = {mesh.resolve() for urdf in sorted(urdfs) for mesh in _referenced_meshes(urdf)}
    sources = [path for path in files if path in urdfs or path.resolve() not in referenced]
    ids = _object_ids(sources, directory)
    return [
        _urdf_source(ids[path], path) if path in urdfs else _Source(ids[path], path, (path,), None, None, None)
        for path in sources
    ]


def _object_ids(files: list[Path], directory: Path) -> dict[Path, str]:
    stems = collections.Counter(path.stem for path in files)
    return {
        path: path.stem if stems[path.stem] == 1 else path.relative_to(directory).as_posix().replace("/", "_").replace(".", "_")
        for path in files
    }


# -- URDF sources --------------------------------------------------------------------------------------------------
def _mesh_file(urdf_path: Path, filename: str) -> Path:
    if filename.startswith("package://"):
        raise _Unusable(f"mesh '{filename}' is a ROS package path, which cannot be resolved without the package")
    return urdf_file_path(urdf_path, filename)


def _usable_geometry(geometry: UrdfGeometry, element: str) -> UrdfGeometry:
    if not geometry.shape:
        raise _Unusable(f"a <{element}> has no geometry")
    if geometry.shape not in ("mesh", "box", "cylinder", "sphere"):
        raise _Unusable(f"geometry <{geometry.shape}> is not a mesh, box, cylinder or sphere")
    return geometry


def _single_link(urdf_path: Path) -> UrdfLink:
    try:
        links = read_urdf_document(urdf_path).links
    except UrdfSyntaxError as exc:
        raise _Unusable(f"URDF is not valid XML: {exc}") from exc
    if len(links) != 1:
        raise _Unusable(f"URDF has {len(links)} links; a rigid object is one link")
    return links[0]


def _referenced_meshes(urdf_path: Path) -> list[Path]:
    """Every mesh file a URDF's links name (visual and collision), whether or not the URDF can be imported."""
    try:
        filenames = read_urdf_document(urdf_path).mesh_files
    except UrdfSyntaxError:
        return []
    return [urdf_file_path(urdf_path, filename) for filename in filenames if filename and not filename.startswith("package://")]


def _urdf_source(object_id: str, urdf_path: Path) -> _Source:
    """A URDF's visual geometry (its collision geometry where it has no visual), or why it cannot be imported."""
    try:
        link = _single_link(urdf_path)
        visuals = link.visuals
        element, geometries = ("visual", visuals) if visuals else ("collision", link.collisions)
        if not geometries:
            raise _Unusable("URDF link has no visual or collision geometry")
        parts, meshes = [], []
        for geometry in geometries:
            parts.append(_usable_geometry(geometry, element))
            if geometry.shape == "mesh":
                meshes.append(_mesh_file(urdf_path, geometry.filename))
        for mesh in meshes:
            if not mesh.is_file():
                raise _Unusable(f"URDF mesh {mesh} does not exist")
    except _Unusable as reason:
        return _Source(object_id, urdf_path, (urdf_path,), None, None, str(reason))
    return _Source(object_id, urdf_path, (urdf_path, *sorted(set(meshes))), tuple(parts), link.rgba, None)


# -- geometry ------------------------------------------------------------------------------------------------------
def _read_mesh(path: Path) -> trimesh.Trimesh:
    """A mesh file's triangles (every part of a scene, each placed by its scene transform), without visuals."""
    try:
        loaded = trimesh.load(str(path), force="mesh")
    except Exception as exc:  # trimesh's loaders raise whatever their parsers do
        raise _Unusable(f"unreadable: {type(exc).__name__}: {exc}") from exc
    faces = getattr(loaded, "faces", None)
    if faces is None or len(faces) == 0:
        raise _Unusable("unreadable: no triangles")
    return trimesh.Trimesh(np.asarray(loaded.vertices, dtype=np.float64), np.asarray(faces), process=False)


def _source_mesh(source: _Source, scale: float) -> trimesh.Trimesh:
    """The object's surface, metres, in the source's frame: the mesh file's, or the URDF link's."""
    if source.urdf_parts is None:
        mesh = _read_mesh(source.path)
        mesh.apply_scale(scale)
        return mesh
    parts = []
    for part in source.urdf_parts:
        if part.shape == "mesh":
            mesh = _read_mesh(_mesh_file(source.path, part.filename))
        elif part.shape == "box":
            mesh = trimesh.creation.box(extents=part.size)
        elif part.shape == "cylinder":
            mesh = trimesh.creation.cylinder(radius=part.size[0], height=part.size[1])
        else:
            mesh = trimesh.creation.icosphere(subdivisions=3, radius=part.size[0])
        mesh.apply_transform(np.diag([*part.scale, 1.0]))
        mesh.apply_transform(part.origin)
        parts.append(mesh)
    mesh = trimesh.util.concatenate(parts)
    mesh.apply_scale(scale)
    return mesh
