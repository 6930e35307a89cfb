"""Annotated functional regions: where a person grasps an object to use it, and where a grasp is wrong.

Grasps are measured against the object itself, not against the pipeline's own zones: each annotated
object has a ``functional`` region (mug handle, drill grip, ...) and an ``avoid`` region (mug rim,
drill chuck, ...), each a union of axis-aligned boxes in the object's link frame (the frame of its
``textured.obj`` vertices: metres, origin at the bottom centre, z up). The table lives in
``sagp_batched/data/functional_regions.json``; its ``method`` field says how the boxes were made.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import numpy as np

REGION_NAMES = ("functional", "avoid")
DEFAULT_SOURCE = "sagp_batched/data/functional_regions.json"


@dataclass(frozen=True)
class RegionBox:
    """An axis-aligned box in the object frame, metres; ``min`` < ``max`` on every axis."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]

    def contains(self, points_object: np.ndarray) -> np.ndarray:
        """points_object: (N, 3) in the object frame, metres. Returns (N,) bool, faces included."""
        return np.all((points_object >= self.min) & (points_object <= self.max), axis=-1)


@dataclass(frozen=True)
class ObjectRegions:
    """One object's annotation: each region's boxes and the reason people hold (or avoid) it there."""

    object_id: str
    functional: tuple[RegionBox, ...]
    avoid: tuple[RegionBox, ...]
    functional_reason: str
    avoid_reason: str

    def contains(self, region: str, points_object: np.ndarray) -> np.ndarray:
        """region: "functional" or "avoid"; points_object: (N, 3), object frame, metres. Returns (N,)
        bool, True where a point lies in any of the region's boxes."""
        boxes: tuple[RegionBox, ...] = getattr(self, region)
        inside = np.zeros(points_object.shape[0], dtype=bool)
        for box in boxes:
            inside |= box.contains(points_object)
        return inside


def _vector(value: Any, where: str) -> tuple[float, float, float]:
    if (not isinstance(value, list) or len(value) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)):
        raise ValueError(f"{where}: expected a list of 3 finite numbers in metres, got {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def _region(object_id: str, name: str, entry: Any, source: str) -> tuple[tuple[RegionBox, ...], str]:
    where = f"{source}: object '{object_id}' field '{name}'"
    if not isinstance(entry, dict):
        raise ValueError(f"{where}: expected an object with 'reason' and 'boxes', got {type(entry).__name__}")
    reason = entry.get("reason")
    if not isinstance(reason, str) or not reason.strip():
        raise ValueError(f"{where}.reason: expected a non-empty string, got {reason!r}")
    raw_boxes = entry.get("boxes")
    if not isinstance(raw_boxes, list) or not raw_boxes:
        raise ValueError(f"{where}.boxes: expected a non-empty list of boxes, got {raw_boxes!r}")
    boxes = []
    for i, raw in enumerate(raw_boxes):
        if not isinstance(raw, dict) or set(raw) != {"min", "max"}:
            raise ValueError(f"{where}.boxes[{i}]: expected {{'min': [x, y, z], 'max': [x, y, z]}}, got {raw!r}")
        low, high = _vector(raw["min"], f"{where}.boxes[{i}].min"), _vector(raw["max"], f"{where}.boxes[{i}].max")
        if not all(a < b for a, b in zip(low, high)):
            raise ValueError(f"{where}.boxes[{i}]: min {list(low)} is not below max {list(high)} on every axis")
        boxes.append(RegionBox(low, high))
    return tuple(boxes), reason


def parse_regions(table: Any, source: str = DEFAULT_SOURCE) -> dict[str, ObjectRegions]:
    """Validate a decoded ``functional_regions.json`` and return object id -> its regions.

    Raises ValueError, one line naming the object and the field, on any malformed entry."""
    if not isinstance(table, dict):
        raise ValueError(f"{source}: expected a JSON object at the top level, got {type(table).__name__}")
    if not isinstance(table.get("method"), str) or not table["method"].strip():
        raise ValueError(f"{source}: field 'method': expected a non-empty string describing how the boxes were made")
    objects = table.get("objects")
    if not isinstance(objects, dict):
        raise ValueError(f"{source}: field 'objects': expected an object mapping object ids to regions")
    regions = {}
    for object_id, entry in objects.items():
        if not isinstance(entry, dict):
            raise ValueError(f"{source}: object '{object_id}': expected an object with 'functional' and 'avoid'")
        missing = [name for name in REGION_NAMES if name not in entry]
        if missing:
            raise ValueError(f"{source}: object '{object_id}': missing field '{missing[0]}'")
        functional, functional_reason = _region(object_id, "functional", entry["functional"], source)
        avoid, avoid_reason = _region(object_id, "avoid", entry["avoid"], source)
        regions[object_id] = ObjectRegions(object_id, functional, avoid, functional_reason, avoid_reason)
    return regions


def load_regions(path: str | Path | None = None) -> dict[str, ObjectRegions]:
    """The annotations from ``path``, or from the package's ``data/functional_regions.json``."""
    if path is None:
        return _package_regions()
    return parse_regions(json.loads(Path(path).read_text()), str(path))


@lru_cache(maxsize=1)
def _package_regions() -> dict[str, ObjectRegions]:
    text = resources.files("sagp_batched").joinpath("data/functional_regions.json").read_text()
    return parse_regions(json.loads(text))


def region_membership(object_id: str, midpoint_object: np.ndarray,
                      regions: Mapping[str, ObjectRegions] | None = None) -> dict[str, Any]:
    """Whether grasp contact midpoints lie in the object's functional and avoid regions.

    midpoint_object: (3,) or (N, 3), object link frame, metres. Returns {"in_functional_region",
    "in_avoid_region"}: a bool each for a (3,) midpoint, (N,) bool arrays for (N, 3), and None for
    both when ``object_id`` has no annotation. ``regions`` defaults to the package's table."""
    annotation = (load_regions() if regions is None else regions).get(object_id)
    if annotation is None:
        return {"in_functional_region": None, "in_avoid_region": None}
    points = np.asarray(midpoint_object, dtype=float)
    if points.shape[-1:] != (3,) or points.ndim not in (1, 2):
        raise ValueError(f"midpoint_object: expected shape (3,) or (N, 3), got {points.shape}")
    functional = annotation.contains("functional", points.reshape(-1, 3))
    avoid = annotation.contains("avoid", points.reshape(-1, 3))
    if points.ndim == 1:
        return {"in_functional_region": bool(functional[0]), "in_avoid_region": bool(avoid[0])}
    return {"in_functional_region": functional, "in_avoid_region": avoid}


def mesh_vertices(obj_path: str | Path) -> np.ndarray:
    """(N, 3) vertex positions of a Wavefront OBJ (its ``v`` lines), in the mesh's own frame and units."""
    vertices = [line.split()[1:4] for line in Path(obj_path).read_text().splitlines() if line.startswith("v ")]
    if not vertices:
        raise ValueError(f"{obj_path}: no 'v' lines")
    return np.asarray(vertices, dtype=float)
