"""Grasps as the pipeline hands them on: one ``Grasp``, a batch of them (``GraspCandidates``, a struct
of tensors) and their poses at the package's boundaries (``GraspPoses``).

Their positions and directions carry no frame suffix, since one batch is moved between frames
(``GraspCandidates.transform``): each says its frame in ``frame``, one of ``GRASP_FRAMES``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import torch

# The frames a grasp batch can be expressed in: the planner's and execution's world, and the
# target object's link frame that datasets and the functional-region judgement use.
GRASP_FRAMES: tuple[str, ...] = ("world", "object")


class InvalidGraspError(ValueError):
    """A grasp handed to execution is malformed; the message names the field."""


def _check_frame(frame: str) -> None:
    if frame not in GRASP_FRAMES:
        raise ValueError(f"frame must be one of {GRASP_FRAMES}, got {frame!r}")


def _rigid_matrix(transform: torch.Tensor | np.ndarray) -> torch.Tensor:
    """A (4, 4) rigid transform as a float64 tensor, or ``ValueError``."""
    matrix = torch.tensor(np.asarray(transform), dtype=torch.float64)  # a copy: a read-only array (from Ray) stays untouched
    if matrix.shape != (4, 4) or not torch.allclose(matrix[:3, :3] @ matrix[:3, :3].T, torch.eye(3, dtype=torch.float64), atol=1e-6):
        raise ValueError(f"transform must be a (4, 4) rigid transform, got shape {tuple(matrix.shape)}")
    return matrix


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
class GraspPoses:
    """N grasp poses in one frame, the one form poses take where they cross the package's boundary
    (a user's grasps in, a dataset's grasps out; ``GraspCandidates.poses``), as pytorch-kinematics'
    ``Transform3d`` is its one pose type. ``position`` is where ``panda_grasptarget`` goes (the
    contact midpoint); ``rotation``'s columns are (closing x approach, closing axis, approach)."""

    position: torch.Tensor  # (N, 3) float64
    rotation: torch.Tensor  # (N, 3, 3) float64, proper rotations
    frame: str = "world"  # one of ``GRASP_FRAMES``

    def __post_init__(self) -> None:
        _check_frame(self.frame)
        n = self.position.shape[0] if self.position.dim() == 2 else -1
        if self.position.shape != (n, 3) or self.rotation.shape != (n, 3, 3):
            raise InvalidGraspError(f"grasp poses need (N, 3) positions and (N, 3, 3) rotations, got {tuple(self.position.shape)} and {tuple(self.rotation.shape)}")

    @classmethod
    def from_quat_xyzw(cls, position: Any, quat_xyzw: Any, frame: str = "world") -> "GraspPoses":
        """Poses from (N, 3) positions and (N, 4) xyzw quaternions (normalised here); a malformed
        row raises ``InvalidGraspError`` naming the field."""
        from scipy.spatial.transform import Rotation

        positions, quats = np.atleast_2d(np.asarray(position, dtype=float)), np.atleast_2d(np.asarray(quat_xyzw, dtype=float))
        if positions.ndim != 2 or positions.shape[1] != 3 or quats.ndim != 2 or quats.shape[1] != 4:
            raise InvalidGraspError(f"grasp poses need (N, 3) positions and (N, 4) quaternions, got {positions.shape} and {quats.shape}")
        if len(positions) != len(quats):
            raise InvalidGraspError(f"{len(positions)} positions and {len(quats)} orientations: give one of each per grasp")
        if not np.all(np.isfinite(positions)):
            raise InvalidGraspError("position must be finite numbers")
        for quat in quats:
            if not np.all(np.isfinite(quat)) or np.linalg.norm(quat) < 1e-9:
                raise InvalidGraspError(f"quat_xyzw must be 4 finite numbers, not all zero, got {quat.tolist()}")
        rotation = Rotation.from_quat(quats).as_matrix().reshape(-1, 3, 3)
        return cls(torch.tensor(positions), torch.tensor(rotation), frame)

    @classmethod
    def from_matrices(cls, matrices: Any, frame: str) -> "GraspPoses":
        """Poses from (N, 4, 4) homogeneous transforms of the grasp frame."""
        matrices = torch.as_tensor(np.asarray(matrices), dtype=torch.float64)
        if matrices.dim() != 3 or matrices.shape[1:] != (4, 4):
            raise InvalidGraspError(f"grasp poses need (N, 4, 4) transforms, got {tuple(matrices.shape)}")
        return cls(matrices[:, :3, 3].clone(), matrices[:, :3, :3].clone(), frame)

    @classmethod
    def cat(cls, poses: Sequence["GraspPoses"], frame: str) -> "GraspPoses":
        """The poses of several batches, all in ``frame``, as one batch (empty for none)."""
        if any(p.frame != frame for p in poses):
            raise ValueError(f"poses in the frames {sorted({p.frame for p in poses})} cannot be joined as {frame} poses")
        position = torch.cat([p.position for p in poses] + [torch.zeros(0, 3, dtype=torch.float64)])
        return cls(position, torch.cat([p.rotation for p in poses] + [torch.zeros(0, 3, 3, dtype=torch.float64)]), frame)

    def __len__(self) -> int:
        return int(self.position.shape[0])

    @property
    def approach(self) -> torch.Tensor:
        """(N, 3) unit directions the gripper moves in toward the object: the frames' z axes."""
        return self.rotation[:, :, 2]

    def matrices(self) -> np.ndarray:
        """(N, 4, 4) float64 homogeneous transforms of the grasp frames."""
        transforms = np.tile(np.eye(4), (len(self), 1, 1))
        transforms[:, :3, :3] = self.rotation.numpy()
        transforms[:, :3, 3] = self.position.numpy()
        return transforms

    def transform(self, transform: torch.Tensor | np.ndarray, frame: str) -> "GraspPoses":
        """The poses moved by a (4, 4) rigid transform into ``frame``, as ``GraspCandidates.transform``
        moves a batch: ``transform(world_from_object, "world")`` expresses object-frame poses in the world."""
        matrix = _rigid_matrix(transform)
        rotation, translation = matrix[:3, :3], matrix[:3, 3]
        return GraspPoses(self.position.double() @ rotation.T + translation, rotation @ self.rotation.double(), frame)

    def quat_xyzw(self) -> torch.Tensor:
        """(N, 4) float64 xyzw quaternions of the grasp frames."""
        from scipy.spatial.transform import Rotation

        return torch.tensor(Rotation.from_matrix(self.rotation.numpy()).as_quat().reshape(-1, 4))


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
        ik_joints = None if ik_solution is None else as_finite_vector(ik_solution, 7, "ik_solution")
        return cls.from_frame(position, Rotation.from_quat(quat).as_matrix(), width_m, approach / np.linalg.norm(approach), ik_joints)

    @classmethod
    def from_frame(cls, position: np.ndarray, rotation: np.ndarray, width_m: float, approach: np.ndarray,
                   ik_solution: np.ndarray | None = None) -> "Grasp":
        """A world-frame grasp from checked values: centre (3,), grasp frame (3, 3), contact width,
        unit approach (3,) and optionally the (7,) arm joints reaching it."""
        half_width = 0.5 * float(width_m) * rotation[:, 1]
        return cls(
            candidate_id=0,
            contacts=torch.tensor(np.stack([position - half_width, position + half_width])),
            rotation=torch.tensor(rotation),
            approach=torch.tensor(approach),
            width_m=float(width_m),
            ik_solution=None if ik_solution is None else torch.tensor(ik_solution),
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
        _check_frame(self.frame)
        if self.candidate_id is None:
            self.candidate_id = torch.arange(self.width_m.shape[0], device=self.width_m.device)

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

    def to(self, device: torch.device) -> "GraspCandidates":
        """These candidates with every tensor on ``device``."""
        return dataclasses.replace(self, **{name: getattr(self, name).to(device) for name in self._tensor_fields()})

    def with_fields(self, **tensors: torch.Tensor) -> "GraspCandidates":
        return dataclasses.replace(self, **tensors)

    def appended(self, more: "GraspCandidates") -> "GraspCandidates":
        """This batch followed by ``more`` (same frame and zones; its tensors cast to this batch's dtypes)."""
        if more.frame != self.frame or more.zone_names != self.zone_names:
            raise ValueError(f"appending {more.frame}-frame candidates zoned {more.zone_names} to {self.frame}-frame ones zoned {self.zone_names}")
        fields = [name for name in self._tensor_fields() if isinstance(getattr(more, name), torch.Tensor)]
        return dataclasses.replace(self, **{name: torch.cat([getattr(self, name), getattr(more, name).to(getattr(self, name).dtype)])
                                            for name in fields})

    def ranked_by(self, key: torch.Tensor) -> "GraspCandidates":
        """Sorted by ``key`` descending; ties keep their current order (stable)."""
        order = torch.sort(key, descending=True, stable=True).indices
        return self.select(order)

    def poses(self) -> GraspPoses:
        """The candidates' grasp poses, in float64, in the batch's frame."""
        return GraspPoses(self.position.double(), self.rotation.double(), self.frame)

    def transform(self, transform: torch.Tensor | np.ndarray, frame: str) -> "GraspCandidates":
        """The batch moved by a (4, 4) rigid transform into ``frame``, in float64:
        ``transform(object_from_world, "object")`` expresses a world-frame batch in the object frame."""
        matrix = _rigid_matrix(transform)
        rotation, translation = matrix[:3, :3], matrix[:3, 3]
        return self.with_fields(
            contacts=self.contacts.double() @ rotation.T + translation,
            closing_axis=self.closing_axis.double() @ rotation.T,
            approach=self.approach.double() @ rotation.T,
            rotation=rotation @ self.rotation.double(),
            frame=frame,
        )
