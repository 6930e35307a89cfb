"""How a folder of meshes becomes objects: the settings of ``mesh_import``, each part of an object's cache key."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..config.world import GRIPPERS
from ..robot.gripper_description import load_gripper
from .objects import sagp_cache_root

DECOMPOSERS = ("auto", "coacd", "vhacd")
COACD_PREPROCESS_MODES = ("open", "auto", "on", "off")
# Settings that change no generated file: where the cache lives, and the bounds an object is judged by on loading.
NOT_IN_CACHE_KEY = frozenset({"cache_dir", "max_hull_volume_ratio", "max_hull_distance_m"})


@dataclass(frozen=True)
class MeshImportSettings:
    """How a folder of meshes becomes objects; every field but those in ``NOT_IN_CACHE_KEY`` is part of each object's
    cache key."""

    #: Metres per unit of a bare mesh file (OBJ/STL/PLY/GLB); a URDF's geometry is in metres already.
    scale: float = 1.0
    #: Density that turns a solid's volume into mass, kg/m^3 (ACRONYM's default).
    density_kg_m3: float = 150.0
    #: Mass of every object, kg, in place of ``density_kg_m3``; ``None`` derives it from the density.
    mass_kg: float | None = None
    #: Lateral (sliding) friction coefficient written into each URDF.
    friction: float = 1.0
    #: Visual colour of objects whose source gives none (a URDF's own visual colour is kept).
    rgba: tuple[float, float, float, float] = (0.65, 0.65, 0.65, 1.0)
    #: Collision decomposition: "coacd", "vhacd", or "auto" (CoACD, with V-HACD where it does not import or fails).
    decomposer: str = "auto"
    #: The surface CoACD cuts is decimated to at most this many triangles; ``None``: as is. CoACD's time grows with
    #: the triangles while a scan's 16,000 fit no better than 3,000 (the fit is measured against the full mesh).
    coacd_input_faces: int | None = 3000
    #: How far, at most, CoACD may leave a hull's surface from its part of the mesh, m: each body's concavity
    #: threshold is this over half its longest side (CoACD measures concavity on the body scaled to a longest side
    #: of 2), so a large object's hulls stray no further than a small one's. The largest value that keeps a mug's
    #: hulls within 1.15x its volume, with a margin under ``max_hull_distance_m``.
    coacd_max_concavity_m: float = 0.002
    #: CoACD's concavity threshold for a body small enough that ``coacd_max_concavity_m`` would allow more.
    concavity_threshold: float = 0.05
    #: CoACD's cap on the number of hulls (-1: none). No cap: CoACD meets one by merging hulls past its concavity
    #: threshold, and the merged hulls fill cavities again.
    max_convex_hulls: int = -1
    #: CoACD's remeshing of its input: "open" (only a surface that is not closed), or CoACD's own "auto" (also a
    #: closed one with a few self-intersecting triangles, as scans have), "on" or "off". The remeshing is a voxel
    #: surface, up to a voxel thicker than thin walls.
    coacd_preprocess_mode: str = "open"
    #: CoACD's voxel resolution of that remeshing (its default; finer voxels fit no better and cost far more time).
    coacd_preprocess_resolution: int = 50
    #: CoACD's sampling resolution of the surface (its default: fewer samples save no time worth having).
    coacd_resolution: int = 2000
    #: CoACD's Monte-Carlo tree search effort: iterations, nodes per level, depth. A short search: with the concavity
    #: threshold fixing how far hulls may stray, a deeper search for each cut buys no tighter fit, only time.
    coacd_mcts_iterations: int = 20
    coacd_mcts_nodes: int = 10
    coacd_mcts_max_depth: int = 2
    #: CoACD decimates each hull to at most this many vertices; ``None`` keeps them whole (a hull of a decimated
    #: surface's piece has a few dozen vertices: nothing to save).
    coacd_max_hull_vertices: int | None = None
    #: V-HACD's voxel resolution (the fallback: a finer grid costs far more time and still leaves a mug's hulls well
    #: past 1.15x its volume).
    vhacd_resolution: int = 100_000
    #: At most this many resting poses are kept, the most probable first.
    max_resting_poses: int = 8
    #: Resting poses whose up directions lie within this angle are one pose (the facets of a rounded body), deg.
    resting_pose_merge_deg: float = 30.0
    #: Resting poses less probable than this are dropped (the most probable one is always kept).
    min_resting_pose_probability: float = 0.01
    #: An object each of whose convex parts is wider than this in every direction cannot be grasped: the widest opening
    #: of the grippers the package describes (the planner holds each gripper to its own).
    max_grasp_width_m: float = field(default_factory=lambda: max(load_gripper(name).open_width_m for name in GRIPPERS))
    #: An object whose hulls' union holds more than this times its mesh's volume is flagged (not skipped).
    max_hull_volume_ratio: float = 1.15
    #: An object whose hulls' surface strays further than this outside its mesh is flagged (not skipped), m.
    max_hull_distance_m: float = 0.003
    #: Cache root (objects go under ``<root>/objects/``); ``None``: ``$SAGP_CACHE_DIR``, else ``~/.cache/sagp_batched``.
    cache_dir: Path | None = None

    def __post_init__(self) -> None:
        positive = {
            "scale": self.scale, "density_kg_m3": self.density_kg_m3, "concavity_threshold": self.concavity_threshold,
            "coacd_max_concavity_m": self.coacd_max_concavity_m,
            "coacd_preprocess_resolution": self.coacd_preprocess_resolution, "coacd_resolution": self.coacd_resolution,
            "coacd_mcts_iterations": self.coacd_mcts_iterations, "coacd_mcts_nodes": self.coacd_mcts_nodes,
            "coacd_mcts_max_depth": self.coacd_mcts_max_depth, "vhacd_resolution": self.vhacd_resolution,
            "max_resting_poses": self.max_resting_poses, "max_grasp_width_m": self.max_grasp_width_m,
            "max_hull_volume_ratio": self.max_hull_volume_ratio, "max_hull_distance_m": self.max_hull_distance_m,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ValueError(f"MeshImportSettings.{name} must be positive, got {value}")
        if not 0 <= self.resting_pose_merge_deg < 180:
            raise ValueError(f"MeshImportSettings.resting_pose_merge_deg must be in [0, 180), got {self.resting_pose_merge_deg}")
        if self.mass_kg is not None and not self.mass_kg > 0:
            raise ValueError(f"MeshImportSettings.mass_kg must be positive or None, got {self.mass_kg}")
        if not self.friction >= 0:
            raise ValueError(f"MeshImportSettings.friction must be >= 0, got {self.friction}")
        if not (self.max_convex_hulls == -1 or self.max_convex_hulls > 0):
            raise ValueError(f"MeshImportSettings.max_convex_hulls must be positive or -1 (no cap), got {self.max_convex_hulls}")
        if self.coacd_input_faces is not None and not self.coacd_input_faces >= 4:
            raise ValueError(f"MeshImportSettings.coacd_input_faces must be at least 4 or None, got {self.coacd_input_faces}")
        if self.coacd_max_hull_vertices is not None and not self.coacd_max_hull_vertices >= 4:
            raise ValueError(f"MeshImportSettings.coacd_max_hull_vertices must be at least 4 or None, got {self.coacd_max_hull_vertices}")
        if self.coacd_preprocess_mode not in COACD_PREPROCESS_MODES:
            raise ValueError(f"MeshImportSettings.coacd_preprocess_mode must be one of {', '.join(COACD_PREPROCESS_MODES)}, "
                             f"got '{self.coacd_preprocess_mode}'")
        if self.decomposer not in DECOMPOSERS:
            raise ValueError(f"MeshImportSettings.decomposer must be one of {', '.join(DECOMPOSERS)}, got '{self.decomposer}'")

    def cache_root(self) -> Path:
        return sagp_cache_root(self.cache_dir) / "objects"
