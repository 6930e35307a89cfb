"""What geometry alone decides about a grasp, on the object's true mesh rather than its collision hulls.

A label is the outcome of a simulation, and a simulation that starts with the open hand inside the
object or the table tests nothing: such a grasp is labelled a collision here, without simulating it.
The test is on the mesh the object is (its visual mesh, the surface a learner sees), so hulls that
overfill a cavity cannot turn a free grasp into a collision.

- ``ObjectSurface``: the object's mesh in its link frame, points spread over its surface, and an
  Open3D ray-casting scene for occupancy and widths.
- ``open_hand_collisions``: for each grasp, whether the open hand's collision hulls (the ones the
  simulation collides) hold any of the object's surface points deeper than a tolerance, hold the
  object's interior (a hand wholly inside a solid crosses no surface), or reach below the table.
- ``finger_contacts``, ``contact_widths``: where the closing fingers meet the mesh, and the gap between.
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import ConvexHull

from ..formats.frames import mesh_reference
from ..grasps import GraspPoses
from ..robot.description import RobotDescription
from ..robot.hand import DOP_DIRECTIONS, load_hand_geometry
from ..types import PerceivedCloud
from ..world.objects import ObjectSpec, objects_root
from ..world.perception import voxel_downsample

# Surface points are spread this far apart: well under a finger's 14 mm thinnest side, so a wall
# crossing a finger always leaves points inside it.
SURFACE_SPACING_M = 0.0015
MAX_SURFACE_POINTS = 200_000
# Points in random order, so every 4th is an even subsample ~3 mm apart: still well under a finger's side.
CLEARANCE_STRIDE = 4
# Grasps tested together: (grasps x points x 13) projections stay within a few tens of MB.
GRASPS_PER_BLOCK = 32


@dataclass(frozen=True)
class ObjectSurface:
    """An object's mesh in its link frame: points on its surface and a ray-casting scene of it."""

    points: torch.Tensor  # (P, 3) float32, link frame
    normals: np.ndarray  # (P, 3) outward unit normals of the faces the points lie on
    scene: object  # open3d.t.geometry.RaycastingScene of the mesh
    watertight: bool

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(M,) whether each point (link frame) lies inside the mesh; False for an open mesh, whose inside is undefined."""
        if not self.watertight or len(points) == 0:
            return np.zeros(len(points), dtype=bool)
        from .._open3d import o3d

        query = o3d.core.Tensor(np.asarray(points, dtype=np.float32))
        return self.scene.compute_occupancy(query, nsamples=3).numpy() > 0.5

    @property
    def box_centre(self) -> np.ndarray:
        """(3,) the centre of the surface's bounding box, link frame."""
        points = self.points.numpy()
        return (points.min(axis=0) + points.max(axis=0)) / 2.0


def object_mesh_link(spec: ObjectSpec):
    """The object's visual mesh as a ``trimesh.Trimesh`` in its link frame, metres, as geometry alone
    (``solid_surface``)."""
    import trimesh

    mesh_file, _, _, mesh_to_link = mesh_reference(spec)
    if not mesh_file:
        raise ValueError(f"object '{spec.id}' has no visual mesh to test grasps against")
    path = objects_root(Path(spec.urdf_path).resolve()) / mesh_file
    mesh = solid_surface(trimesh.load(path, force="mesh", process=True))
    mesh.apply_transform(mesh_to_link)
    return mesh


def solid_surface(mesh):
    """A visual mesh as geometry alone: vertices merged across texture seams, which a scan's textured mesh
    keeps apart (leaving it open, its volume and inside unknown), and bodies too small to enclose anything
    (stray triangle pairs) dropped."""
    import trimesh

    merged = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    merged.merge_vertices(merge_tex=True, merge_norm=True)
    bodies = [body for body in merged.split(only_watertight=False) if len(body.faces) >= 4]
    return trimesh.util.concatenate(bodies) if bodies else merged


@functools.lru_cache(maxsize=16)
def object_surface(spec: ObjectSpec) -> ObjectSurface:
    """The object's surface for geometric tests (cached per object: building it costs a mesh load)."""
    import trimesh

    from .._open3d import o3d

    mesh = object_mesh_link(spec)
    count = int(np.clip(mesh.area / SURFACE_SPACING_M**2, 1_000, MAX_SURFACE_POINTS))
    # A fixed seed: a label never depends on the draw.
    samples, faces = trimesh.sample.sample_surface(mesh, count, seed=0)
    points = np.concatenate([samples, mesh.vertices])
    normals = np.concatenate([mesh.face_normals[faces], mesh.vertex_normals])
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    return ObjectSurface(torch.as_tensor(points, dtype=torch.float32), normals, scene, bool(mesh.is_watertight))


