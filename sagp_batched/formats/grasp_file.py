"""The one reader of grasp files: ACRONYM's HDF5 and JSON, GraspGen's JSON, ours and those the projects publish.

What is read (all grasps in ACRONYM's gripper frame, ``frames``, of the gripper the file names):

- ACRONYM HDF5 (what ``acronym_tools.load_grasps`` / ``load_mesh`` read): ``grasps/transforms`` (N, 4, 4) gripper
  poses in the frame of the mesh ``object/file`` scaled by ``object/scale``; ``grasps/qualities/flex/object_in_gripper``
  (N,) 1 held, 0 dropped; optionally ``object/{mass, friction, density, com}`` (the COM in the scaled mesh's frame)
  our ``grasps/width`` and ``gripper/type``, the gripper. Our files (``acronym``) hold their grasps in the object's URDF link frame instead, with
  ``object/mesh_to_link`` beside them: the reader moves those grasps into the scaled mesh's frame
  (``frames.link_from_scaled_mesh``), so every ``GraspFile`` means the same frame.
- ACRONYM JSON (the same loaders' other branch): ``object``, ``object_scale``, ``transforms``,
  ``quality_flex_object_in_gripper`` at the top level.
- GraspGen JSON (``graspgen``): ``object.file``, ``object.scale``, ``grasps.transforms``, ``grasps.object_in_gripper``
  (booleans), optionally ``gripper.name``. A file naming no gripper is the Franka's; GraspGen's frame is ACRONYM's.

Bad input raises ``GraspFileError``, one line naming the file and what is wrong.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .frames import ROTATION_TOLERANCE, link_from_scaled_mesh

FLEX = "grasps/qualities/flex/object_in_gripper"


class GraspFileError(ValueError):
    """A grasp file that cannot be read; the message is one line naming the file."""


@dataclass(frozen=True)
class GraspFile:
    """One object's grasps as a grasp file gives them, in ACRONYM's gripper convention (z = approach,
    x = closing axis, origin at the gripper base), in the frame of ``mesh_file`` scaled by ``scale``."""

    path: Path
    format: str  # "acronym" (HDF5 or ACRONYM's JSON) or "graspgen"
    mesh_file: str  # as written: relative to the mesh root the file's users are given
    scale: float
    transforms: np.ndarray  # (N, 4, 4) float64
    labels: np.ndarray  # (N,) bool: held in the file's own simulation
    width_m: np.ndarray | None = None  # (N,) contact widths, where the file holds them (ours)
    mass_kg: float | None = None
    friction: float | None = None
    density_kg_m3: float | None = None
    com_m: np.ndarray | None = None  # (3,) in the scaled mesh's frame
    mesh_to_link: np.ndarray | None = None  # (4, 4) as our files write it (mesh vertices -> URDF link frame)
    # The gripper the file names (ACRONYM's ``gripper/type``, GraspGen's ``gripper.name``); a file naming none is the Franka's.
    gripper: str = "franka_panda"

    def __len__(self) -> int:
        return len(self.labels)


def read_grasp_file(path: str | Path) -> GraspFile:
    """The grasps of an ACRONYM HDF5 file or an ACRONYM / GraspGen JSON file, checked (``GraspFileError``)."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise GraspFileError(f"{path}: no such file")
    try:
        is_hdf5 = h5py.is_hdf5(path)
    except OSError as exc:
        raise GraspFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if is_hdf5:
        return _read_hdf5(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise GraspFileError(f"{path}: neither HDF5 nor JSON (not UTF-8 text)") from None
    except ValueError as exc:
        raise GraspFileError(f"{path}: neither HDF5 nor valid JSON ({exc})") from None
    except OSError as exc:
        raise GraspFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return _read_json(path, document)


# -- HDF5 ----------------------------------------------------------------------------------------------------------
def _read_hdf5(path: Path) -> GraspFile:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            values = {key: f[key][()] for key in _HDF5_KEYS if key in f}
    except (OSError, KeyError, ValueError) as exc:  # a truncated or damaged file fails inside h5py
        raise GraspFileError(f"{path}: unreadable HDF5 ({type(exc).__name__}: {exc})") from None
    for key in ("grasps/transforms", FLEX, "object/file", "object/scale"):
        if key not in values:
            raise GraspFileError(f"{path}: missing {key} (not an ACRONYM grasp file)")
    transforms = _transforms(path, "grasps/transforms", values["grasps/transforms"])
    labels = _labels(path, FLEX, values[FLEX], len(transforms))
    scale = _number(path, "object/scale", values["object/scale"], positive=True)
    com = _vector(path, "object/com", values.get("object/com"), (3,))
    mesh_to_link = _vector(path, "object/mesh_to_link", values.get("object/mesh_to_link"), (4, 4))
    if mesh_to_link is not None:
        try:
            scaled_to_link = link_from_scaled_mesh(mesh_to_link, scale)
        except ValueError as exc:
            raise GraspFileError(f"{path}: {exc}") from None
        transforms = np.linalg.inv(scaled_to_link) @ transforms
        com = None if com is None else (np.linalg.inv(scaled_to_link) @ np.append(com, 1.0))[:3]
    width = values.get("grasps/width")
    return GraspFile(
        path=path, format="acronym", mesh_file=_text(path, "object/file", values["object/file"]), scale=scale,
        transforms=transforms, labels=labels,
        width_m=None if width is None else _widths(path, width, len(transforms)),
        mass_kg=_optional_number(path, "object/mass", values.get("object/mass"), positive=True),
        friction=_optional_number(path, "object/friction", values.get("object/friction"), positive=False),
        density_kg_m3=_optional_number(path, "object/density", values.get("object/density"), positive=True),
        com_m=com, mesh_to_link=mesh_to_link,
        **({"gripper": _text(path, "gripper/type", values["gripper/type"])} if "gripper/type" in values else {}),
    )


_HDF5_KEYS = ("grasps/transforms", FLEX, "grasps/width", "object/file", "object/scale", "object/mass", "object/friction",
              "object/density", "object/com", "object/mesh_to_link", "gripper/type")


# -- JSON ----------------------------------------------------------------------------------------------------------
def _read_json(path: Path, document: Any) -> GraspFile:
    if not isinstance(document, dict):
        raise GraspFileError(f"{path}: JSON is not an object of grasp fields")
    if isinstance(document.get("object"), dict) or isinstance(document.get("grasps"), dict):
        file_format, keys = "graspgen", ("object.file", "object.scale", "grasps.transforms", "grasps.object_in_gripper")
    else:
        file_format, keys = "acronym", ("object", "object_scale", "transforms", "quality_flex_object_in_gripper")
    values = [_json_field(path, document, key) for key in keys]
    transforms = _transforms(path, keys[2], _json_array(path, keys[2], values[2]))
    return GraspFile(
        path=path, format=file_format, mesh_file=_text(path, keys[0], values[0]),
        scale=_number(path, keys[1], values[1], positive=True), transforms=transforms,
        labels=_labels(path, keys[3], _json_array(path, keys[3], values[3]), len(transforms)),
        **({"gripper": _text(path, "gripper.name", document["gripper"].get("name"))} if isinstance(document.get("gripper"), dict) else {}),
    )


def _json_field(path: Path, document: dict[str, Any], dotted: str) -> Any:
    value: Any = document
    for part in dotted.split("."):
        if not isinstance(value, dict) or part not in value:
            raise GraspFileError(f"{path}: missing {dotted}")
        value = value[part]
    return value


def _json_array(path: Path, key: str, value: Any) -> np.ndarray:
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise GraspFileError(f"{path}: {key} is not an array of numbers") from None


# -- checks --------------------------------------------------------------------------------------------------------
def _transforms(path: Path, key: str, value: Any) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.size == 0:
        return np.zeros((0, 4, 4))
    if array.ndim != 3 or array.shape[1:] != (4, 4):
        raise GraspFileError(f"{path}: {key} has shape {array.shape}, expected (N, 4, 4)")
    bad = ~np.isfinite(array).all(axis=(1, 2))
    if bad.any():
        raise GraspFileError(f"{path}: {key} holds non-finite values ({int(bad.sum())} grasp(s), first row {int(np.argmax(bad))})")
    rotation = array[:, :3, :3]
    off = (np.abs(rotation @ rotation.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2)) > ROTATION_TOLERANCE) | (np.linalg.det(rotation) < 0)
    off |= np.abs(array[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > ROTATION_TOLERANCE
    if off.any():
        raise GraspFileError(f"{path}: {key} row {int(np.argmax(off))} is not a rigid transform ({int(off.sum())} such)")
    return array


def _labels(path: Path, key: str, value: Any, n: int) -> np.ndarray:
    array = np.asarray(value)
    if array.shape != (n,):
        raise GraspFileError(f"{path}: {key} has shape {array.shape}, expected ({n},), one per transform")
    if array.dtype != bool and not np.isin(array, (0, 1)).all():
        raise GraspFileError(f"{path}: {key} holds values other than 0/1 or true/false")
    return array.astype(bool)


def _widths(path: Path, value: Any, n: int) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != (n,) or not (np.isfinite(array).all() and (array >= 0).all()):
        raise GraspFileError(f"{path}: grasps/width must hold {n} finite widths >= 0, got shape {array.shape}")
    return array


def _text(path: Path, key: str, value: Any) -> str:
    if isinstance(value, np.ndarray) and value.shape == ():
        value = value.item()
    text = value.decode("utf-8", "replace") if isinstance(value, bytes) else value
    if not isinstance(text, str) or not text:
        raise GraspFileError(f"{path}: {key} must be a non-empty string, got {value!r}")
    return text


def _number(path: Path, key: str, value: Any, positive: bool) -> float:
    try:
        number = float(np.asarray(value, dtype=np.float64).reshape(()))
    except (TypeError, ValueError):
        raise GraspFileError(f"{path}: {key} must be one number, got {value!r}") from None
    if not np.isfinite(number) or (number <= 0 if positive else number < 0):
        raise GraspFileError(f"{path}: {key} must be a finite number {'> 0' if positive else '>= 0'}, got {number}")
    return number


def _optional_number(path: Path, key: str, value: Any, positive: bool) -> float | None:
    return None if value is None else _number(path, key, value, positive)


def _vector(path: Path, key: str, value: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    if value is None:
        return None
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape or not np.isfinite(array).all():
        raise GraspFileError(f"{path}: {key} must hold {shape} finite numbers, got shape {array.shape}")
    return array
