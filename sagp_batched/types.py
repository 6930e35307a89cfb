"""Typed data that flows between the pipeline's stages.

Frames are explicit in field names: ``*_world`` is the PyBullet world frame (z up, metres),
``*_object`` the target object's URDF link frame. Grasps are the exception, since one batch is
moved between frames (``GraspCandidates.transform``): their fields carry no suffix and the batch
says its frame in ``frame`` (one of ``GRASP_FRAMES``). Quaternions are xyzw (PyBullet's order)
unless a name says ``wxyz``.
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
# The frames a grasp batch can be expressed in: the planner's and execution's world, and the
# target object's link frame that datasets and the functional-region judgement use.
GRASP_FRAMES: tuple[str, ...] = ("world", "object")
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


class InvalidGraspError(ValueError):
    """A grasp handed to execution is malformed; the message names the field."""


def as_finite_vector(value: Any, length: int, name: str) -> np.ndarray:
    """``value`` (a sequence, array or tensor) as a (length,) float64 array, or ``InvalidGraspError``."""
    try:
        array = np.asarray(value.detach().cpu() if isinstance(value, torch.Tensor) else value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        array = np.full(0, np.nan)
    if array.shape != (length,) or not np.all(np.isfinite(array)):
        raise InvalidGraspError(f"{name} must be {length} finite numbers, got {value!r}")
    return array


@dataclass(frozen=True)
class Grasp:
    """One candidate of a batch (``GraspCandidates[i]``): what execution runs and a record describes.

    Tensors are the batch's rows without the batch dimension, in the batch's ``frame``;
    ``position`` is the contact midpoint where ``panda_grasptarget`` goes, ``rotation``'s columns
    are (closing x approach, closing axis, approach). Execution runs world-frame grasps only.
    """

    candidate_id: int
    contacts: torch.Tensor  # (2, 3)
    rotation: torch.Tensor  # (3, 3)
    approach: torch.Tensor  # (3,) unit, direction the gripper moves in toward the object
    width_m: float
    ik_solution: torch.Tensor | None = None  # (7,) arm joints reaching the grasp
    joint_path: torch.Tensor | None = None  # (W, 7) planned joints at every motion waypoint
    hand_clearance_m: float | None = None
    zone: str | None = None  # primary zone, None where unzoned
    zones: tuple[str, ...] = ()  # every zone it is rated by, primary first
    score: float = 0.0
    terms: dict[str, float] = field(default_factory=dict)
    frame: str = "world"  # the frame of contacts, rotation and approach (``GRASP_FRAMES``)

    @classmethod
    def from_pose(cls, position_world: Any, quat_xyzw: Any, width_m: float, approach_world: Any, ik_solution: Any = None) -> "Grasp":
        """A grasp given as a pose: centre (3,), orientation xyzw (4,), contact width and approach
        (3,), optionally the (7,) arm joints reaching it; ``InvalidGraspError`` names a malformed one."""
        from scipy.spatial.transform import Rotation

        position = as_finite_vector(position_world, 3, "position_world")
        quat = as_finite_vector(quat_xyzw, 4, "quat_xyzw")
        approach = as_finite_vector(approach_world, 3, "approach_world")
        if np.linalg.norm(quat) < 1e-9 or np.linalg.norm(approach) < 1e-9:
            raise InvalidGraspError("quat_xyzw and approach_world must be non-zero")
        rotation = Rotation.from_quat(quat).as_matrix()
        half_width = 0.5 * float(width_m) * rotation[:, 1]
        return cls(
            candidate_id=0,
            contacts=torch.tensor(np.stack([position - half_width, position + half_width])),
            rotation=torch.tensor(rotation),
            approach=torch.tensor(approach / np.linalg.norm(approach)),
            width_m=float(width_m),
            ik_solution=None if ik_solution is None else torch.tensor(as_finite_vector(ik_solution, 7, "ik_solution")),
        )

    @property
    def position(self) -> torch.Tensor:
        return self.contacts.mean(dim=0)

    @property
    def quat_xyzw(self) -> torch.Tensor:
        """(4,) orientation as an xyzw quaternion, in the batch's float precision."""
        from scipy.spatial.transform import Rotation

        quat = Rotation.from_matrix(self.rotation.double().numpy()).as_quat()
        return torch.as_tensor(quat, dtype=self.rotation.dtype)

    def record(self) -> dict[str, Any]:
        """The grasp as plain JSON-ready values (metres, in its ``frame``, which names the contacts' key)."""
        return {
            "position": self.position.tolist(),
            "quat_xyzw": self.quat_xyzw.tolist(),
            "width": self.width_m,
            "approach": self.approach.tolist(),
            f"contacts_{self.frame}": self.contacts.tolist(),
            "zone": self.zone,
            "zones": list(self.zones),
            "score": self.score,
            "terms": dict(self.terms),
        }


