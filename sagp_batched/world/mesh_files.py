"""The files an imported object is written as: Wavefront OBJ (and V-HACD's OBJ read back) and its URDF."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import trimesh

# The YCB URDFs' values: a little resistance to spinning and rolling in place.
SPINNING_FRICTION = 0.001
ROLLING_FRICTION = 0.001


def write_obj_parts(path: Path, parts: list[trimesh.Trimesh], with_normals: bool) -> None:
    """Wavefront OBJ, one ``o`` per part (PyBullet makes each part of a collision OBJ a convex hull of its own)."""
    path.write_text(obj_text(parts, with_normals))


def obj_text(parts: list[trimesh.Trimesh], with_normals: bool) -> str:
    """The Wavefront OBJ ``write_obj_parts`` writes."""
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
    return "\n".join(lines) + "\n"


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
<!-- Made by sagp_batched.world.mesh_import (cache key {key}). Units: metres. Link frame: origin at the centre of the
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
