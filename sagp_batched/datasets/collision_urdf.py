"""URDFs for worlds that simulate and never render: a robot's hand alone (its pads crowned), and an object
without its visual meshes, each with absolute mesh paths and written once per content into a cache folder;
and what an engine that builds its world itself reads of a URDF link (collision hulls, inertia, contact friction).

Crowned pads. The contact model (``execution.contact_model``) gives a pad pressed flat a uniform pressure, its
resultant at the face's centre, and puts all the resistance to turning about the normal in the torsional
friction. A rigid flat face against a flat or straight surface has no such point: PyBullet keeps up to four
manifold points spread over the face, whose lateral friction adds a lever of its own (a bar 20 % past its
torsion limit turned 0.2 deg in the shake, an ideal grip 1.5 deg), and MuJoCo keeps one point a pair at
whichever corner its collider finds, mirrored on the other pad, so the normal forces make a couple about the
approach axis that the pads' friction must also carry. The labelling hand's pads are therefore crowned
(``crowned_hull``): the face raised into a shallow paraboloid whose apex, the deepest point, where both
engines' contacts gather, is the face's centre. Its height is the rubber layer's compression under the grip
force pressed flat (``EnginePad.crown_m``): a real pad crowned that much would flatten and touch with its whole
face, so the crown moves where the contact sits, not what the pad touches (0.23 mm at the Panda's 70 N, inside
the open hand's 1 mm geometry tolerance).
"""
from __future__ import annotations

import functools
import hashlib
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, Delaunay

from .. import description_files
from ..description_files import UrdfGeometry, UrdfLink, urdf_file_path
from ..execution.contact_model import engine_pad
from ..robot.gripper_description import PAD_FACE_DEPTH_M
from ..robot.description import RobotDescription, robot_of
from ..robot.hand import grasp_frame_link_poses
from ..world.mesh_files import _read_obj_parts, obj_text

if TYPE_CHECKING:
    from ..config import Config

# Points a side of the grid a crown is sampled on, odd so one lies on the apex: at 7 the Panda's crowned finger
# is a 34-vertex hull; at 15 (120 vertices) PyBullet took 1.08 times the CPU time for the same 504 labels.
CROWN_GRID_POINTS = 7

def labelling_hand_urdf(config: Config) -> Path:
    """The hand the engines label with: the configured gripper's ``floating_hand_urdf``, its pads crowned as the
    contact model says (``EnginePad.crown_m``), cached in ``labelling.hand_urdf_cache_dir``."""
    robot = robot_of(config)
    return floating_hand_urdf(robot, config.labelling.hand_urdf_cache_dir, engine_pad(config.execution, robot).crown_m)


def floating_hand_urdf(robot: RobotDescription, cache_dir: str | Path, pad_crown_m: float = 0.0) -> Path:
    """A URDF of ``robot``'s gripper alone: its base link and every link below it (fingers on their joints,
    the grasp target), collision geometry only, mesh paths made absolute so it loads from anywhere; taken
    from the robot's URDF where the robot carries the gripper, else from the gripper's own; its pads crowned
    ``pad_crown_m`` high where that is positive (``crowned_pad_meshes``). Written once per content into
    ``cache_dir`` (named by its hash)."""
    gripper = robot.gripper
    source, name = (robot.urdf_path, robot.name) if robot.gripper_mounted else (gripper.urdf_path, gripper.name)
    crowned = crowned_pad_meshes(robot, source, pad_crown_m, cache_dir) if pad_crown_m > 0.0 else None
    text = description_files.subtree_urdf_text(source, gripper.base_link, f"{name}_floating_hand", crowned)
    return _cached_file(text, cache_dir, f"{name}_hand", ".urdf")


def collision_only_urdf(urdf_path: str | Path, cache_dir: str | Path) -> Path:
    """``urdf_path`` without its visual geometry, mesh paths made absolute, cached in ``cache_dir``.

    A world built for every grasp would otherwise parse the object's visual mesh each time (often
    far larger than its convex hulls) for a simulation that never renders."""
    urdf_path = Path(urdf_path)
    text = description_files.collision_only_urdf_text(urdf_path)
    return _cached_file(text, cache_dir, description_files.read_urdf_document(urdf_path).name or urdf_path.stem, ".urdf")


def _cached_file(text: str, cache_dir: str | Path, stem: str, suffix: str) -> Path:
    folder = Path(cache_dir).expanduser()
    path = folder / f"{stem}_{hashlib.sha256(text.encode()).hexdigest()[:16]}{suffix}"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        # Written beside its final name and moved there whole: concurrent labellers never read half a file.
        handle, partial = tempfile.mkstemp(dir=folder, suffix=f"{suffix}.partial")
        with os.fdopen(handle, "w") as stream:
            stream.write(text)
        os.replace(partial, path)
    return path


# -- crowned pads -----------------------------------------------------------------------------------------
def crowned_pad_meshes(robot: RobotDescription, urdf_path: Path, crown_m: float, cache_dir: str | Path) -> dict[tuple[str, int], str]:
    """Per pad link of the gripper in the URDF at ``urdf_path``, (link, index of its collision that reaches
    nearest the closing plane, y = 0 of the grasp frame with the hand open) -> an OBJ of that collision's hulls
    written into ``cache_dir``, its hull nearest the plane crowned ``crown_m`` high (``crowned_hull``)."""
    return {key: str(_cached_file(text, cache_dir, "crowned_pad", ".obj")) for key, text in _crowned_pad_objs(robot, Path(urdf_path), crown_m)}


