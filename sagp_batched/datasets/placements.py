"""Where a labelling protocol puts the object: resting on the study's table (``ObjectPlacement``, its
centre-of-mass frame where it settled) or floating alone (``FloatingPlacement``, its link frame)."""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import ClassVar, Sequence

import numpy as np

from ..description_files import read_urdf_document
from ..execution.poses import pose_matrix
from ..world.objects import ObjectSpec

Pose = tuple[Sequence[float], Sequence[float]]  # position (3,), xyzw quaternion (4,)


@dataclass(frozen=True)
class ObjectPlacement:
    """An object resting on the study's table: its spec and the world pose of its centre-of-mass
    frame (what ``getBasePositionAndOrientation`` reports)."""

    spec: ObjectSpec
    com_position_world: tuple[float, float, float]
    com_quat_xyzw: tuple[float, float, float, float]

    @classmethod
    def from_scene(cls, scene) -> "ObjectPlacement":
        """The target of a reset ``Scene`` where it settled (the scene is restored to its saved state first)."""
        if scene.target_spec is None:
            raise ValueError("ObjectPlacement.from_scene needs a Scene after reset")
        scene.restore_state()
        position, quat = scene.centre_of_mass(scene.target_id)
        return cls(scene.target_spec, tuple(float(v) for v in position), tuple(float(v) for v in quat))

    frame: ClassVar[str] = "com"  # the object's frame ``pose`` places

    @property
    def pose(self) -> Pose:
        return self.com_position_world, self.com_quat_xyzw

    def link_pose_world(self) -> np.ndarray:
        """(4, 4) the object's link frame in the world."""
        return pose_matrix(*self.pose) @ np.linalg.inv(com_in_link(self.spec))


@dataclass(frozen=True)
class FloatingPlacement:
    """An object floating alone (the ``floating`` protocol): the world pose of its link frame.
    Gravity pulls along the world's -z, so the pose says which way is down for the object."""

    spec: ObjectSpec
    link_position_world: tuple[float, float, float] = (0.0, 0.0, 0.0)
    link_quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    frame: ClassVar[str] = "link"  # the object's frame ``pose`` places

    @property
    def pose(self) -> Pose:
        return self.link_position_world, self.link_quat_xyzw

    def link_pose_world(self) -> np.ndarray:
        """(4, 4) the object's link frame in the world."""
        return pose_matrix(*self.pose)


Placement = ObjectPlacement | FloatingPlacement


@functools.lru_cache(maxsize=64)
def com_in_link(spec: ObjectSpec) -> np.ndarray:
    """(4, 4) the centre-of-mass (inertial) frame in the link frame, from the URDF's ``<inertial><origin>``."""
    links = read_urdf_document(spec.urdf_path).links
    inertial = links[0].inertial if links else None
    return inertial.frame_in_link if inertial is not None else np.eye(4)
