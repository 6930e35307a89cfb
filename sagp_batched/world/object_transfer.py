"""Objects shipped to workers by value: no worker needs the driver's objects folder at the driver's path.

``pack_objects`` reads every file the chosen objects use (each URDF, the meshes and textures it names, the
material libraries its OBJ meshes name and the textures those name, ``metadata.json`` beside an imported
object's URDF, the set's ``objects.json``) into one picklable ``PackedObjects``. A worker turns it back into an
``ObjectSet`` with ``materialise``: the files go under ``<cache>/transfer/<checksum>/`` on the worker's own disk,
written into a temporary folder and renamed into place, so two workers of one node never see each other's
half-written files and the second reuses the first's. The specs keep their ids, names, categories, masses,
extents and resting poses; their URDFs point into that folder, and the set's ``checksum()`` is the driver's.

Files keep their layout below the objects root that ``objects.objects_root`` finds (the folder holding
``objects.json``), so what a worker exports names each mesh relative to that root exactly as the driver would.
Objects inside ``pybullet_data`` are named by their path there instead: every worker has that folder, since
PyBullet ships it, and the checksum check catches a worker whose copy differs.

On Ray the driver places the pack in the object store once (``ray.put``) and hands each actor the reference.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import pybullet_data

from ..description_files import UrdfSyntaxError, read_urdf_document, urdf_file_path
from ..run_directory import path_inside
from .objects import METADATA_FILE, ObjectLoadError, ObjectSet, ObjectSpec, objects_root, sagp_cache_root

TRANSFER_DIR = "transfer"
INDEX_FILE = "objects.json"
# MTL statements whose last field names a texture file (options come before it).
_MTL_TEXTURE_STATEMENTS = ("map_", "bump", "disp", "decal", "refl", "norm")


class ObjectTransferError(ObjectLoadError):
    """An object's files cannot be packed (one is missing or unreadable) or materialised (disk, checksum)."""


@dataclass(frozen=True)
class _PackedSpec:
    spec: ObjectSpec  # the driver's spec; its urdf_path is replaced where the files land
    tree: int | None  # index into ``PackedObjects.trees``; None: a file of pybullet_data
    urdf: str  # the URDF's path relative to its tree (or to pybullet_data), POSIX separators


@dataclass(frozen=True)
class PackedObjects:
    """Objects and the bytes of every file they use, picklable; ``checksum`` is the source set's over these objects."""

    source: str
    checksum: str
    specs: tuple[_PackedSpec, ...]
    trees: tuple[dict[str, bytes], ...]  # per objects root: path relative to the tree -> contents
    skipped: tuple[tuple[Path, str], ...] = ()

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(packed.spec.id for packed in self.specs)

    @property
    def nbytes(self) -> int:
        return sum(len(contents) for tree in self.trees for contents in tree.values())


def _obj_material_libraries(obj_path: Path) -> list[Path]:
    names = []
    with obj_path.open("r", encoding="utf-8", errors="replace") as lines:
        for line in lines:
            if line.startswith("mtllib"):
                names.extend(line.split()[1:])
    return [obj_path.parent / name for name in names]


def _mtl_textures(mtl_path: Path) -> list[Path]:
    textures = []
    for line in mtl_path.read_text(encoding="utf-8", errors="replace").splitlines():
        fields = line.split()
        if len(fields) >= 2 and fields[0].lower().startswith(_MTL_TEXTURE_STATEMENTS):
            textures.append(mtl_path.parent / fields[-1])
    return textures


def referenced_files(spec: ObjectSpec) -> list[Path]:
    """The URDF of ``spec`` and every file it uses, resolved, URDF first; raises ``ObjectTransferError``
    naming a file the URDF names that does not exist."""
    urdf_path = Path(spec.urdf_path).resolve()
    if not urdf_path.is_file():
        raise ObjectTransferError(f"object '{spec.id}': URDF {urdf_path} does not exist")
    try:
        document = read_urdf_document(urdf_path)
    except (UrdfSyntaxError, OSError) as exc:
        raise ObjectTransferError(f"object '{spec.id}': cannot read URDF {urdf_path}: {exc}") from exc
    files = [urdf_path]
    for filename in filter(None, (*document.mesh_files, *document.texture_files)):
        path = urdf_file_path(urdf_path, filename).resolve()
        if not path.is_file():
            raise ObjectTransferError(f"object '{spec.id}': URDF {urdf_path} names {path}, which does not exist")
        files.append(path)
    # A material library or texture named by a mesh but absent is absent for a local run too (PyBullet then
    # draws the mesh untextured): the worker gets what the driver has, and nothing is refused for it.
    libraries = [mtl.resolve() for path in files if path.suffix.lower() == ".obj" for mtl in _obj_material_libraries(path)]
    libraries = [path for path in libraries if path.is_file()]
    textures = [texture.resolve() for mtl in libraries for texture in _mtl_textures(mtl)]
    files += libraries + [path for path in textures if path.is_file()]
    metadata = urdf_path.parent / METADATA_FILE
    if metadata.is_file():
        files.append(metadata)
    return list(dict.fromkeys(files))