@dataclass(frozen=True)
class _HandHulls:
    """The open hand's collision hulls in the grasp frame: k-DOP bounds to cull points, half-spaces to test them."""

    dop_low: torch.Tensor  # (H, 13)
    dop_high: torch.Tensor  # (H, 13)
    planes: tuple[torch.Tensor, ...]  # per hull (F, 4): outward normal, offset
    vertices: torch.Tensor  # (V, 3) every hull's vertices
    centres: torch.Tensor  # (H, 3) each hull's vertex mean: a point well inside it


@functools.lru_cache(maxsize=4)
def _hand_hulls(robot: RobotDescription, links: tuple[str, ...]) -> _HandHulls:
    geometry = load_hand_geometry(robot)
    keep = [i for i, name in enumerate(geometry.links) if name in links]
    hulls = [geometry.hull_vertices[i].double() for i in keep]
    planes = tuple(torch.as_tensor(ConvexHull(hull.numpy()).equations, dtype=torch.float32) for hull in hulls)
    return _HandHulls(geometry.dop_low[keep], geometry.dop_high[keep], planes, torch.cat(hulls).float(),
                      torch.stack([hull.mean(dim=0) for hull in hulls]).float())


def floating_hand_links(robot: RobotDescription) -> tuple[str, ...]:
    """The links of the hand hand-mode labels simulate: the gripper's, not the arm above them."""
    return robot.gripper.collision_links


def open_hand_clear(surface: ObjectSurface, poses: GraspPoses, robot: RobotDescription, tolerance_m: float) -> np.ndarray:
    """(N,) whether the open hand at each grasp pose (object frame) stays out of the object's mesh, on
    every ``CLEARANCE_STRIDE``-th surface point: a dataset asks this of every pose it could pick (thousands),
    the labels of the few it picks then test every point."""
    sparse = dataclasses.replace(surface, points=surface.points[::CLEARANCE_STRIDE], normals=surface.normals[::CLEARANCE_STRIDE])
    object_hit, _ = open_hand_collisions(sparse, poses, robot, floating_hand_links(robot), tolerance_m)
    return ~object_hit


