"""How a folder of meshes becomes objects: the settings of ``mesh_import``, each part of an object's cache key."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..robot.description import load_robot
from .objects import sagp_cache_root

DECOMPOSERS = ("auto", "coacd", "vhacd")


@dataclass(frozen=True)
class MeshImportSettings:
    """How a folder of meshes becomes objects; every field but ``cache_dir`` is part of each object's cache key."""

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
    #: Collision decomposition: "coacd", "vhacd", or "auto" (CoACD where it imports, else V-HACD).
    decomposer: str = "auto"
    #: CoACD's concavity threshold: lower splits into more, tighter hulls.
    concavity_threshold: float = 0.05
    #: CoACD's cap on the number of hulls.
    max_convex_hulls: int = 16
    #: CoACD's sampling resolution of the surface.
    coacd_resolution: int = 2000
    #: CoACD's Monte-Carlo tree search effort: iterations, nodes per level, depth.
    coacd_mcts_iterations: int = 150
    coacd_mcts_nodes: int = 20
    coacd_mcts_max_depth: int = 3
    #: V-HACD's voxel resolution.
    vhacd_resolution: int = 100_000
    #: At most this many resting poses are kept, the most probable first.
    max_resting_poses: int = 8
    #: Resting poses less probable than this are dropped (the most probable one is always kept).
    min_resting_pose_probability: float = 0.01
    #: An object each of whose convex parts is wider than this in every direction cannot be grasped: the Panda's open hand.
    max_grasp_width_m: float = field(default_factory=lambda: load_robot().open_width_m)
    #: Cache root (objects go under ``<root>/objects/``); ``None``: ``$SAGP_CACHE_DIR``, else ``~/.cache/sagp_batched``.
    cache_dir: Path | None = None

    def __post_init__(self) -> None:
        positive = {
            "scale": self.scale, "density_kg_m3": self.density_kg_m3, "concavity_threshold": self.concavity_threshold,
            "max_convex_hulls": self.max_convex_hulls, "coacd_resolution": self.coacd_resolution,
            "coacd_mcts_iterations": self.coacd_mcts_iterations, "coacd_mcts_nodes": self.coacd_mcts_nodes,
            "coacd_mcts_max_depth": self.coacd_mcts_max_depth, "vhacd_resolution": self.vhacd_resolution,
            "max_resting_poses": self.max_resting_poses, "max_grasp_width_m": self.max_grasp_width_m,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ValueError(f"MeshImportSettings.{name} must be positive, got {value}")
        if self.mass_kg is not None and not self.mass_kg > 0:
            raise ValueError(f"MeshImportSettings.mass_kg must be positive or None, got {self.mass_kg}")
        if not self.friction >= 0:
            raise ValueError(f"MeshImportSettings.friction must be >= 0, got {self.friction}")
        if self.decomposer not in DECOMPOSERS:
            raise ValueError(f"MeshImportSettings.decomposer must be one of {', '.join(DECOMPOSERS)}, got '{self.decomposer}'")

    def cache_root(self) -> Path:
        return sagp_cache_root(self.cache_dir) / "objects"