def pack_objects(objects: ObjectSet, ids: Iterable[str] | None = None) -> PackedObjects:
    """The objects ``ids`` of ``objects`` (default: all), in the set's order, with the bytes of every file they use."""
    subset = objects if ids is None else objects.subset(ids)
    data_dir = Path(pybullet_data.getDataPath()).resolve()
    used: list[tuple[ObjectSpec, Path, list[Path]]] = []  # (spec, its objects root, its files)
    for object_id in subset.ids:
        spec = subset.get(object_id)
        files = referenced_files(spec)
        root = objects_root(files[0])
        index = root / INDEX_FILE
        if root != data_dir and index.is_file():
            files.append(index)
        used.append((spec, root, files))
    # One tree per objects root: the folder holding the root and every file of its objects, so a file named
    # outside the root travels too and the root keeps its place relative to the files.
    bases: dict[Path, Path] = {}
    for _, root, files in used:
        if root != data_dir:
            bases[root] = Path(os.path.commonpath([bases.get(root, root), *files]))
    tree_numbers = {root: number for number, root in enumerate(bases)}
    trees: list[dict[str, bytes]] = [{} for _ in bases]
    packed_specs = []
    for spec, root, files in used:
        if root == data_dir:
            packed_specs.append(_PackedSpec(spec, None, _posix_relative(files[0], data_dir)))
            continue
        tree = trees[tree_numbers[root]]
        for path in files:
            name = _posix_relative(path, bases[root])
            if name not in tree:
                try:
                    tree[name] = path.read_bytes()
                except OSError as exc:
                    raise ObjectTransferError(f"object '{spec.id}': cannot read {path}: {exc.strerror or exc}") from exc
        packed_specs.append(_PackedSpec(spec, tree_numbers[root], _posix_relative(files[0], bases[root])))
    return PackedObjects(subset.source, subset.checksum(), tuple(packed_specs), tuple(trees), tuple(subset.skipped))


def _posix_relative(path: Path, base: Path) -> str:
    return path.relative_to(base).as_posix()


def transfer_dir(cache_dir: str | Path | None = None) -> Path:
    """Where materialised object sets live: ``<cache>/transfer`` (``cache_dir``, else ``$SAGP_CACHE_DIR``, else ~/.cache)."""
    return sagp_cache_root(cache_dir) / TRANSFER_DIR


def _is_complete(directory: Path, packed: PackedObjects) -> bool:
    for number, tree in enumerate(packed.trees):
        for name, contents in tree.items():
            path = directory / str(number) / name
            try:
                if path.stat().st_size != len(contents):
                    return False
            except OSError:
                return False
    return True


def _write_trees(directory: Path, packed: PackedObjects) -> None:
    for number, tree in enumerate(packed.trees):
        for name, contents in tree.items():
            path = path_inside(directory / str(number), name)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(contents)


def _write_materialised(packed: PackedObjects, cache_dir: str | Path | None) -> Path:
    """The folder holding ``packed``'s files on this machine, written first when missing or damaged."""
    directory = materialised_dir(packed, cache_dir)
    parent = directory.parent
    if _is_complete(directory, packed):
        return directory
    try:
        parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{packed.checksum[:16]}-", dir=parent))
    except OSError as exc:
        raise ObjectTransferError(f"cannot write the objects under {parent}: {exc.strerror or exc}") from exc
    try:
        _write_trees(staging, packed)
        try:
            staging.rename(directory)
            return directory
        except OSError:
            # Taken: by another worker that finished first (then it is complete, and may be in use), or damaged.
            if _is_complete(directory, packed):
                return directory
        stale = Path(tempfile.mkdtemp(prefix=f".stale-{packed.checksum[:16]}-", dir=parent))
        try:
            directory.rename(stale / "old")
        except OSError:
            pass  # another worker set it aside first
        shutil.rmtree(stale, ignore_errors=True)
        try:
            staging.rename(directory)
        except OSError:
            if not _is_complete(directory, packed):  # not another worker that finished first
                raise
    except OSError as exc:
        raise ObjectTransferError(f"cannot write the objects under {parent}: {exc.strerror or exc}") from exc
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return directory


def materialise(packed: PackedObjects, cache_dir: str | Path | None = None) -> ObjectSet:
    """``packed`` as an ``ObjectSet`` whose URDFs lie in this machine's cache (see ``transfer_dir``);
    raises ``ObjectTransferError`` when the files cannot be written or the set's checksum is not the driver's."""
    directory = _write_materialised(packed, cache_dir)
    data_dir = Path(pybullet_data.getDataPath())
    specs = []
    for entry in packed.specs:
        tree_dir = data_dir if entry.tree is None else directory / str(entry.tree)
        specs.append(dataclasses.replace(entry.spec, urdf_path=path_inside(tree_dir, entry.urdf)))
    objects = ObjectSet(packed.source, specs, list(packed.skipped))
    checksum = objects.checksum()
    if checksum != packed.checksum:
        raise ObjectTransferError(
            f"the objects materialised in {directory} are not the driver's (checksum {checksum[:12]}, the driver's "
            f"{packed.checksum[:12]}): a pybullet_data object differs from the driver's, or a URDF changed while it was packed")
    return objects


def materialised_dir(packed: PackedObjects, cache_dir: str | Path | None = None) -> Path:
    """Where ``materialise`` puts ``packed``'s files on this machine."""
    return transfer_dir(cache_dir) / packed.checksum
