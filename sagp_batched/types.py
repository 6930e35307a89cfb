"""Typed data that flows between the pipeline's stages.

Frames are explicit in field names: ``*_world`` is the PyBullet world frame (z up, metres),
``*_object`` the target object's URDF link frame; grasps, which move between frames, say theirs
(``sagp_batched.grasps``). Quaternions are xyzw (PyBullet's order) unless a name says ``wxyz``.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from .attempt import AttemptDiagnostics


# The coarse-zone vocabulary. A standing object is split into vertical thirds (top, middle,
# bottom); an elongated object lying on the table into thirds along its length (wide_end, middle,
# narrow_end), since its vertical thirds would be layers of its thickness. Each protrusion cluster
# of a cloud is a zone of its own, ``protrusion_1``, ``protrusion_2``, ... (largest first); the
# general name ``protrusion`` is what a rating uses to speak of all of them at once.
PROTRUSION = "protrusion"
VERTICAL_ZONES: tuple[str, ...] = ("top", "middle", "bottom")
LENGTH_ZONES: tuple[str, ...] = ("wide_end", "middle", "narrow_end")
# Halves of the object seen from the robot: each crosses every third.
SIDE_ZONES: tuple[str, ...] = ("left", "right", "front", "back")
ZONE_NAMES: tuple[str, ...] = ("top", "middle", "bottom", "wide_end", "narrow_end", *SIDE_ZONES, PROTRUSION)
_NUMBERED_PROTRUSION = re.compile(r"protrusion_[1-9][0-9]*")


def protrusion_zone(number: int) -> str:
    """Name of the ``number``-th protrusion zone (1-based, largest cluster first)."""
    return f"{PROTRUSION}_{number}"


def is_zone_name(name: str) -> bool:
    """Whether ``name`` is in the zone vocabulary: a ``ZONE_NAMES`` entry or ``protrusion_<n>``."""
    return name in ZONE_NAMES or bool(_NUMBERED_PROTRUSION.fullmatch(name))


def general_zone(name: str) -> str | None:
    """The zone a rating of ``name`` falls back to: ``protrusion`` for ``protrusion_<n>``, else None."""
    return PROTRUSION if _NUMBERED_PROTRUSION.fullmatch(name) else None


# The study's tasks, described as a rating model is told them.
TASKS: dict[str, str] = {
    "t1": "stable pickup: lift the object 20 cm and hold it without dropping it",
    "t2": "functional grasp: hold the object where a person holds it to use it, keeping it within 15 degrees of its resting orientation",
    "t3": "cluttered grasp: pick the object up while 3-4 other objects stand within 15 cm of it, without moving them",
}
# The compared methods: Geometry-Only, SAGP's fused score, VLM-Direct.
METHODS: tuple[str, ...] = ("go", "sagp", "vd")


class PerceptionFailure(RuntimeError):
    """The target could not be perceived well enough to plan on.

    ``reason`` is one of ``"not_visible"`` (no camera sees the target) or ``"too_few_points"``.
    """

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


@dataclass
class CameraData:
    name: str
    width_px: int
    height_px: int
    intrinsics: np.ndarray  # (3, 3) pinhole K in pixels
    camera_to_world: np.ndarray  # (4, 4) pose of the camera (x right, y down, z forward) in world
    view_matrix: np.ndarray  # (16,) PyBullet/OpenGL column-major view matrix
    projection_matrix: np.ndarray  # (16,) PyBullet/OpenGL column-major projection matrix
    near_m: float
    far_m: float


@dataclass
class PerceivedCloud:
    """The target object as the cameras see it: what the planner consumes."""

    points_world: torch.Tensor  # (N, 3) float32, metres
    normals_world: torch.Tensor  # (N, 3) float32, unit, pointing away from the cloud centroid
    view_index: torch.Tensor  # (N,) int64, index into ``cameras`` of the view each point came from
    crop_rgb: np.ndarray  # (H, W, 3) uint8, tight crop of the object with padding, for the rating model
    cameras: list[CameraData]
    object_id: str
    # Ground-truth pose of the object's URDF link frame at capture time; used only to express
    # results in the object frame (``midpoint_object``), never by the planner.
    object_position_world: np.ndarray  # (3,)
    object_quat_xyzw: np.ndarray  # (4,)
    # Points of other bodies on the table (t3 distractors): the gripper-volume check counts them.
    obstacle_points_world: torch.Tensor = field(default_factory=lambda: torch.zeros(0, 3))
    # Pixel box (u0, v0, u1, v1) of ``crop_rgb`` in ``cameras[crop_camera_index]``: VLM-Direct projects
    # candidates into the crop through it; None when unknown.
    crop_box_px: tuple[int, int, int, int] | None = None
    crop_camera_index: int = 0

    @property
    def n_points(self) -> int:
        return int(self.points_world.shape[0])

    def on(self, device: torch.device) -> PerceivedCloud:
        """This cloud with its point tensors on ``device`` (itself where they are there already)."""
        tensors = ("points_world", "normals_world", "view_index", "obstacle_points_world")
        if all(getattr(self, name).device == device for name in tensors):
            return self
        return dataclasses.replace(self, **{name: getattr(self, name).to(device) for name in tensors})

    @property
    def object_from_world(self) -> np.ndarray:
        """(4, 4) the world-to-object transform of the ground-truth pose (``object_position_world``,
        ``object_quat_xyzw``): for expressing results, never for planning."""
        from scipy.spatial.transform import Rotation

        rotation = Rotation.from_quat(self.object_quat_xyzw).as_matrix()
        transform = np.eye(4)
        transform[:3, :3] = rotation.T
        transform[:3, 3] = -rotation.T @ np.asarray(self.object_position_world, dtype=float)
        return transform

    def in_object_frame(self, points_world: np.ndarray) -> np.ndarray:
        """(..., 3) world points in the object's own (URDF link) frame (``object_from_world``)."""
        transform = self.object_from_world
        return np.asarray(points_world) @ transform[:3, :3].T + transform[:3, 3]


@dataclass
class GraspAttempt:
    """Outcome of executing one grasp in PyBullet."""

    success: bool
    failure_reason: str | None  # None on success; "unreachable" | "collision" | "slipped" | "not_lifted"
    orientation_change_deg: float  # the object's rotation from its resting orientation when the attempt ended
    diagnostics: AttemptDiagnostics = field(default_factory=AttemptDiagnostics)
    # RGB (H, W, 3) uint8 images by moment ("contact", "lifted", "failed_<phase>"), only when asked for;
    # images are saved as files, never written into a record.
    frames: dict[str, np.ndarray] = field(default_factory=dict)

    def record(self, candidate_id: int) -> dict[str, Any]:
        """This attempt's entry in a ``trials.jsonl`` attempt log (``attempt.ATTEMPT_RECORD_FIELDS``)."""
        return {"candidate": candidate_id, "success": self.success, "failure_reason": self.failure_reason, **self.diagnostics.record()}
