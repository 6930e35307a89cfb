"""How faithfully an object's collision hulls stand for its mesh: how much volume their union adds, and how far
their surface strays from the mesh's.

Grasps are simulated against the hulls, not the mesh: hulls that fill a mug's cavity or thicken its walls make a
descent collide where the real object has no material, so each imported object records these figures and is
flagged when they pass ``MeshImportSettings``' bounds.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError
from scipy.stats import qmc

from .._open3d import o3d

# Quasi-random points in the hulls' bounding box: the union's volume to about 0.5 % of the box's.
VOLUME_SAMPLES = 200_000
# Points on the hulls' surfaces (besides their vertices, where a hull strays furthest) for the distance.
SURFACE_SAMPLES = 50_000
# A point this close to a hull's plane counts as on it: a surface point of one hull that another hull holds is on a
# face inside the union, which no collision touches.
PLANE_TOLERANCE_M = 1e-6
# (point, plane) pairs tested at once: the products stay in cache instead of filling memory for a hull of many faces.
CHUNK_PAIRS = 1 << 18


@dataclass(frozen=True)
class HullFidelity:
    """The hulls' union against the mesh it stands for."""

    #: Volume of the hulls' union over the mesh's volume: 1 when they fit, 2.5 when a mug's cavity is filled.
    volume_ratio: float
    #: Largest distance from a point on the union's surface that lies outside the mesh to the mesh's surface, m.
    max_hull_to_mesh_distance_m: float
    #: The mean of those distances (points inside the mesh counting 0), m.
    mean_hull_to_mesh_distance_m: float
    hull_volume_m3: float
    mesh_volume_m3: float
    #: "mesh": a closed mesh's own volume; "bodies": the sampled union of a closed mesh's several bodies (shapes
    #: made of overlapping closed parts, whose summed volume counts the overlaps twice); "convex hull": a mesh
    #: that is not closed, whose convex hull's volume stands in (the ratio then understates the hulls' excess, and
    #: inside-ness is unknown, so every point's distance counts).
    mesh_volume_from: str


def fidelity_issues(volume_ratio: float, max_distance_m: float, volume_from: str, max_volume_ratio: float,
                    max_distance_bound_m: float) -> list[str]:
    """Each bound the hulls pass, in words (empty when they fit)."""
    issues = []
    if volume_ratio > max_volume_ratio:
        issues.append(f"its collision hulls hold {volume_ratio:.2f}x its mesh's volume ({volume_from}), over {max_volume_ratio:.2f}x")
    if max_distance_m > max_distance_bound_m:
        issues.append(f"its collision hulls stray {max_distance_m * 1000:.1f} mm outside its mesh, over {max_distance_bound_m * 1000:.1f} mm")
    return issues


