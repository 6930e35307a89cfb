"""The object registry: which objects exist, where their URDFs are, and what the study knows of them.

Four sources:
- a YCB directory laid out like the project's ``shared/ycb`` (``objects.json`` + ``<id>/model.urdf``), chosen by
  argument or the ``SAGP_YCB_DIR`` environment variable;
- without either, the embedded compact YCB set: the published study's 14 objects and 7 distractors, shipped inside
  the package (``sagp_batched/data/ycb``: decimated visual meshes and smaller textures, the same URDFs, collision
  decompositions and link frames as ``shared/ycb``; made by ``runners/compact_objects.py``);
- by the name ``pybullet_data`` (``PYBULLET_DATA_SET``), a set of objects that ship inside ``pybullet_data``;
- any other folder of meshes (OBJ, STL, PLY, GLB) or URDFs, whose ``objects.json`` (optional) lists no ``urdf``:
  each object's URDF, collision hulls, mass, inertia and resting poses are made by ``mesh_import``.
"""
from __future__ import annotations

import hashlib
import importlib.resources
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable

import numpy as np
import pybullet_data

from ..description_files import UrdfSyntaxError, load_urdf, read_urdf_document, urdf_file_path

if TYPE_CHECKING:
    from .mesh_settings import MeshImportSettings

YCB_DIR_ENV = "SAGP_YCB_DIR"
# The cache that generated objects live in (imported meshes, object sets shipped to workers).
CACHE_DIR_ENV = "SAGP_CACHE_DIR"
DEFAULT_CACHE_ROOT = "~/.cache/sagp_batched"
DISTRACTOR_CATEGORY = "distractor"
# The ``objects_dir`` value (or ``$SAGP_YCB_DIR``) that selects the built-in pybullet_data set.
PYBULLET_DATA_SET = "pybullet_data"
EMBEDDED_YCB_SOURCE = "embedded compact YCB"
# Top-level keys of ``objects.json`` that describe the directory, not an object (the compact copy's provenance).
INDEX_METADATA_KEYS = frozenset({"compact"})
# Beside an imported object's URDF: its import record (the solid's mass, density, volume, inertia; its source).
METADATA_FILE = "metadata.json"

# The published study's asymmetric objects: those with a functional region geometry alone does not reveal.
# The flag of an ``objects.json`` entry without an ``asymmetric`` key (the YCB sets' entries have none).
YCB_ASYMMETRIC_IDS = frozenset(
    {"025_mug", "019_pitcher_base", "035_power_drill", "037_scissors", "051_large_clamp", "011_banana", "040_large_marker"}
)

# Built-in set: pybullet_data objects a Panda can grasp (each narrower than 8 cm somewhere; checked to
# settle on the table). (id, urdf path inside pybullet_data, category, asymmetric).
BUILTIN_OBJECTS = (
    ("mug", "objects/mug.urdf", "containers", True),
    ("duck", "duck_vhacd.urdf", "toys", True),
    ("teddy", "teddy_vhacd.urdf", "toys", True),
    ("lego", "lego/lego.urdf", "boxes", False),
    ("cube_small", "cube_small.urdf", "boxes", False),
    ("jenga", "jenga/jenga.urdf", "elongated", False),
    ("sphere_small", "sphere_small.urdf", "spheres", False),
    ("domino", "domino/domino.urdf", DISTRACTOR_CATEGORY, False),
    ("block", "block.urdf", DISTRACTOR_CATEGORY, False),
    ("random_000", "random_urdfs/000/000.urdf", DISTRACTOR_CATEGORY, False),
    ("random_008", "random_urdfs/008/008.urdf", DISTRACTOR_CATEGORY, False),
)


class ObjectSetError(ValueError):
    """An objects directory is missing, or its ``objects.json`` is unreadable, malformed or lists no object."""


class UnknownObjectError(KeyError):
    """An object id that the object set does not hold."""

    def __init__(self, object_id: str, known_ids: tuple[str, ...]):
        self.object_id = object_id
        self.known_ids = known_ids
        super().__init__(f"unknown object id '{object_id}' (known: {', '.join(known_ids)})")

    def __str__(self) -> str:
        return str(self.args[0])


class ObjectLoadError(RuntimeError):
    """An object's URDF is missing, unparsable, or PyBullet refuses to load it."""


