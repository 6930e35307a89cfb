"""Grasp files in the layouts grasp-learning code reads, read and written here: ACRONYM's HDF5 and GraspGen's JSON.

Reading accepts the files those projects publish, not only ours:

- ACRONYM HDF5 (what ``acronym_tools.load_grasps`` / ``load_mesh`` read): ``grasps/transforms`` (N, 4, 4) Franka
  gripper poses in the frame of the mesh ``object/file`` scaled by ``object/scale``;
  ``grasps/qualities/flex/object_in_gripper`` (N,) 1 held, 0 dropped; optionally ``object/{mass, friction,
  density, com}`` (the COM in the scaled mesh's frame). Our files (``write_object_file``) hold their grasps in
  the object's URDF link frame instead, with ``object/mesh_to_link`` (mesh vertices -> link frame) beside them:
  the reader moves those grasps into the scaled mesh's frame, so every ``GraspFile`` means the same frame.
- ACRONYM JSON (the same loaders' other branch): ``object``, ``object_scale``, ``transforms``,
  ``quality_flex_object_in_gripper`` at the top level.
- GraspGen JSON: ``object.file``, ``object.scale``, ``grasps.transforms``, ``grasps.object_in_gripper`` (booleans).
  GraspGen's files name no gripper; its Franka gripper's frame is ACRONYM's (fingers along x, 0.0584 m up z).

Bad input raises ``GraspFileError``, one line naming the file and what is wrong.

Writing: one object's labelled grasps in our layout (``write_object_file``, the keys listed in ``dataset``) and in
GraspGen's (``write_graspgen_file``); a relabelled file's grasps with the file's label and ours (``relabel_bytes``).
"""
from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .export import panda_hand_transforms_object

if TYPE_CHECKING:
    from .dataset import LabelledGrasps, ObjectPhysics, UntestedGrasps

GRIPPER_TYPE = "franka_panda"
# Rotation blocks further than this from orthonormal are refused: a pose that is not one cannot be simulated.
ROTATION_TOLERANCE = 1e-4
FLEX = "grasps/qualities/flex/object_in_gripper"


class GraspFileError(ValueError):
    """A grasp file that cannot be read; the message is one line naming the file."""


@dataclass(frozen=True)
class GraspFile:
    """One object's grasps as a grasp file gives them, in ACRONYM's Franka gripper convention (z = approach,
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
        scaled_to_link = _scaled_mesh_to_link(path, mesh_to_link, scale)
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
    )


_HDF5_KEYS = ("grasps/transforms", FLEX, "grasps/width", "object/file", "object/scale", "object/mass", "object/friction",
              "object/density", "object/com", "object/mesh_to_link")


def _scaled_mesh_to_link(path: Path, mesh_to_link: np.ndarray, scale: float) -> np.ndarray:
    """The rigid transform from the scaled mesh's frame to the link frame: ``mesh_to_link`` less the scale."""
    scaled_to_link = mesh_to_link @ np.diag([1.0 / scale] * 3 + [1.0])
    rotation = scaled_to_link[:3, :3]
    if not (np.allclose(rotation @ rotation.T, np.eye(3), atol=ROTATION_TOLERANCE) and np.allclose(scaled_to_link[3], [0, 0, 0, 1])):
        # A per-axis mesh scale: no frame of the mesh at one scale holds these grasps rigidly.
        raise GraspFileError(f"{path}: object/mesh_to_link is not a rigid transform times object/scale {scale:g}")
    return scaled_to_link


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
        raise GraspFileError(f"{path}: {key} must be a non-empty mesh path, got {value!r}")
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


# -- writing -------------------------------------------------------------------------------------------------------
def string_dataset(group, name: str, values: list[str]) -> None:
    """``values`` as a UTF-8 string dataset ``name`` of an HDF5 group, the dtype ACRONYM's strings read as."""
    import h5py

    group.create_dataset(name, data=np.array(values, dtype=object), dtype=h5py.string_dtype())


