"""The inputs of a folder import: which files below the folder become objects, under which ids, and each one's
surface in metres (a bare mesh file, or a single-link URDF's meshes and primitives at their origins and scales).
"""
from __future__ import annotations

import collections
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

MESH_SUFFIXES = frozenset({".obj", ".stl", ".ply", ".glb"})


class _Unusable(Exception):
    """An object that cannot serve; its message is the reason listed in ``ObjectSet.skipped``."""


@dataclass(frozen=True)
class _UrdfGeometry:
    """One ``<visual>`` (or ``<collision>``) of a URDF: a mesh file or a primitive, and where it sits in the link."""

    mesh_path: Path | None
    primitive: tuple[str, tuple[float, ...]] | None  # ("box", size) / ("cylinder", (radius, length)) / ("sphere", (radius,))
    scale: tuple[float, float, float]
    origin: np.ndarray  # (4, 4) geometry frame -> URDF link frame


@dataclass(frozen=True)
class _Source:
    """A file found in the folder that may become one object."""

    object_id: str
    path: Path
    files: tuple[Path, ...]  # every file whose bytes make the object (the URDF and its meshes)
    urdf_parts: tuple[_UrdfGeometry, ...] | None  # None: a bare mesh file
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
def _floats(text: str | None, default: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split()) if text else default


def urdf_origin(element: ElementTree.Element | None) -> np.ndarray:
    """(4, 4) a URDF ``<origin>``: fixed-axis roll, pitch, yaw, then the translation; identity where absent."""
    matrix = np.eye(4)
    if element is not None:
        matrix[:3, :3] = Rotation.from_euler("xyz", _floats(element.get("rpy"), (0.0, 0.0, 0.0))).as_matrix()  # URDF: fixed-axis roll, pitch, yaw
        matrix[:3, 3] = _floats(element.get("xyz"), (0.0, 0.0, 0.0))
    return matrix


def _mesh_file(urdf_path: Path, filename: str) -> Path:
    if filename.startswith("package://"):
        raise _Unusable(f"mesh '{filename}' is a ROS package path, which cannot be resolved without the package")
    return urdf_path.parent / filename.removeprefix("file://")


def _geometry(urdf_path: Path, element: ElementTree.Element) -> _UrdfGeometry:
    origin = urdf_origin(element.find("origin"))
    geometry = element.find("geometry")
    shape = geometry[0] if geometry is not None and len(geometry) else None
    if shape is None:
        raise _Unusable(f"a <{element.tag}> has no geometry")
    if shape.tag == "mesh":
        scale = _floats(shape.get("scale"), (1.0, 1.0, 1.0))
        return _UrdfGeometry(_mesh_file(urdf_path, shape.get("filename", "")), None, scale * 3 if len(scale) == 1 else scale, origin)  # type: ignore[arg-type]
    sizes = {"box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",)}
    if shape.tag not in sizes:
        raise _Unusable(f"geometry <{shape.tag}> is not a mesh, box, cylinder or sphere")
    values = tuple(v for name in sizes[shape.tag] for v in _floats(shape.get(name), ()))
    return _UrdfGeometry(None, (shape.tag, values), (1.0, 1.0, 1.0), origin)


def _single_link(urdf_path: Path) -> tuple[ElementTree.Element, ElementTree.Element]:
    try:
        root = ElementTree.parse(urdf_path).getroot()
    except ElementTree.ParseError as exc:
        raise _Unusable(f"URDF is not valid XML: {exc}") from exc
    links = root.findall("link")
    if len(links) != 1:
        raise _Unusable(f"URDF has {len(links)} links; a rigid object is one link")
    return root, links[0]


def _referenced_meshes(urdf_path: Path) -> list[Path]:
    """Every mesh file a URDF's links name (visual and collision), whether or not the URDF can be imported."""
    try:
        root = ElementTree.parse(urdf_path).getroot()
    except ElementTree.ParseError:
        return []
    found = []
    for mesh in root.iter("mesh"):
        filename = mesh.get("filename", "")
        if filename and not filename.startswith("package://"):
            found.append(urdf_path.parent / filename.removeprefix("file://"))
    return found


def _urdf_source(object_id: str, urdf_path: Path) -> _Source:
    """A URDF's visual geometry (its collision geometry where it has no visual), or why it cannot be imported."""
    try:
        root, link = _single_link(urdf_path)
        elements = link.findall("visual") or link.findall("collision")
        if not elements:
            raise _Unusable("URDF link has no visual or collision geometry")
        parts = tuple(_geometry(urdf_path, element) for element in elements)
        for part in parts:
            if part.mesh_path is not None and not part.mesh_path.is_file():
                raise _Unusable(f"URDF mesh {part.mesh_path} does not exist")
    except _Unusable as reason:
        return _Source(object_id, urdf_path, (urdf_path,), None, None, str(reason))
    meshes = sorted({part.mesh_path for part in parts if part.mesh_path is not None})
    return _Source(object_id, urdf_path, (urdf_path, *meshes), parts, _urdf_rgba(root, link), None)


def _urdf_rgba(root: ElementTree.Element, link: ElementTree.Element) -> tuple[float, float, float, float] | None:
    material = link.find("visual/material")
    if material is None:
        return None
    color = material.find("color")
    if color is None:  # a material defined once at the robot level and named here
        named = [m for m in root.findall("material") if m.get("name") == material.get("name")]
        color = named[0].find("color") if named else None
    rgba = _floats(color.get("rgba") if color is not None else None, ())
    return rgba if len(rgba) == 4 else None  # type: ignore[return-value]


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
        if part.mesh_path is not None:
            mesh = _read_mesh(part.mesh_path)
        elif part.primitive[0] == "box":
            mesh = trimesh.creation.box(extents=part.primitive[1])
        elif part.primitive[0] == "cylinder":
            mesh = trimesh.creation.cylinder(radius=part.primitive[1][0], height=part.primitive[1][1])
        else:
            mesh = trimesh.creation.icosphere(subdivisions=3, radius=part.primitive[1][0])
        mesh.apply_transform(np.diag([*part.scale, 1.0]))
        mesh.apply_transform(part.origin)
        parts.append(mesh)
    mesh = trimesh.util.concatenate(parts)
    mesh.apply_scale(scale)
    return mesh