@dataclass(frozen=True)
class RestingPose:
    """One way the object comes to rest on a plane, and how likely a random drop ends in it (quasi-static)."""

    probability: float
    # (4, 4) rows: link frame -> a frame on the plane (z up, the pose's AABB bottom centre at the origin).
    link_to_rest: tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class ObjectImport:
    """How an object imported from a mesh file (``mesh_import``) was made, and how well its collision hulls fit it."""

    # (4, 4) rows, rigid: the mesh file's frame at the import scale (its coordinates times ``scale``, in metres; a
    # URDF's link frame) -> this object's link frame. Grasp poses given on the scaled mesh (ACRONYM's) move with it.
    source_to_link: tuple[tuple[float, ...], ...]
    # Metres per unit of the mesh file (a URDF's geometry is in metres already: 1).
    scale: float
    com_m: tuple[float, float, float]  # centre of mass in the link frame
    # The hulls' union volume over the mesh's, and the furthest the union's surface strays outside the mesh (m).
    hull_volume_ratio: float
    hull_max_distance_m: float
    decomposer: str
    collision_hulls: int
    # Within ``MeshImportSettings``' bounds: where not, grasps simulated on the hulls may disagree with the mesh.
    fidelity_ok: bool
    # Each bound passed, in words (empty when ``fidelity_ok``).
    fidelity_issues: tuple[str, ...] = ()

    def fidelity_summary(self) -> dict[str, Any]:
        """The hulls' fit as the dataset report and the label-fidelity benchmark record it."""
        return {"volume_ratio": self.hull_volume_ratio, "max_distance_m": self.hull_max_distance_m, "hulls": self.collision_hulls,
                "ok": self.fidelity_ok, "issues": list(self.fidelity_issues)}

    @property
    def link_from_source(self) -> np.ndarray:
        """(4, 4) map of poses and points from the mesh file's frame at the import scale into the link frame:
        ``link_from_source @ pose``; a point read from the file in its own units is multiplied by ``scale`` first."""
        return np.array(self.source_to_link, dtype=float)


@dataclass(frozen=True)
class ObjectSpec:
    id: str
    name: str
    urdf_path: Path
    category: str
    asymmetric: bool
    mass_kg: float
    extents_m: tuple[float, float, float]  # resting-pose extents in the object's link frame (x, y, z)
    # Imported objects: their resting poses, most probable first; the first is the link frame's own (identity).
    resting_poses: tuple[RestingPose, ...] = ()
    # Imported objects: where their link frame and collision hulls came from (None for the YCB and built-in sets).
    import_record: ObjectImport | None = None


class ObjectSet:
    """An ordered registry of objects; targets are every non-distractor object.

    ``skipped`` lists the files of an imported folder that could not serve, each with its reason.
    """

    def __init__(self, source: str, specs: list[ObjectSpec], skipped: list[tuple[Path, str]] | None = None):
        self.source = source
        self._specs = {spec.id: spec for spec in specs}
        self.skipped = list(skipped or [])

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(self._specs)

    def get(self, object_id: str) -> ObjectSpec:
        try:
            return self._specs[object_id]
        except KeyError:
            raise UnknownObjectError(object_id, self.ids) from None

    def targets(self) -> list[ObjectSpec]:
        return [spec for spec in self._specs.values() if spec.category != DISTRACTOR_CATEGORY]

    def distractors(self) -> list[ObjectSpec]:
        return [spec for spec in self._specs.values() if spec.category == DISTRACTOR_CATEGORY]

    def subset(self, object_ids: Iterable[str]) -> "ObjectSet":
        """The objects ``object_ids`` of this set, in the set's order, under the same source."""
        wanted = set(object_ids)
        for object_id in wanted:
            self.get(object_id)  # raises UnknownObjectError naming the id
        return ObjectSet(self.source, [spec for spec in self._specs.values() if spec.id in wanted], self.skipped)

    def checksum(self) -> str:
        """SHA-256 over every object's metadata and URDF bytes: identifies the exact set a run used."""
        digest = hashlib.sha256(self.source.encode())
        for spec in self._specs.values():
            digest.update(json.dumps([spec.id, spec.name, spec.category, spec.asymmetric, spec.mass_kg, spec.extents_m]).encode())
            digest.update(spec.urdf_path.read_bytes())
        return digest.hexdigest()

    def __len__(self) -> int:
        return len(self._specs)