def write_object_file(
    path: Path,
    object_id: str,
    mesh_file: str,
    mesh_scale: float,
    mesh_to_link: np.ndarray,
    physics: ObjectPhysics,
    grasps: LabelledGrasps,
    untested: UntestedGrasps,
    mode: str,
    protocol: str,
    rater: str,
) -> None:
    """One object's grasps as an ACRONYM-layout HDF5 file, replaced atomically."""
    import h5py

    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f["grasps/transforms"] = grasps.transforms.astype(np.float64)
        f["grasps/panda_hand_transforms"] = panda_hand_transforms_object(grasps.transforms.astype(np.float64))
        flex = "grasps/qualities/flex"
        f[f"{flex}/object_in_gripper"] = grasps.held.astype(np.int64)
        f[f"{flex}/held_fraction"] = grasps.held_fraction.astype(np.float64)
        f[f"{flex}/object_motion_during_closing_linear"] = grasps.motion_closing_linear_m.astype(np.float64)
        f[f"{flex}/object_motion_during_closing_angular"] = grasps.motion_closing_angular_rad.astype(np.float64)
        f[f"{flex}/object_motion_during_shaking_linear"] = grasps.motion_shaking_linear_m.astype(np.float64)
        f[f"{flex}/object_motion_during_shaking_angular"] = grasps.motion_shaking_angular_rad.astype(np.float64)
        for engine, held in grasps.engine_held.items():
            f[f"grasps/qualities/{engine}/object_in_gripper"] = held.astype(np.int64)
            f[f"grasps/qualities/{engine}/held_fraction"] = grasps.engine_held_fraction[engine].astype(np.float64)
            string_dataset(f, f"grasps/qualities/{engine}/failure_reason", grasps.engine_failure[engine])
        string_dataset(f, "engines", list(grasps.engine_held))
        f["grasps/qualities/terms/geom"] = grasps.s_geom.astype(np.float64)
        f["grasps/qualities/terms/reach"] = grasps.s_reach.astype(np.float64)
        f["grasps/width"] = grasps.width_m.astype(np.float64)
        f["grasps/contacts"] = grasps.contacts.astype(np.float64)
        f["grasps/resting_pose"] = grasps.resting_pose.astype(np.int64)
        for name in ("verdict", "verdict_reason", "failure_reason", "decided_by", "zone"):
            string_dataset(f, f"grasps/{name}", getattr(grasps, name))
        for task, levels in grasps.zone_rating.items():
            string_dataset(f, f"grasps/zone_rating/{task}", levels)
        f["untested/transforms"] = untested.transforms.astype(np.float64).reshape(-1, 4, 4)
        string_dataset(f, "untested/reason", untested.reason)
        f["object/file"] = mesh_file
        f["object/scale"] = float(mesh_scale)
        f["object/mesh_to_link"] = np.asarray(mesh_to_link, dtype=np.float64)
        f["object/id"] = object_id
        f["object/mass"] = float(physics.mass_kg)
        f["object/density"] = float(physics.density_kg_m3)
        f["object/friction"] = float(physics.friction)
        f["object/com"] = np.asarray(physics.com_m, dtype=np.float64)
        f["object/inertia"] = np.asarray(physics.inertia_kg_m2, dtype=np.float64)
        f["object/volume"] = float(physics.volume_m3)
        f["gripper/type"] = GRIPPER_TYPE
        f["mode"] = mode
        f["protocol"] = protocol
        f["rater"] = rater
    os.replace(tmp, path)


def write_graspgen_file(path: Path, mesh_file: str, mesh_scale: float, grasps: LabelledGrasps) -> None:
    """The same grasps in GraspGen's JSON layout, replaced atomically."""
    document = {
        "object": {"file": mesh_file, "scale": float(mesh_scale)},
        "grasps": {"transforms": grasps.transforms.tolist(), "object_in_gripper": [bool(h) for h in grasps.held]},
    }
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(document), encoding="utf-8")
    os.replace(tmp, path)




def relabel_bytes(grasp_file: GraspFile, rows: np.ndarray, link_from_file: np.ndarray, labels: list[dict[str, Any]], regions: list[str],
                  *, object_id: str, mass_kg: float, protocol: str, engine: str) -> bytes:
    """A relabelled file's rows ``rows`` as HDF5 bytes: the grasps as the file gives them (its mesh, scale and frame, so
    ACRONYM's loaders and ``read_grasp_file`` read them as they read the file), our label as ``object_in_gripper`` and
    the file's under ``grasps/reference/``; ``labels`` hold held, held_fraction, simulated, failure_reason, failed_at, and
    with several engines each one's under "by_engine" (written to ``grasps/qualities/<engine>/``)."""
    import h5py

    transforms = grasp_file.transforms[rows]
    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        f["grasps/transforms"] = transforms
        f["grasps/panda_hand_transforms"] = panda_hand_transforms_object(transforms)
        f["grasps/link_transforms"] = link_from_file @ transforms  # what our simulation ran, in the object's link frame
        f["grasps/source_index"] = np.asarray(rows, dtype=np.int64)
        f[FLEX] = np.array([label["held"] for label in labels], dtype=np.int64)
        f["grasps/reference/object_in_gripper"] = grasp_file.labels[rows].astype(np.int64)
        f["grasps/held_fraction"] = np.array([label["held_fraction"] for label in labels], dtype=np.float64)
        f["grasps/simulated"] = np.array([label["simulated"] for label in labels], dtype=np.int64)
        for name in ("failure_reason", "failed_at"):
            string_dataset(f, f"grasps/{name}", [label[name] for label in labels])
        string_dataset(f, "grasps/region", regions)
        for engine in labels[0].get("by_engine", {}) if labels else ():  # several engines: each one's own label
            f[f"grasps/qualities/{engine}/object_in_gripper"] = np.array([label["by_engine"][engine]["held"] for label in labels], dtype=np.int64)
            string_dataset(f, f"grasps/qualities/{engine}/failed_at", [label["by_engine"][engine]["failed_at"] for label in labels])
        if grasp_file.width_m is not None:
            f["grasps/width"] = grasp_file.width_m[rows]
        f["object/file"] = grasp_file.mesh_file
        f["object/scale"] = grasp_file.scale
        f["object/mesh_to_link"] = np.diag([grasp_file.scale] * 3 + [1.0])  # the file's frame is the scaled mesh's
        f["object/link_from_file"] = link_from_file
        f["object/id"] = object_id
        f["object/mass"] = float(mass_kg)
        f["gripper/type"] = GRIPPER_TYPE
        f["protocol"] = protocol
        f["engine"] = engine
        f["reference/file"] = str(grasp_file.path)
        f["reference/format"] = grasp_file.format
    return buffer.getvalue()
