"""A folder of meshes or URDFs as an object set: every object's URDF, collision hulls and metadata made by code.

``import_object_folder`` finds every OBJ, STL, PLY and GLB file and every URDF below a folder (a URDF brings its
mesh(es), their scale and origins; the meshes a URDF references are not imported again on their own) and turns each
into an object like the YCB set's: a link frame at the bottom centre of the axis-aligned bounding box of its most
probable resting pose, z up, x along the footprint's long side; a visual mesh (the scaled mesh as OBJ, flat colour);
a collision mesh of convex hulls (CoACD where it imports, else PyBullet's V-HACD; the hull itself for a convex
mesh); mass, centre of mass and inertia from the mesh and a density or a given mass; lateral friction.

A mesh is repaired (vertices merged, degenerate and duplicate faces dropped, normals made consistent, small holes
filled). One that still does not enclose a volume (not watertight) serves with its convex hull's volume, centre of
mass and inertia: the hull is the solid that a closed version of the surface can at most be, so its mass errs on
the heavy side for concave objects; the metadata says which solid was used (``mass_properties_from``).

Everything generated goes to ``<cache>/objects/<key>/`` (``model.urdf``, ``visual.obj``, ``collision.obj``,
``metadata.json``), where the key hashes the source files' bytes and every setting that changes the result; the
cache root is ``MeshImportSettings.cache_dir``, else ``$SAGP_CACHE_DIR``, else ``~/.cache/sagp_batched``. Nothing
is written into the imported folder. A mesh that cannot serve is listed in ``ObjectSet.skipped`` with its reason.

An optional ``objects.json`` in the folder maps object ids to overrides (``OVERRIDE_KEYS``). An object's id is its
file's stem (``mug.obj`` -> ``mug``; a URDF's own stem), or, where two files share a stem, its path below the
folder with ``/`` and ``.`` as ``_``.
"""
from __future__ import annotations

import collections
import dataclasses
import functools
import hashlib
import importlib.metadata
import json
import logging
import math
import os
import shutil
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pybullet
import trimesh
from scipy.spatial import QhullError
from scipy.spatial.transform import Rotation

from .objects import CACHE_DIR_ENV  # noqa: F401 (callers name the variable through this module)
from .objects import INDEX_METADATA_KEYS, ObjectSet, ObjectSetError, ObjectSpec, RestingPose, sagp_cache_root
from .robot import load_robot

log = logging.getLogger(__name__)

MESH_SUFFIXES = frozenset({".obj", ".stl", ".ply", ".glb"})
# Bumped whenever the generated files change for the same inputs, so older cache entries are not reused.
IMPORT_FORMAT = 2
METADATA_FILE = "metadata.json"
DECOMPOSERS = ("auto", "coacd", "vhacd")
# The keys an ``objects.json`` entry of an imported folder may hold.
OVERRIDE_KEYS = frozenset({"name", "category", "asymmetric", "scale", "density_kg_m3", "mass_kg", "friction"})
DEFAULT_CATEGORY = "object"
# A solid smaller than this (1 mm^3) has no volume worth simulating.
MIN_VOLUME_M3 = 1e-9
# Directions besides the hull's face normals along which the narrowest width is sought.
WIDTH_PROBE_DIRECTIONS = 512
# The YCB URDFs' values: a little resistance to spinning and rolling in place.
SPINNING_FRICTION = 0.001
ROLLING_FRICTION = 0.001