def sagp_cache_root(cache_dir: str | Path | None = None) -> Path:
    """The cache root: ``cache_dir``, else ``$SAGP_CACHE_DIR``, else ``~/.cache/sagp_batched``."""
    chosen = cache_dir if cache_dir is not None else os.environ.get(CACHE_DIR_ENV) or DEFAULT_CACHE_ROOT
    return Path(chosen).expanduser()


def _check_urdf(urdf_path: Path, object_id: str) -> None:
    """The URDF parses as a ``<robot>`` and every mesh it names exists: read, not loaded into PyBullet."""
    if not urdf_path.is_file():
        raise ObjectLoadError(f"object '{object_id}': URDF {urdf_path} does not exist")
    try:
        document = read_urdf_document(urdf_path)
    except UrdfSyntaxError as exc:
        raise ObjectLoadError(f"object '{object_id}': URDF {urdf_path} is not valid XML: {exc}") from exc
    except OSError as exc:
        raise ObjectLoadError(f"object '{object_id}': cannot read URDF {urdf_path}: {exc.strerror or exc}") from exc
    if document.root_element != "robot":
        raise ObjectLoadError(f"object '{object_id}': URDF {urdf_path} is not a URDF (root element <{document.root_element}>, not <robot>)")
    for filename in document.mesh_files:
        if not filename:
            raise ObjectLoadError(f"object '{object_id}': URDF {urdf_path} has a <mesh> without a filename")
        mesh_path = urdf_file_path(urdf_path, filename)
        if not mesh_path.is_file():
            raise ObjectLoadError(f"object '{object_id}': URDF {urdf_path} names mesh {mesh_path}, which does not exist")


def embedded_ycb_dir() -> Path:
    """The compact YCB set inside the installed package (a plain directory: setuptools installs package data unzipped)."""
    return Path(str(importlib.resources.files("sagp_batched").joinpath("data", "ycb")))