class _Solid:
    """A mesh as distances to its surface and, where it is closed, which points lie inside it (inside any of its
    bodies: ray parity alone would call a point inside two overlapping bodies outside)."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.closed = bool(mesh.is_watertight)
        self.bodies = list(mesh.split(only_watertight=False)) if self.closed else []
        self._surface = _scene([mesh])
        self._bodies = [_scene([body]) for body in self.bodies]

    def distance(self, points: np.ndarray) -> np.ndarray:
        return self._surface.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy().astype(np.float64)

    def contains(self, points: np.ndarray) -> np.ndarray:
        query = o3d.core.Tensor(points.astype(np.float32))
        inside = np.zeros(len(points), dtype=bool)
        for scene in self._bodies:
            inside |= scene.compute_occupancy(query, nsamples=3).numpy() > 0.5
        return inside


def _scene(meshes: list[trimesh.Trimesh]) -> "o3d.t.geometry.RaycastingScene":
    scene = o3d.t.geometry.RaycastingScene()
    for mesh in meshes:
        scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
                            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)))
    return scene


def hull_fidelity(mesh: trimesh.Trimesh, hulls: list[trimesh.Trimesh], volume_samples: int = VOLUME_SAMPLES,
                  surface_samples: int = SURFACE_SAMPLES, seed: int = 0) -> HullFidelity:
    """The volume ratio and the hull-to-mesh distances of ``hulls`` (convex) against ``mesh``; the same for the
    same inputs and seed."""
    planes = [_planes(hull) for hull in hulls]
    hull_volume = _sampled_volume(np.array([hull.bounds for hull in hulls]), volume_samples, seed,
                                  lambda points: _inside_any(points, hulls, planes, tolerance=0.0))
    solid = _Solid(mesh)
    if not solid.closed:
        mesh_volume, volume_from = float(mesh.convex_hull.volume), "convex hull"
    elif len(solid.bodies) == 1:
        mesh_volume, volume_from = float(mesh.volume), "mesh"
    else:
        mesh_volume, volume_from = _sampled_volume(mesh.bounds[None], volume_samples, seed, solid.contains), "bodies"
    distances = _surface_distances(solid, hulls, planes, surface_samples, seed)
    return HullFidelity(
        volume_ratio=hull_volume / mesh_volume,
        max_hull_to_mesh_distance_m=float(distances.max(initial=0.0)),
        mean_hull_to_mesh_distance_m=float(distances.mean()) if len(distances) else 0.0,
        hull_volume_m3=hull_volume,
        mesh_volume_m3=mesh_volume,
        mesh_volume_from=volume_from,
    )


def _planes(hull: trimesh.Trimesh) -> np.ndarray:
    """(F, 4) outward unit normals and offsets: a point x is inside where ``n . x + d <= 0`` for every row. Coplanar
    facets share a row; single precision is a nanometre's error at these sizes and halves the tests' time."""
    try:
        equations = ConvexHull(hull.vertices).equations
    except QhullError:  # a flat hull holds no volume: no point is inside it
        return np.array([[0.0, 0.0, 1.0, -np.inf]], dtype=np.float32)
    return np.unique(np.round(equations, 9), axis=0).astype(np.float32)


def _inside_any(points: np.ndarray, hulls: list[trimesh.Trimesh], planes: list[np.ndarray], tolerance: float,
                skip: int = -1) -> np.ndarray:
    """Whether each point lies within ``tolerance`` inside some hull (hull ``skip`` aside)."""
    inside = np.zeros(len(points), dtype=bool)
    single = points.astype(np.float32)
    for index, (hull, equations) in enumerate(zip(hulls, planes)):
        if index == skip:
            continue
        lower, upper = hull.bounds
        candidates = np.flatnonzero(~inside & np.all((points >= lower - tolerance) & (points <= upper + tolerance), axis=1))
        normals, offsets = equations[:, :3].T.copy(), equations[:, 3]
        rows = max(1, CHUNK_PAIRS // len(equations))
        for start in range(0, len(candidates), rows):
            chosen = candidates[start:start + rows]
            signed = single[chosen] @ normals
            signed += offsets
            inside[chosen[signed.max(axis=1) <= -tolerance]] = True
    return inside


def _sampled_volume(bounds: np.ndarray, samples: int, seed: int, inside: Callable[[np.ndarray], np.ndarray]) -> float:
    """The volume of what ``inside`` holds, from quasi-random points in the box around every (2, 3) ``bounds``."""
    lower, upper = bounds[:, 0].min(axis=0), bounds[:, 1].max(axis=0)
    points = lower + qmc.Halton(d=3, scramble=True, seed=seed).random(samples) * (upper - lower)
    return float(np.prod(upper - lower) * inside(points).mean())


def _surface_distances(solid: _Solid, hulls: list[trimesh.Trimesh], planes: list[np.ndarray], samples: int,
                       seed: int) -> np.ndarray:
    """Distance to the mesh's surface of points on the union's surface; 0 for those inside a closed mesh."""
    areas = np.array([hull.area for hull in hulls])
    counts = np.maximum(1, np.round(samples * areas / areas.sum())).astype(int)
    points = []
    for index, (hull, count) in enumerate(zip(hulls, counts)):
        on_hull = np.concatenate([hull.vertices, trimesh.sample.sample_surface(hull, int(count), seed=seed + index)[0]])
        points.append(on_hull[~_inside_any(on_hull, hulls, planes, PLANE_TOLERANCE_M, skip=index)])
    points = np.concatenate(points)
    distances = solid.distance(points)
    if solid.closed:
        # Hull material inside the mesh is where the mesh has material too: only what lies outside is excess.
        distances[solid.contains(points)] = 0.0
    return distances