@dataclass
class GraspCandidates:
    """A batch of C grasp candidates as a struct of tensors (graspnetAPI's GraspGroup habit).

    Stages add fields or mask the batch; nothing becomes per-grasp Python objects until a grasp
    is executed or written (``batch[i]`` is a ``Grasp``; ``batch[a:b]`` or ``batch[mask]`` a
    batch). Positions and directions are in the batch's ``frame``: the world as planned,
    the object's link frame after ``transform(object_from_world, "object")``. Grasp frame: columns
    of ``rotation`` are (x = closing x approach, y = closing axis, z = approach direction);
    ``position`` is the grasp centre (contact midpoint), which is where the Panda's
    ``panda_grasptarget`` frame is sent. A ranked batch is best first:
    execution runs its first ``max_attempts``.
    """

    contacts: torch.Tensor  # (C, 2, 3)
    closing_axis: torch.Tensor  # (C, 3) unit, from contact 0 to contact 1
    width_m: torch.Tensor  # (C,)
    s_geom: torch.Tensor  # (C,)
    approach: torch.Tensor  # (C, 3) unit, direction the gripper moves in to grasp
    rotation: torch.Tensor  # (C, 3, 3)
    s_reach: torch.Tensor  # (C,) in [0, 1]
    ik_solution: torch.Tensor  # (C, 7) Panda arm joints reaching the grasp pose
    zone: torch.Tensor  # (C,) int64 primary zone index into ``zone_names``, -1 before zoning
    s_afford: torch.Tensor  # (C,)
    s_avoid: torch.Tensor  # (C,)
    s_task: torch.Tensor  # (C,)
    score: torch.Tensor  # (C,) fused score the batch is ranked by
    zone_names: tuple[str, ...] = ()
    # (C,) int64 position of each candidate in the planner's output: it follows the candidates
    # through re-ranking, so every method's choices name the same candidate by the same id.
    candidate_id: torch.Tensor | None = None
    # (C, W, 7) planned arm joints at every waypoint of ``motion.motion_waypoints`` (pre-grasp,
    # descent, grasp, lift): execution tracks exactly these. None for grasps planned without a motion.
    joint_path: torch.Tensor | None = None
    # (C,) smallest separation (m) of the hand's hulls swept along the descent from the cloud's points.
    hand_clearance_m: torch.Tensor | None = None
    # (C, Z) bool: the zones each candidate is rated by (its primary zone and its two side
    # zones), set once by zoning; scoring and records read them. None before zoning.
    rated_zones: torch.Tensor | None = None
    frame: str = "world"  # the frame of contacts, closing_axis, approach and rotation (``GRASP_FRAMES``)

    def __post_init__(self) -> None:
        if self.frame not in GRASP_FRAMES:
            raise ValueError(f"frame must be one of {GRASP_FRAMES}, got {self.frame!r}")
        if self.candidate_id is None:
            self.candidate_id = torch.arange(self.width_m.shape[0])

    @property
    def position(self) -> torch.Tensor:
        return self.contacts.mean(dim=1)

    def __len__(self) -> int:
        return int(self.width_m.shape[0])

    def __getitem__(self, index: int | slice | torch.Tensor) -> "Grasp | GraspCandidates":
        """``Grasp`` number ``index``, or the batch picked by a slice, mask or index tensor."""
        if isinstance(index, (int, np.integer)):
            return self._grasp(int(index))
        return self.select(index)

    def primary_zone_names(self) -> list[str]:
        """Each candidate's primary zone name, "" before zoning (zone -1)."""
        return [self.zone_names[z] if 0 <= z < len(self.zone_names) else "" for z in self.zone.tolist()]

    def _grasp(self, i: int) -> Grasp:
        if not -len(self) <= i < len(self):
            raise IndexError(f"grasp {i} outside the {len(self)} candidates")
        zone = int(self.zone[i])
        primary = self.zone_names[zone] if 0 <= zone < len(self.zone_names) else None
        rated = self.rated_zones[i].tolist() if self.rated_zones is not None else []
        others = tuple(name for index, (name, member) in enumerate(zip(self.zone_names, rated)) if member and index != zone)
        return Grasp(
            candidate_id=int(self.candidate_id[i]),
            contacts=self.contacts[i],
            rotation=self.rotation[i],
            approach=self.approach[i],
            width_m=float(self.width_m[i]),
            ik_solution=self.ik_solution[i],
            joint_path=self.joint_path[i] if self.joint_path is not None else None,
            hand_clearance_m=float(self.hand_clearance_m[i]) if self.hand_clearance_m is not None else None,
            zone=primary,
            zones=((primary,) if primary is not None else ()) + others,
            score=float(self.score[i]),
            frame=self.frame,
            terms={
                "geom": float(self.s_geom[i]),
                "reach": float(self.s_reach[i]),
                "afford": float(self.s_afford[i]),
                "avoid": float(self.s_avoid[i]),
                "task": float(self.s_task[i]),
            },
        )

    def _tensor_fields(self) -> list[str]:
        return [f.name for f in dataclasses.fields(self) if isinstance(getattr(self, f.name), torch.Tensor)]

    def select(self, index: torch.Tensor | slice) -> "GraspCandidates":
        """The candidates picked by a boolean mask, an index tensor or a slice, in that order."""
        return dataclasses.replace(self, **{name: getattr(self, name)[index] for name in self._tensor_fields()})

    def with_fields(self, **tensors: torch.Tensor) -> "GraspCandidates":
        return dataclasses.replace(self, **tensors)

    def ranked_by(self, key: torch.Tensor) -> "GraspCandidates":
        """Sorted by ``key`` descending; ties keep their current order (stable)."""
        order = torch.sort(key, descending=True, stable=True).indices
        return self.select(order)

    def transform(self, transform: torch.Tensor | np.ndarray, frame: str) -> "GraspCandidates":
        """The batch moved by a (4, 4) rigid transform into ``frame``, in float64:
        ``transform(object_from_world, "object")`` expresses a world-frame batch in the object frame."""
        matrix = torch.tensor(np.asarray(transform), dtype=torch.float64)  # a copy: a read-only array (from Ray) stays untouched
        if matrix.shape != (4, 4) or not torch.allclose(matrix[:3, :3] @ matrix[:3, :3].T, torch.eye(3, dtype=torch.float64), atol=1e-6):
            raise ValueError(f"transform must be a (4, 4) rigid transform, got shape {tuple(matrix.shape)}")
        rotation, translation = matrix[:3, :3], matrix[:3, 3]
        return self.with_fields(
            contacts=self.contacts.double() @ rotation.T + translation,
            closing_axis=self.closing_axis.double() @ rotation.T,
            approach=self.approach.double() @ rotation.T,
            rotation=rotation @ self.rotation.double(),
            frame=frame,
        )


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