def _read_index(objects_dir: Path) -> dict[str, Any] | None:
    """The directory's ``objects.json``, or None where it has none."""
    if not objects_dir.is_dir():
        raise ObjectSetError(f"objects directory {objects_dir} does not exist")
    index_path = objects_dir / "objects.json"
    if not index_path.is_file():
        return None
    try:
        index = json.loads(index_path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ObjectSetError(f"{index_path} is not UTF-8 text (byte {exc.start}: {exc.object[exc.start:exc.end]!r})") from exc
    except OSError as exc:
        raise ObjectSetError(f"cannot read {index_path}: {exc.strerror or exc}") from exc
    except json.JSONDecodeError as exc:
        raise ObjectSetError(f"{index_path} is not valid JSON: {exc}") from exc
    if not isinstance(index, dict):
        raise ObjectSetError(f"{index_path} must map object ids to entries")
    return index


def _lists_urdfs(index: dict[str, Any]) -> bool:
    """Whether an ``objects.json`` describes a YCB-layout set (entries with ``urdf``) rather than overrides."""
    return any(isinstance(entry, dict) and "urdf" in entry for key, entry in index.items() if key not in INDEX_METADATA_KEYS)


def _asymmetric_flag(object_id: str, entry: dict[str, Any]) -> bool:
    flag = entry.get("asymmetric", object_id in YCB_ASYMMETRIC_IDS)
    if not isinstance(flag, bool):
        raise TypeError(f"asymmetric must be true or false, got {flag!r}")
    return flag


def _load_ycb_dir(objects_dir: Path, source_label: str = "ycb") -> ObjectSet:
    index = _read_index(objects_dir)
    index_path = objects_dir / "objects.json"
    if index is None:
        raise ObjectSetError(f"objects directory {objects_dir} has no objects.json")
    if not index:
        raise ObjectSetError(f"{index_path} must map object ids to entries")
    specs = []
    for object_id, entry in index.items():
        if object_id in INDEX_METADATA_KEYS:
            continue
        try:
            urdf_path = objects_dir / entry["urdf"]
            extents = tuple(float(e) for e in entry["extents_m"])
            spec = ObjectSpec(
                id=object_id,
                name=str(entry.get("name", object_id)),
                urdf_path=urdf_path,
                category=str(entry["category"]),
                asymmetric=_asymmetric_flag(object_id, entry),
                mass_kg=float(entry["mass_kg"]),
                extents_m=extents,  # type: ignore[arg-type]
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ObjectSetError(f"{index_path}: entry '{object_id}' is malformed ({type(exc).__name__}: {exc})") from exc
        if len(extents) != 3 or not all(math.isfinite(e) and e > 0 for e in extents):
            raise ObjectSetError(f"{index_path}: entry '{object_id}' extents_m must hold 3 finite numbers > 0, got {entry['extents_m']!r}")
        if not (math.isfinite(spec.mass_kg) and spec.mass_kg > 0):
            raise ObjectSetError(f"{index_path}: entry '{object_id}' mass_kg must be a finite number > 0, got {entry['mass_kg']!r}")
        _check_urdf(urdf_path, object_id)
        specs.append(spec)
    if not specs:
        raise ObjectSetError(f"{index_path} lists no objects")
    return ObjectSet(f"{source_label}:{objects_dir.resolve()}", specs)


def _measure_builtin(urdf_path: Path) -> tuple[float, tuple[float, float, float]]:
    """Mass and resting extents of a pybullet_data object, read from PyBullet (its URDFs carry no metadata)."""
    import pybullet  # here alone: objects are read by engines without PyBullet too

    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = load_urdf(client, urdf_path)
        lower, upper = pybullet.getAABB(body, physicsClientId=client)
        mass = pybullet.getDynamicsInfo(body, -1, physicsClientId=client)[0]
    finally:
        pybullet.disconnect(client)
    return float(mass), tuple(float(u - l) for l, u in zip(lower, upper))  # type: ignore[return-value]


def _load_builtin() -> ObjectSet:
    data_dir = Path(pybullet_data.getDataPath())
    specs = []
    for object_id, relative_path, category, asymmetric in BUILTIN_OBJECTS:
        urdf_path = data_dir / relative_path
        _check_urdf(urdf_path, object_id)
        mass, extents = _measure_builtin(urdf_path)
        specs.append(ObjectSpec(object_id, object_id.replace("_", " "), urdf_path, category, asymmetric, mass, extents))
    return ObjectSet(f"builtin:pybullet_data:{data_dir}", specs)


def objects_root(urdf_path: Path) -> Path:
    """The directory object paths are written relative to: the nearest one above the URDF holding an
    ``objects.json`` (a YCB set), else ``pybullet_data`` when the URDF is inside it, else the URDF's own."""
    for directory in urdf_path.parents:
        if (directory / "objects.json").is_file():
            return directory
    data_dir = Path(pybullet_data.getDataPath()).resolve()
    return data_dir if urdf_path.is_relative_to(data_dir) else urdf_path.parent


def load_object_set(objects_dir: str | Path | None = None, import_settings: MeshImportSettings | None = None) -> ObjectSet:
    """The object set from ``objects_dir``, else from env ``SAGP_YCB_DIR``, else the embedded compact YCB set.

    ``objects_dir`` (or ``SAGP_YCB_DIR``) equal to ``PYBULLET_DATA_SET`` (``"pybullet_data"``) selects the built-in
    pybullet_data set. A directory whose ``objects.json`` lists URDFs is read as a YCB-layout set; any other is
    imported mesh by mesh with ``import_settings`` (default ``MeshImportSettings()``; a YCB-layout set ignores them).
    The set's ``source`` says which was used: ``ycb:<dir>``, ``embedded compact YCB:<dir>``,
    ``builtin:pybullet_data:<dir>`` or ``mesh:<dir>``.
    """
    chosen = objects_dir if objects_dir is not None else os.environ.get(YCB_DIR_ENV) or None
    if chosen is None:
        return _load_ycb_dir(embedded_ycb_dir(), EMBEDDED_YCB_SOURCE)
    if str(chosen) == PYBULLET_DATA_SET:
        return _load_builtin()
    directory = Path(chosen).expanduser()
    index = _read_index(directory)
    if index is not None and _lists_urdfs(index):
        return _load_ycb_dir(directory)
    # Imported lazily: trimesh and the decomposers are needed only by folders of meshes.
    from .mesh_import import import_object_folder
    from .mesh_settings import MeshImportSettings

    return import_object_folder(directory, index or {}, import_settings or MeshImportSettings())
