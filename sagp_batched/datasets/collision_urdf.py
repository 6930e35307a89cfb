"""URDFs for worlds that simulate and never render: a robot's hand alone, and an object without its
visual meshes, each with absolute mesh paths and written once per content into a cache folder; and what
an engine that builds its world itself reads of a URDF link (collision hulls, inertia, contact friction)."""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from .. import description_files
from ..description_files import UrdfLink, urdf_file_path
from ..robot.description import RobotDescription

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
def link_collision_hulls(link: UrdfLink, urdf_path: Path) -> list[np.ndarray]:
    """(V, 3) vertices of each convex hull the link (of the URDF at ``urdf_path``) collides as, in the link frame, as
    PyBullet builds them: one hull per ``o`` part of an OBJ mesh (a decomposition's hulls), one of any other mesh
    file, a box's corners; the ``<origin>`` and mesh ``scale`` applied. Other primitives raise ``ValueError``."""
    import trimesh

    from ..world.mesh_files import _read_obj_parts

    hulls = []
    for collision in link.collisions:
        if collision.shape == "mesh":
            path = urdf_file_path(urdf_path, collision.filename)
            parts = _read_obj_parts(path) if path.suffix.lower() == ".obj" else [trimesh.load(path, force="mesh").convex_hull]
            vertices = [np.asarray(part.vertices) * np.array(collision.scale) for part in parts]
        elif collision.shape == "box":
            corners = np.array(np.meshgrid([-0.5, 0.5], [-0.5, 0.5], [-0.5, 0.5], indexing="ij")).reshape(3, -1).T
            vertices = [corners * np.array(collision.size)]
        else:
            raise ValueError(f"link '{link.name}' collides as a {collision.shape or 'nothing'}; only meshes and boxes are read")
        hulls.extend(part @ collision.origin[:3, :3].T + collision.origin[:3, 3] for part in vertices)
    return hulls
