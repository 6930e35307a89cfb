"""A folder of meshes or URDFs as an object set: every object's URDF, collision hulls and metadata made by code.

``import_object_folder`` finds every OBJ, STL, PLY and GLB file and every URDF below a folder (a URDF brings its
mesh(es), their scale and origins; the meshes a URDF references are not imported again on their own) and turns each
into an object like the YCB set's: a link frame at the bottom centre of the axis-aligned bounding box of its most
probable resting pose, z up, x along the footprint's long side; a visual mesh (the scaled mesh as OBJ, flat colour);
a collision mesh of convex hulls (CoACD; PyBullet's V-HACD where CoACD does not import or fails; the hull itself for
a convex mesh); mass, centre of mass and inertia from the mesh and a density or a given mass; lateral friction.
How well the hulls stand for the mesh (their union's volume over the mesh's, the furthest their surface strays
outside it) is recorded, and an object past ``MeshImportSettings``' bounds is flagged in its ``ObjectSpec``'s
``import_record`` (kept, not skipped).

A mesh is repaired (vertices merged, degenerate and duplicate faces dropped, normals made consistent, small holes
filled, a few stray triangles hanging off an otherwise closed surface dropped). One that still does not enclose a
volume (not watertight) serves with its convex hull's volume, centre of mass and inertia: the hull is the solid that
a closed version of the surface can at most be, so its mass errs on the heavy side for concave objects; the metadata
says which solid was used (``mass_properties_from``).

Everything generated goes to ``<cache>/objects/<key>/`` (``model.urdf``, ``visual.obj``, ``collision.obj``,
``metadata.json``), where the key hashes the source files' bytes and every setting that changes the result; the
cache root is ``MeshImportSettings.cache_dir``, else ``$SAGP_CACHE_DIR``, else ``~/.cache/sagp_batched``. Nothing
is written into the imported folder. A mesh that cannot serve is listed in ``ObjectSet.skipped`` with its reason.

An optional ``objects.json`` in the folder maps object ids to overrides (``OVERRIDE_KEYS``). An object's id is its
file's stem (``mug.obj`` -> ``mug``; a URDF's own stem), or, where two files share a stem, its path below the
folder with ``/`` and ``.`` as ``_``.

The stages live apart: the settings in ``mesh_settings``, the folder's files and their surfaces in ``mesh_sources``,
repair, solid and resting poses in ``mesh_physics``, the convex decomposition in ``mesh_decompose``, how well it fits
in ``hull_fidelity``, the OBJ and URDF files written in ``mesh_files``; this module imports the folder and keeps the
content-hashed cache.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from .hull_fidelity import fidelity_issues, hull_fidelity
from .mesh_decompose import _decompose, _decomposer_version, _narrowest_width, _resolve_decomposer
from .mesh_files import _urdf_text, write_obj_parts
from .mesh_physics import _resting_poses, _repaired, _solid_of
from .mesh_settings import NOT_IN_CACHE_KEY, MeshImportSettings
from .mesh_sources import _discover, _Source, _source_mesh, _Unusable
from .objects import CACHE_DIR_ENV  # noqa: F401 (callers name the variable through this module)
from .objects import INDEX_METADATA_KEYS, METADATA_FILE, ObjectImport, ObjectSet, ObjectSetError, ObjectSpec, RestingPose

log = logging.getLogger(__name__)

# Bumped whenever the generated files change for the same inputs, so older cache entries are not reused.
IMPORT_FORMAT = 3
# The keys an ``objects.json`` entry of an imported folder may hold.
OVERRIDE_KEYS = frozenset({"name", "category", "asymmetric", "scale", "density_kg_m3", "mass_kg", "friction"})
DEFAULT_CATEGORY = "object"


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
        specs.append(_spec(source.object_id, entry, metadata, urdf_path, settings))
    if not specs:
        reasons = "; ".join(f"{path.relative_to(directory)}: {reason}" for path, reason in skipped)
        raise ObjectSetError(f"objects directory {directory} holds no usable object ({reasons})")
    return ObjectSet(f"mesh:{directory.resolve()}", specs, skipped)


def _spec(object_id: str, entry: dict[str, Any], metadata: dict[str, Any], urdf_path: Path, settings: MeshImportSettings) -> ObjectSpec:
    return ObjectSpec(
        id=object_id,
        name=str(entry.get("name", object_id.replace("_", " "))),
        urdf_path=urdf_path,
        category=str(entry.get("category", DEFAULT_CATEGORY)),
        asymmetric=bool(entry.get("asymmetric", False)),
        mass_kg=float(metadata["mass_kg"]),
        extents_m=tuple(float(e) for e in metadata["extents_m"]),  # type: ignore[arg-type]
        resting_poses=tuple(
            RestingPose(float(pose["probability"]), tuple(tuple(float(v) for v in row) for row in pose["link_to_rest"]))
            for pose in metadata["resting_poses"]
        ),
        import_record=_import_record(metadata, settings),
    )


def _import_record(metadata: dict[str, Any], settings: MeshImportSettings) -> ObjectImport:
    """The object's import figures, judged against the settings' bounds (which are not in the cache key: a stricter
    bound flags cached objects without rebuilding them)."""
    ratio, distance = float(metadata["hull_volume_ratio"]), float(metadata["hull_max_distance_m"])
    issues = fidelity_issues(ratio, distance, metadata["hull_ratio_volume_from"], settings.max_hull_volume_ratio, settings.max_hull_distance_m)
    # The metadata's map takes the file's raw coordinates (the scale inside it); the record's is rigid.
    rigid = np.array(metadata["source_to_link"], dtype=float)
    rigid[:3, :3] /= float(metadata["scale"])
    return ObjectImport(
        source_to_link=tuple(tuple(float(v) for v in row) for row in rigid),
        scale=float(metadata["scale"]),
        com_m=tuple(float(v) for v in metadata["com_m"]),  # type: ignore[arg-type]
        hull_volume_ratio=ratio,
        hull_max_distance_m=distance,
        decomposer=str(metadata["decomposer"]),
        collision_hulls=int(metadata["collision_hulls"]),
        fidelity_ok=not issues,
        fidelity_issues=tuple(issues),
    )


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


# -- one object ----------------------------------------------------------------------------------------------------
def _cache_key(source: _Source, parameters: _ObjectParameters, settings: MeshImportSettings, decomposer: str) -> str:
    recipe = {
        "format": IMPORT_FORMAT,
        "kind": "mesh" if source.urdf_parts is None else "urdf",
        "parameters": dataclasses.asdict(parameters),
        "settings": {name: value for name, value in dataclasses.asdict(settings).items() if name not in NOT_IN_CACHE_KEY},
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


def _collision_metadata(mesh: trimesh.Trimesh, hulls: list[trimesh.Trimesh], method: str, fallback_reason: str | None) -> dict[str, Any]:
    """How the collision hulls were made and how well they stand for ``mesh`` (see ``hull_fidelity``)."""
    fidelity = hull_fidelity(mesh, hulls)
    return {
        "decomposer": method,
        "decomposer_fallback_reason": fallback_reason,
        "collision_hulls": len(hulls),
        "hull_volume_ratio": fidelity.volume_ratio,
        "hull_max_distance_m": fidelity.max_hull_to_mesh_distance_m,
        "hull_mean_distance_m": fidelity.mean_hull_to_mesh_distance_m,
        # The ratio's denominator: a closed mesh's volume, or an open one's convex hull's (which understates the excess).
        "hull_ratio_volume_from": fidelity.mesh_volume_from,
    }


def _build(source: _Source, parameters: _ObjectParameters, settings: MeshImportSettings, decomposer: str, key: str,
           work_dir: Path) -> dict[str, Any]:
    """Write the object's files into ``work_dir`` and return its metadata (also written there)."""
    started = time.perf_counter()
    mesh = _repaired(_source_mesh(source, parameters.scale))
    solid, watertight = _solid_of(mesh)

    poses = _resting_poses(solid, settings)
    source_to_link = poses[0][1]
    link_to_source = np.linalg.inv(source_to_link)
    mesh.apply_transform(source_to_link)
    solid = mesh if watertight else mesh.convex_hull
    density = parameters.mass_kg / solid.volume if parameters.mass_kg is not None else parameters.density_kg_m3
    solid.density = density
    properties = solid.mass_properties
    hulls, method, fallback_reason = _decompose(mesh, settings, decomposer, work_dir)
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
        **_collision_metadata(mesh, hulls, method, fallback_reason),
        # Source coordinates (a mesh file's own units, or a URDF's link frame) -> this object's link frame.
        "source_to_link": (source_to_link @ np.diag([parameters.scale] * 3 + [1.0])).tolist(),
        "resting_poses": [
            {"probability": probability, "link_to_rest": (transform @ link_to_source).tolist()} for probability, transform in poses
        ],
    }
    write_obj_parts(work_dir / "visual.obj", [mesh], with_normals=True)
    write_obj_parts(work_dir / "collision.obj", hulls, with_normals=False)
    rgba = source.urdf_rgba if source.urdf_rgba is not None else settings.rgba
    (work_dir / "model.urdf").write_text(_urdf_text(key, metadata, rgba))
    metadata["build_seconds"] = round(time.perf_counter() - started, 3)
    (work_dir / METADATA_FILE).write_text(json.dumps(metadata, indent=1))
    return metadata