@dataclass(frozen=True)
class MeshImportSettings:
    """How a folder of meshes becomes objects; every field but ``cache_dir`` is part of each object's cache key."""

    #: Metres per unit of a bare mesh file (OBJ/STL/PLY/GLB); a URDF's geometry is in metres already.
    scale: float = 1.0
    #: Density that turns a solid's volume into mass, kg/m^3 (ACRONYM's default).
    density_kg_m3: float = 150.0
    #: Mass of every object, kg, in place of ``density_kg_m3``; ``None`` derives it from the density.
    mass_kg: float | None = None
    #: Lateral (sliding) friction coefficient written into each URDF.
    friction: float = 1.0
    #: Visual colour of objects whose source gives none (a URDF's own visual colour is kept).
    rgba: tuple[float, float, float, float] = (0.65, 0.65, 0.65, 1.0)
    #: Collision decomposition: "coacd", "vhacd", or "auto" (CoACD where it imports, else V-HACD).
    decomposer: str = "auto"
    #: CoACD's concavity threshold: lower splits into more, tighter hulls.
    concavity_threshold: float = 0.05
    #: CoACD's cap on the number of hulls.
    max_convex_hulls: int = 16
    #: CoACD's sampling resolution of the surface.
    coacd_resolution: int = 2000
    #: CoACD's Monte-Carlo tree search effort: iterations, nodes per level, depth.
    coacd_mcts_iterations: int = 150
    coacd_mcts_nodes: int = 20
    coacd_mcts_max_depth: int = 3
    #: V-HACD's voxel resolution.
    vhacd_resolution: int = 100_000
    #: At most this many resting poses are kept, the most probable first.
    max_resting_poses: int = 8
    #: Resting poses less probable than this are dropped (the most probable one is always kept).
    min_resting_pose_probability: float = 0.01
    #: An object each of whose convex parts is wider than this in every direction cannot be grasped: the Panda's open hand.
    max_grasp_width_m: float = field(default_factory=lambda: load_robot().open_width_m)
    #: Cache root (objects go under ``<root>/objects/``); ``None``: ``$SAGP_CACHE_DIR``, else ``~/.cache/sagp_batched``.
    cache_dir: Path | None = None

    def __post_init__(self) -> None:
        positive = {
            "scale": self.scale, "density_kg_m3": self.density_kg_m3, "concavity_threshold": self.concavity_threshold,
            "max_convex_hulls": self.max_convex_hulls, "coacd_resolution": self.coacd_resolution,
            "coacd_mcts_iterations": self.coacd_mcts_iterations, "coacd_mcts_nodes": self.coacd_mcts_nodes,
            "coacd_mcts_max_depth": self.coacd_mcts_max_depth, "vhacd_resolution": self.vhacd_resolution,
            "max_resting_poses": self.max_resting_poses, "max_grasp_width_m": self.max_grasp_width_m,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ValueError(f"MeshImportSettings.{name} must be positive, got {value}")
        if self.mass_kg is not None and not self.mass_kg > 0:
            raise ValueError(f"MeshImportSettings.mass_kg must be positive or None, got {self.mass_kg}")
        if not self.friction >= 0:
            raise ValueError(f"MeshImportSettings.friction must be >= 0, got {self.friction}")
        if self.decomposer not in DECOMPOSERS:
            raise ValueError(f"MeshImportSettings.decomposer must be one of {', '.join(DECOMPOSERS)}, got '{self.decomposer}'")

    def cache_root(self) -> Path:
        return sagp_cache_root(self.cache_dir) / "objects"


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


@dataclass(frozen=True)
class _ObjectParameters:
    """The settings one object is built with: the set's, with its ``objects.json`` overrides applied."""

    scale: float
    density_kg_m3: float
    mass_kg: float | None
    friction: float


# -- the folder ----------------------------------------------------------------------------------------------------
def import_object_folder(directory: Path, index: dict[str, Any], settings: MeshImportSettings) -> ObjectSet:
    """The object set made from every mesh and URDF below ``directory``; ``index`` is its ``objects.json`` (or {})."""
    cache_root = settings.cache_root()
    sources = _discover(directory, cache_root)
    index_path = directory / "objects.json"
    if not sources:
        index_state = "an objects.json without urdf entries" if index_path.is_file() else "no objects.json"
        raise ObjectSetError(f"objects directory {directory} has {index_state} and no OBJ, STL, PLY, GLB or URDF file")
    overrides = _overrides(index, {source.object_id for source in sources}, index_path)
    decomposer = _resolve_decomposer(settings.decomposer)
    specs, skipped = [], []
    for source in sources:
        entry = overrides.get(source.object_id, {})
        try:
            if source.problem is not None:
                raise _Unusable(source.problem)
            metadata, urdf_path = _cached_or_built(source, _parameters(source, entry, settings), settings, decomposer, cache_root)
        except _Unusable as reason:
            log.info("skipping %s: %s", source.path, reason)  # the set lists it in ``skipped``; runners report it
            skipped.append((source.path, str(reason)))
            continue
        specs.append(
            ObjectSpec(
                id=source.object_id,
                name=str(entry.get("name", source.object_id.replace("_", " "))),
                urdf_path=urdf_path,
                category=str(entry.get("category", DEFAULT_CATEGORY)),
                asymmetric=bool(entry.get("asymmetric", False)),
                mass_kg=float(metadata["mass_kg"]),
                extents_m=tuple(float(e) for e in metadata["extents_m"]),  # type: ignore[arg-type]
                resting_poses=tuple(
                    RestingPose(float(pose["probability"]), tuple(tuple(float(v) for v in row) for row in pose["link_to_rest"]))
                    for pose in metadata["resting_poses"]
                ),
            )
        )
    if not specs:
        reasons = "; ".join(f"{path.relative_to(directory)}: {reason}" for path, reason in skipped)
        raise ObjectSetError(f"objects directory {directory} holds no usable object ({reasons})")
    return ObjectSet(f"mesh:{directory.resolve()}", specs, skipped)


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


def _overrides(index: dict[str, Any], known_ids: set[str], index_path: Path) -> dict[str, dict[str, Any]]:
    """``objects.json``'s entries, checked: each names an object found in the folder and holds only ``OVERRIDE_KEYS``."""
    checked = {}
    for object_id, entry in index.items():
        if object_id in INDEX_METADATA_KEYS:
            continue
        if object_id not in known_ids:
            raise ObjectSetError(f"{index_path}: entry '{object_id}' names no mesh or URDF in the folder (found: {', '.join(sorted(known_ids))})")
        if not isinstance(entry, dict):
            raise ObjectSetError(f"{index_path}: entry '{object_id}' must be an object of overrides")
        unknown = sorted(set(entry) - OVERRIDE_KEYS)
        if unknown:
            raise ObjectSetError(f"{index_path}: entry '{object_id}' has unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(OVERRIDE_KEYS))})")
        for key in ("scale", "density_kg_m3", "mass_kg"):
            if key in entry and not (isinstance(entry[key], (int, float)) and not isinstance(entry[key], bool) and entry[key] > 0):
                raise ObjectSetError(f"{index_path}: entry '{object_id}' {key} must be a positive number, got {entry[key]!r}")
        if "friction" in entry and not (isinstance(entry["friction"], (int, float)) and entry["friction"] >= 0):
            raise ObjectSetError(f"{index_path}: entry '{object_id}' friction must be a number >= 0, got {entry['friction']!r}")
        if "asymmetric" in entry and not isinstance(entry["asymmetric"], bool):
            raise ObjectSetError(f"{index_path}: entry '{object_id}' asymmetric must be true or false, got {entry['asymmetric']!r}")
        checked[object_id] = entry
    return checked


def _parameters(source: _Source, entry: dict[str, Any], settings: MeshImportSettings) -> _ObjectParameters:
    # An objects.json scale is the object's own unit (ACRONYM's per-object scale); a URDF without one is in metres.
    default_scale = 1.0 if source.urdf_parts is not None else settings.scale
    return _ObjectParameters(
        scale=float(entry.get("scale", default_scale)),
        density_kg_m3=float(entry.get("density_kg_m3", settings.density_kg_m3)),
        mass_kg=float(entry["mass_kg"]) if "mass_kg" in entry else settings.mass_kg,
        friction=float(entry.get("friction", settings.friction)),
    )


# -- URDF sources --------------------------------------------------------------------------------------------------
def _floats(text: str | None, default: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split()) if text else default


def _origin_matrix(element: ElementTree.Element | None) -> np.ndarray:
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
    origin = _origin_matrix(element.find("origin"))
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
    return mesh


def _narrowest_width(points: np.ndarray, face_normals: np.ndarray) -> float:
    """The smallest extent of ``points`` over the hull's face normals and a spread of directions on the sphere."""
    golden = math.pi * (3.0 - math.sqrt(5.0))
    k = np.arange(WIDTH_PROBE_DIRECTIONS) + 0.5
    z = 1.0 - 2.0 * k / WIDTH_PROBE_DIRECTIONS
    radius = np.sqrt(1.0 - z * z)
    sphere = np.column_stack([radius * np.cos(golden * k), radius * np.sin(golden * k), z])
    along = points @ np.concatenate([face_normals, sphere]).T
    return float((along.max(axis=0) - along.min(axis=0)).min())


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
    kept = [poses[0]] + [pose for pose in poses[1:] if pose[0] >= settings.min_resting_pose_probability]
    return [(probability, transform) for probability, transform, _ in kept[: settings.max_resting_poses]]


# -- collision decomposition ---------------------------------------------------------------------------------------
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


# -- files ---------------------------------------------------------------------------------------------------------
def _write_obj(path: Path, parts: list[trimesh.Trimesh], with_normals: bool) -> None:
    """Wavefront OBJ, one ``o`` per part (PyBullet makes each part of a collision OBJ a convex hull of its own)."""
    lines, offset = [], 1
    for number, part in enumerate(parts):
        lines.append(f"o part_{number}")
        lines.extend(f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in part.vertices)
        if with_normals:
            lines.extend(f"vn {x:.5f} {y:.5f} {z:.5f}" for x, y, z in part.vertex_normals)
            lines.extend(f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in part.faces + offset)
        else:
            lines.extend(f"f {a} {b} {c}" for a, b, c in part.faces + offset)
        offset += len(part.vertices)
    path.write_text("\n".join(lines) + "\n")


def _read_obj_parts(path: Path) -> list[trimesh.Trimesh]:
    """The ``o`` parts of an OBJ whose faces index one vertex list for the whole file (as V-HACD writes it)."""
    vertices, parts = [], []
    for line in path.read_text().splitlines():
        fields = line.split()
        if not fields:
            continue
        if fields[0] == "o" or (fields[0] == "f" and not parts):
            parts.append([])
        if fields[0] == "v":
            vertices.append([float(v) for v in fields[1:4]])
        elif fields[0] == "f":
            parts[-1].append([int(v.split("/")[0]) - 1 for v in fields[1:4]])
    vertices = np.asarray(vertices, dtype=np.float64)
    hulls = []
    for faces in parts:
        used = np.unique(np.asarray(faces, dtype=np.int64))
        if len(used) >= 4:
            hulls.append(trimesh.Trimesh(vertices[used]).convex_hull)
    return hulls


def _number(value: float) -> str:
    return f"{value:.9g}"


def _urdf_text(key: str, metadata: dict[str, Any], rgba: tuple[float, ...]) -> str:
    com = " ".join(_number(v) for v in metadata["com_m"])
    # The tensor's diagonal in the link frame, products of inertia left out (metadata.json keeps the full tensor):
    # PyBullet re-bases a link with a non-diagonal tensor on its principal axes, and the box it then reports
    # around the rotated collision hulls grows by centimetres, which lifts the scene's drop height and
    # widens footprints. The YCB URDFs are written the same way.
    ixx, iyy, izz = np.diag(np.asarray(metadata["inertia_kg_m2"]))
    terms = f'ixx="{_number(ixx)}" ixy="0" ixz="0" iyy="{_number(iyy)}" iyz="0" izz="{_number(izz)}"'
    return f"""<?xml version="1.0"?>
<!-- Made by sagp_batched.mesh_import (cache key {key}). Units: metres. Link frame: origin at the centre of the
     bottom face of the axis-aligned bounding box of the object's most probable resting pose, z up, x along the
     long side of its footprint. Mass and inertia (products of inertia omitted) from the {metadata["mass_properties_from"]}
     at {_number(metadata["density_kg_m3"])} kg/m^3; collision: {metadata["collision_hulls"]} hulls ({metadata["decomposer"]}). -->
<robot name="object">
  <link name="base_link">
    <contact>
      <lateral_friction value="{_number(metadata["friction"])}"/>
      <spinning_friction value="{SPINNING_FRICTION}"/>
      <rolling_friction value="{ROLLING_FRICTION}"/>
    </contact>
    <inertial>
      <origin xyz="{com}" rpy="0 0 0"/>
      <mass value="{_number(metadata["mass_kg"])}"/>
      <inertia {terms}/>
    </inertial>
    <visual>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <geometry>
        <mesh filename="visual.obj" scale="1 1 1"/>
      </geometry>
      <material name="flat_color">
        <color rgba="{" ".join(_number(v) for v in rgba)}"/>
      </material>
    </visual>
    <collision>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <geometry>
        <mesh filename="collision.obj" scale="1 1 1"/>
      </geometry>
    </collision>
  </link>
</robot>
"""


# -- one object ----------------------------------------------------------------------------------------------------
def _cache_key(source: _Source, parameters: _ObjectParameters, settings: MeshImportSettings, decomposer: str) -> str:
    recipe = {
        "format": IMPORT_FORMAT,
        "kind": "mesh" if source.urdf_parts is None else "urdf",
        "parameters": dataclasses.asdict(parameters),
        "settings": {name: value for name, value in dataclasses.asdict(settings).items() if name != "cache_dir"},
        "decomposer": decomposer,
        "versions": {"trimesh": trimesh.__version__, decomposer: _decomposer_version(decomposer)},
        # A URDF names its meshes by path relative to itself; a mesh file's suffix chooses its reader.
        "files": [Path(os.path.relpath(path, source.path.parent)).as_posix() for path in source.files]
        if source.urdf_parts is not None else [source.path.suffix.lower()],
    }
    digest = hashlib.sha256(json.dumps(recipe, sort_keys=True).encode())
    for path in source.files:
        contents = path.read_bytes()
        digest.update(len(contents).to_bytes(8, "little"))
        digest.update(contents)
    return digest.hexdigest()[:32]


def _cached_or_built(source: _Source, parameters: _ObjectParameters, settings: MeshImportSettings, decomposer: str,
                     cache_root: Path) -> tuple[dict[str, Any], Path]:
    """The object's metadata and URDF path from its cache entry, built there first when it is missing or damaged.

    An object found unusable is cached too (its entry holds only the reason), so a second load repeats no work.
    """
    try:
        key = _cache_key(source, parameters, settings, decomposer)
    except OSError as exc:
        raise _Unusable(f"unreadable: {exc}") from exc
    entry = cache_root / key
    metadata = _read_entry(entry, key)
    if metadata is None:
        cache_root.mkdir(parents=True, exist_ok=True)
        work_dir = Path(tempfile.mkdtemp(prefix=f".{key}-", dir=cache_root))
        try:
            try:
                metadata = _build(source, parameters, settings, decomposer, key, work_dir)
            except _Unusable as reason:
                metadata = {"format": IMPORT_FORMAT, "key": key, "unusable": str(reason)}
                (work_dir / METADATA_FILE).write_text(json.dumps(metadata, indent=1))
            if entry.exists():  # damaged: a complete one was read above
                shutil.rmtree(entry)
            try:
                work_dir.rename(entry)
            except OSError:
                if _read_entry(entry, key) is None:  # not a concurrent import that finished first
                    raise
        finally:
            if work_dir.exists():
                shutil.rmtree(work_dir)
    if "unusable" in metadata:
        raise _Unusable(metadata["unusable"])
    return metadata, entry / "model.urdf"


def _read_entry(entry: Path, key: str) -> dict[str, Any] | None:
    try:
        metadata = json.loads((entry / METADATA_FILE).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(metadata, dict) or metadata.get("format") != IMPORT_FORMAT or metadata.get("key") != key:
        return None
    complete = "unusable" in metadata or all((entry / name).is_file() for name in ("model.urdf", "visual.obj", "collision.obj"))
    return metadata if complete else None


def _build(source: _Source, parameters: _ObjectParameters, settings: MeshImportSettings, decomposer: str, key: str,
           work_dir: Path) -> dict[str, Any]:
    """Write the object's files into ``work_dir`` and return its metadata (also written there)."""
    started = time.perf_counter()
    mesh = _repaired(_source_mesh(source, parameters.scale))
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
    solid = mesh if watertight else hull

    poses = _resting_poses(solid, settings)
    source_to_link = poses[0][1]
    link_to_source = np.linalg.inv(source_to_link)
    mesh.apply_transform(source_to_link)
    solid = mesh if watertight else mesh.convex_hull
    density = parameters.mass_kg / solid.volume if parameters.mass_kg is not None else parameters.density_kg_m3
    solid.density = density
    properties = solid.mass_properties
    hulls, method = _decompose(mesh, settings, decomposer, work_dir)
    # A hand can close on a part narrower than the whole (a mug's handle or rim, a bowl's wall), so the
    # width test asks of each convex part, not of the object's hull.
    narrowest = min(_narrowest_width(part.vertices, part.face_normals) for part in hulls)
    if narrowest > settings.max_grasp_width_m:
        raise _Unusable(f"wider than the open hand in every direction, each of its {len(hulls)} convex part(s): "
                        f"narrowest {narrowest:.3f} m > {settings.max_grasp_width_m:.3f} m")

    metadata = {
        "format": IMPORT_FORMAT,
        "key": key,
        "kind": "mesh" if source.urdf_parts is None else "urdf",
        "scale": parameters.scale,
        "watertight": watertight,
        "mass_properties_from": "mesh" if watertight else "convex hull",
        "volume_m3": float(solid.volume),
        "density_kg_m3": float(density),
        "mass_kg": float(properties["mass"]),
        "com_m": [float(v) for v in properties["center_mass"]],
        "inertia_kg_m2": [[float(v) for v in row] for row in properties["inertia"]],
        "friction": parameters.friction,
        "extents_m": [float(v) for v in mesh.extents],
        "narrowest_width_m": narrowest,
        "decomposer": method,
        "collision_hulls": len(hulls),
        # Source coordinates (a mesh file's own units, or a URDF's link frame) -> this object's link frame.
        "source_to_link": (source_to_link @ np.diag([parameters.scale] * 3 + [1.0])).tolist(),
        "resting_poses": [
            {"probability": probability, "link_to_rest": (transform @ link_to_source).tolist()} for probability, transform in poses
        ],
    }
    _write_obj(work_dir / "visual.obj", [mesh], with_normals=True)
    _write_obj(work_dir / "collision.obj", hulls, with_normals=False)
    rgba = source.urdf_rgba if source.urdf_rgba is not None else settings.rgba
    (work_dir / "model.urdf").write_text(_urdf_text(key, metadata, rgba))
    metadata["build_seconds"] = round(time.perf_counter() - started, 3)
    (work_dir / METADATA_FILE).write_text(json.dumps(metadata, indent=1))
    return metadata
