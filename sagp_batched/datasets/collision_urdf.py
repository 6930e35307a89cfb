"""URDFs for worlds that simulate and never render: a robot's hand alone, and an object without its
visual meshes, each with absolute mesh paths and written once per content into a cache folder; and what
an engine that builds its world itself reads of a URDF link (collision hulls, inertia, contact friction)."""
from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import description_files
from ..robot.description import RobotDescription
from ..world.mesh_sources import urdf_origin

# PyBullet's surface of a link whose URDF gives no ``<contact>``: lateral friction 0.5, no spinning or rolling friction.
DEFAULT_FRICTION = (0.5, 0.0, 0.0)


def floating_hand_urdf(robot: RobotDescription, cache_dir: str | Path) -> Path:
    """A URDF of ``robot``'s gripper alone: its base link and every link below it (fingers on their joints,
    the grasp target), collision geometry only, mesh paths made absolute so it loads from anywhere; taken
    from the robot's URDF where the robot carries the gripper, else from the gripper's own. Written once
    per content into ``cache_dir`` (named by its hash)."""
    gripper = robot.gripper
    source, name = (robot.urdf_path, robot.name) if robot.gripper_mounted else (gripper.urdf_path, gripper.name)
    text = description_files.subtree_urdf_text(source, gripper.base_link, f"{name}_floating_hand")
    return _cached_urdf(text, cache_dir, f"{name}_hand")


def collision_only_urdf(urdf_path: str | Path, cache_dir: str | Path) -> Path:
    """``urdf_path`` without its visual geometry, mesh paths made absolute, cached in ``cache_dir``.

    A world built for every grasp would otherwise parse the object's visual mesh each time (often
    far larger than its convex hulls) for a simulation that never renders."""
    urdf_path = Path(urdf_path)
    text = description_files.collision_only_urdf_text(urdf_path)
    return _cached_urdf(text, cache_dir, description_files.read_urdf_document(urdf_path).name or urdf_path.stem)


def _cached_urdf(text: str, cache_dir: str | Path, stem: str) -> Path:
    folder = Path(cache_dir).expanduser()
    path = folder / f"{stem}_{hashlib.sha256(text.encode()).hexdigest()[:16]}.urdf"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        # Written beside its final name and moved there whole: concurrent labellers never read half a file.
        handle, partial = tempfile.mkstemp(dir=folder, suffix=".urdf.partial")
        with os.fdopen(handle, "w") as stream:
            stream.write(text)
        os.replace(partial, path)
    return path


# -- what an engine reads of a link ------------------------------------------------------------------------
@dataclass(frozen=True)
class LinkInertial:
    """A link's ``<inertial>``: mass (kg), its frame in the link frame (4, 4: the centre of mass and the
    axes the tensor is written in) and the (3, 3) tensor about the centre of mass (kg m^2)."""

    mass_kg: float
    frame_in_link: np.ndarray
    tensor_kg_m2: np.ndarray


def link_inertial(link: ElementTree.Element) -> LinkInertial | None:
    """The link's ``<inertial>``; None where it has none or a massless one (a frame, not a body)."""
    inertial = link.find("inertial")
    mass = inertial.find("mass") if inertial is not None else None
    if mass is None or float(mass.get("value")) <= 0.0:
        return None
    terms = inertial.find("inertia")
    value = {key: float(terms.get(key, 0.0)) if terms is not None else 0.0 for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    tensor = np.array([[value["ixx"], value["ixy"], value["ixz"]], [value["ixy"], value["iyy"], value["iyz"]],
                       [value["ixz"], value["iyz"], value["izz"]]])
    return LinkInertial(float(mass.get("value")), urdf_origin(inertial.find("origin")), tensor)


def link_friction(link: ElementTree.Element) -> tuple[float, float, float]:
    """(lateral, spinning, rolling) friction of the link's ``<contact>``, PyBullet's default for any it leaves out."""
    contact = link.find("contact")
    values = []
    for name, default in zip(("lateral_friction", "spinning_friction", "rolling_friction"), DEFAULT_FRICTION):
        element = contact.find(name) if contact is not None else None
        values.append(float(element.get("value")) if element is not None else default)
    return values[0], values[1], values[2]


def link_collision_hulls(link: ElementTree.Element, base: Path) -> list[np.ndarray]:
    """(V, 3) vertices of each convex hull the link collides as, in the link frame, as PyBullet builds
    them: one hull per ``o`` part of an OBJ mesh (a decomposition's hulls), one of any other mesh file,
    a box's corners; the ``<origin>`` and mesh ``scale`` applied. Other primitives raise ``ValueError``."""
    import trimesh

    from ..world.mesh_files import _read_obj_parts

    hulls = []
    for collision in link.findall("collision"):
        geometry = collision.find("geometry")
        mesh, box = geometry.find("mesh"), geometry.find("box")
        if mesh is not None:
            path = base / mesh.get("filename").removeprefix("package://")
            scale = np.array([float(v) for v in (mesh.get("scale") or "1 1 1").split()])
            parts = _read_obj_parts(path) if path.suffix.lower() == ".obj" else [trimesh.load(path, force="mesh").convex_hull]
            vertices = [np.asarray(part.vertices) * scale for part in parts]
        elif box is not None:
            corners = np.array(np.meshgrid([-0.5, 0.5], [-0.5, 0.5], [-0.5, 0.5], indexing="ij")).reshape(3, -1).T
            vertices = [corners * [float(v) for v in box.get("size").split()]]
        else:
            kind = next((child.tag for child in geometry), "nothing")
            raise ValueError(f"link '{link.get('name')}' collides as a {kind}; only meshes and boxes are read")
        origin = urdf_origin(collision.find("origin"))
        hulls.extend(part @ origin[:3, :3].T + origin[:3, 3] for part in vertices)
    return hulls