def open_hand_collisions(
    surface: ObjectSurface,
    poses: GraspPoses,
    robot: RobotDescription,
    links: tuple[str, ...],
    tolerance_m: float,
    table_plane: tuple[np.ndarray, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(N,) object and (N,) table collisions of the open hand at each grasp pose (object frame).

    The object: a surface point inside a hull by more than ``tolerance_m``, or a hull's centre
    inside a watertight mesh. The table: ``table_plane`` (unit normal pointing up, offset: the
    plane is normal . x + offset = 0, object frame) with a hull vertex more than ``tolerance_m`` below it.
    """
    if poses.frame != "object":
        raise ValueError(f"open-hand collisions are tested in the object frame, got poses in the {poses.frame} frame")
    hulls = _hand_hulls(robot, links)
    rotation, position = poses.rotation.float(), poses.position.float()
    object_hit = np.zeros(len(poses), dtype=bool)
    for first in range(0, len(poses), GRASPS_PER_BLOCK):
        block = slice(first, first + GRASPS_PER_BLOCK)
        object_hit[block] = _surface_in_hulls(surface.points, rotation[block], position[block], hulls, tolerance_m)
    centres = (rotation @ hulls.centres.T).transpose(1, 2) + position[:, None]  # (N, H, 3)
    object_hit |= surface.inside(centres.reshape(-1, 3).numpy()).reshape(len(poses), len(hulls.centres)).any(axis=1)
    table_hit = np.zeros(len(poses), dtype=bool)
    if table_plane is not None:
        normal, offset = table_plane
        vertices = (rotation @ hulls.vertices.T).transpose(1, 2) + position[:, None]  # (N, V, 3)
        heights = vertices.double().numpy() @ np.asarray(normal, dtype=float) + float(offset)
        table_hit = (heights < -tolerance_m).any(axis=1)
    return object_hit, table_hit


def _surface_in_hulls(points: torch.Tensor, rotation: torch.Tensor, position: torch.Tensor, hulls: _HandHulls,
                      tolerance_m: float) -> np.ndarray:
    """(B,) whether any surface point lies inside any hand hull by more than ``tolerance_m``, for a block of grasps."""
    local = torch.einsum("bji,pj->bpi", rotation, points) - torch.einsum("bji,bj->bi", rotation, position)[:, None]  # (B, P, 3)
    hit = torch.zeros(len(rotation), dtype=torch.bool)
    for low, high, planes in zip(hulls.dop_low, hulls.dop_high, hulls.planes):
        # The k-DOP's first three directions are the frame's axes: the hull's box is tested on every
        # point, its other ten directions only on the few points inside the box (a third of the work).
        in_box = ((local >= low[:3] - 1e-6) & (local <= high[:3] + 1e-6)).all(dim=2)  # (B, P)
        grasp_index, point_index = in_box.nonzero(as_tuple=True)
        candidates = local[grasp_index, point_index]  # (K, 3)
        along = candidates @ DOP_DIRECTIONS[3:].T
        within = ((along >= low[3:] - 1e-6) & (along <= high[3:] + 1e-6)).all(dim=1)
        grasp_index, candidates = grasp_index[within], candidates[within]
        if len(grasp_index) == 0:
            continue
        depth = -(candidates @ planes[:, :3].T + planes[:, 3]).max(dim=1).values  # distance inside the hull
        hit[grasp_index[depth > tolerance_m]] = True
    return hit.numpy()


@dataclass(frozen=True)
class FingerContacts:
    """Where each grasp's closing fingers first meet the mesh along the closing axis through its centre
    (object frame): ``points`` (N, 2, 3) and ``normals`` (N, 2, 3, outward), index 0 the finger on
    the closing axis' negative side; ``travel_m`` (N, 2) how far each pad moves from the open
    position before it meets the surface (the open width where it meets nothing)."""

    points: np.ndarray
    normals: np.ndarray
    travel_m: np.ndarray

    @property
    def both_met(self) -> np.ndarray:
        """(N,) whether both fingers meet the mesh before closing fully."""
        return np.isfinite(self.points).all(axis=(1, 2))


def finger_contacts(surface: ObjectSurface, poses: GraspPoses, open_width_m: float) -> FingerContacts:
    """Each pose's ``FingerContacts``: one ray a finger, from its open pad toward the grasp centre."""
    from .._open3d import o3d

    if poses.frame != "object":
        raise ValueError(f"finger contacts are measured in the object frame, got poses in the {poses.frame} frame")
    centre, closing = poses.position.numpy(), poses.rotation[:, :, 1].numpy()
    half = open_width_m / 2.0
    origins = np.stack([centre - half * closing, centre + half * closing])  # (2, N, 3): finger 0 at -y
    directions = np.stack([closing, -closing])
    rays = np.concatenate([origins, directions], axis=2).reshape(-1, 6).astype(np.float32)
    cast = surface.scene.cast_rays(o3d.core.Tensor(rays))
    hits = cast["t_hit"].numpy().reshape(2, -1)
    met = hits <= open_width_m
    points = np.where(met[..., None], origins + np.where(met, hits, 0.0)[..., None] * directions, np.nan)
    normals = np.where(met[..., None], cast["primitive_normals"].numpy().reshape(2, -1, 3), np.nan)
    travel = np.minimum(hits, open_width_m)
    return FingerContacts(points.transpose(1, 0, 2), normals.transpose(1, 0, 2), travel.T)


def contact_widths(surface: ObjectSurface, poses: GraspPoses, open_width_m: float) -> np.ndarray:
    """(N,) the gap between the points where each grasp's closing fingers first meet the mesh, along
    the closing axis through the grasp centre (0 where they meet nothing), capped at ``open_width_m``."""
    travel = finger_contacts(surface, poses, open_width_m).travel_m
    return np.clip(open_width_m - travel.sum(axis=1), 0.0, open_width_m)


def whole_object_cloud(cloud: PerceivedCloud, surface: ObjectSurface, voxel_size_m: float) -> PerceivedCloud:
    """``cloud`` with its points replaced by the object's whole surface where it stands (every side,
    the parts the cameras never see among them), at the perception's voxel size, with the mesh's
    outward normals: the candidates of a protocol that grasps the object from any direction."""
    world_from_object = np.linalg.inv(cloud.object_from_world)
    points = surface.points.double().numpy() @ world_from_object[:3, :3].T + world_from_object[:3, 3]
    points, source = voxel_downsample(points, np.arange(len(points)), voxel_size_m)
    normals = surface.normals[source] @ world_from_object[:3, :3].T
    return dataclasses.replace(cloud, points_world=torch.as_tensor(points, dtype=torch.float32),
                               normals_world=torch.as_tensor(normals, dtype=torch.float32),
                               view_index=torch.zeros(len(points), dtype=torch.int64))