# Every engine a labelling run builds asks for the same hand: its crowned hulls are computed once a process.
@functools.lru_cache(maxsize=8)
def _crowned_pad_objs(robot: RobotDescription, urdf_path: Path, crown_m: float) -> tuple[tuple[tuple[str, int], str], ...]:
    """``crowned_pad_meshes``' OBJ texts, keyed alike."""
    poses, objs = grasp_frame_link_poses(robot, robot.gripper.open_width_m), []
    for link in description_files.read_urdf_document(urdf_path).links:
        if link.name not in robot.gripper.pad_links:
            continue
        nearest = None  # (reach to the closing plane, collision index, hull index, collision placement, its hulls, the hull placed)
        for index, geometry in enumerate(link.collisions):
            placement, hulls = poses[link.name] @ geometry.origin, geometry_hulls(geometry, urdf_path, link.name)
            for part, hull in enumerate(hulls):
                placed = hull @ placement[:3, :3].T + placement[:3, 3]
                reach = np.abs(placed[:, 1]).min()
                if nearest is None or reach < nearest[0]:
                    nearest = (reach, index, part, placement, hulls, placed)
        _, index, part, placement, hulls, in_grasp = nearest
        # The grasp frame's x (across the finger), y turned toward the closing plane, and z, in the geometry's frame.
        face_frame = np.diag([1.0, -np.sign(in_grasp[:, 1].mean()), 1.0]) @ placement[:3, :3]
        hulls[part] = crowned_hull(hulls[part], face_frame, crown_m)
        objs.append(((link.name, index), obj_text([trimesh.convex.convex_hull(hull) for hull in hulls], with_normals=False)))
    return tuple(objs)


def crowned_hull(vertices: np.ndarray, face_frame: np.ndarray, crown_m: float) -> np.ndarray:
    """(V', 3) the vertices of the convex hull of ``vertices`` (a pad's hull) and a paraboloid cap on its face;
    ``face_frame`` (3, 3): its rows the face's width direction, its inward normal (toward the object) and its length
    direction, unit vectors in the vertices' frame. The cap is ``crown_m`` high at the centre of the face's
    extents (the rectangle the contact model presses, ``contact_model.pad_face_m``) and level with the face at
    the face's vertex farthest from it. The extents' centre, not the outline's centroid: a hull's face may be cut
    unevenly (the Panda's collision finger's is a pentagon, its centroid 2.5 mm to one side, mirrored on the other
    finger), and the two pads' points must face each other."""
    local = vertices @ face_frame.T  # (width, depth, length)
    deepest = local[:, 1].max()
    outline = local[local[:, 1] >= deepest - PAD_FACE_DEPTH_M][:, [0, 2]]
    outline = outline[ConvexHull(outline).vertices]
    low, high = outline.min(axis=0), outline.max(axis=0)
    centre = (low + high) / 2.0
    reach = np.linalg.norm(outline - centre, axis=1).max()
    grid = np.stack(np.meshgrid(*(np.linspace(low[i], high[i], CROWN_GRID_POINTS) for i in range(2))), axis=-1).reshape(-1, 2)
    grid = grid[Delaunay(outline).find_simplex(grid, tol=1e-12) >= 0]
    height = crown_m * (1.0 - np.sum((grid - centre) ** 2, axis=1) / reach**2)
    cap = np.column_stack([grid[:, 0], deepest + height, grid[:, 1]]) @ face_frame
    points = np.vstack([vertices, cap])
    return points[ConvexHull(points).vertices]


# -- what an engine reads of a link ------------------------------------------------------------------------
def link_collision_hulls(link: UrdfLink, urdf_path: Path) -> list[np.ndarray]:
    """(V, 3) vertices of each convex hull the link (of the URDF at ``urdf_path``) collides as, in the link frame
    (``geometry_hulls`` of each collision placed at its ``<origin>``)."""
    return [hull @ collision.origin[:3, :3].T + collision.origin[:3, 3]
            for collision in link.collisions for hull in geometry_hulls(collision, urdf_path, link.name)]


def geometry_hulls(geometry: UrdfGeometry, urdf_path: Path, link_name: str) -> list[np.ndarray]:
    """(V, 3) vertices of each convex hull a link's collision ``geometry`` (of the URDF at ``urdf_path``, link
    ``link_name``) is, in its own frame, as PyBullet builds them: one hull per ``o`` part of an OBJ mesh (a
    decomposition's hulls), one of any other mesh file, a box's corners; the mesh ``scale`` applied. Other
    primitives raise ``ValueError``."""
    if geometry.shape == "mesh":
        path = urdf_file_path(urdf_path, geometry.filename)
        parts = _read_obj_parts(path) if path.suffix.lower() == ".obj" else [trimesh.load(path, force="mesh").convex_hull]
        return [np.asarray(part.vertices) * np.array(geometry.scale) for part in parts]
    if geometry.shape == "box":
        return [description_files.box_corners(geometry.size)]
    raise ValueError(f"link '{link_name}' collides as a {geometry.shape or 'nothing'}; only meshes and boxes are read")
