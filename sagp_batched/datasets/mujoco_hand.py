"""The MuJoCo engine of hand-mode labels: the same methods as ``pybullet_hand.PyBulletHand``
(``protocols.HandEngine``), so the protocols run on it unchanged, and no PyBullet.

Its world (``mujoco_world``) is compiled once per object and table and every simulation starts from
``mj_resetData``: MuJoCo steps a world deterministically from its state, and the reset clears all of it
(the solver's warm start included), so a label depends on its own grasp alone. Each protocol step of
``scene.time_step_s`` is ``labelling.mujoco.substeps`` MuJoCo steps (times ``step_division`` where a
diverged simulation is run again), the hand's mocap target held still over them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from ..config import Config
from ..execution.poses import pose_matrix
from ..robot.description import robot_of
from ..world.objects import ObjectLoadError, ObjectSpec
from .collision_urdf import labelling_hand_urdf
from .mujoco_world import HandWorld, builds_from_mjcf, compile_world
from .protocols import Pose, WorldStart, speed_past_bound

# MuJoCo writes quaternions w first, the protocols x first.
XYZW_FROM_WXYZ = [1, 2, 3, 0]
WXYZ_FROM_XYZW = [3, 0, 1, 2]
# The warnings of a step gone wrong: MuJoCo resets the state after a bad acceleration and carries on (and
# regularises a singular inertia, drops contacts past its buffers), so only these counters (which survive
# that reset, not ``mj_resetData``) say the outcome is the solver's.
DIVERGENCE_WARNINGS = {mujoco.mjtWarning.mjWARN_BADQACC: "QACC", mujoco.mjtWarning.mjWARN_BADQVEL: "QVEL",
                       mujoco.mjtWarning.mjWARN_BADQPOS: "QPOS", mujoco.mjtWarning.mjWARN_BADCTRL: "control",
                       mujoco.mjtWarning.mjWARN_INERTIA: "singular inertia", mujoco.mjtWarning.mjWARN_CONTACTFULL: "contact buffer full",
                       mujoco.mjtWarning.mjWARN_CNSTRFULL: "constraint buffer full"}


class MuJoCoHand:
    """A ``protocols.HandEngine``: one compiled MuJoCo world per object and table, in which one floating
    hand at a time labels one grasp."""

    name = "mujoco"

    def __init__(self, config: Config):
        self.config = config
        self.robot = robot_of(config)
        self.hand_urdf = None if builds_from_mjcf(self.robot) else labelling_hand_urdf(config)
        self.substeps = config.labelling.mujoco.substeps
        self.step_division = 1
        self._worlds: dict[tuple[str, bool], tuple[HandWorld, mujoco.MjData]] = {}

    def close(self) -> None:
        self._worlds.clear()

    def __enter__(self) -> "MuJoCoHand":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- building ------------------------------------------------------------------------------------
    def _world(self, spec: ObjectSpec, table: bool) -> tuple[HandWorld, mujoco.MjData]:
        key = (str(spec.urdf_path), table)
        if key not in self._worlds:
            try:
                world = compile_world(self.hand_urdf, self.robot, Path(spec.urdf_path), table, self.config)
            except (ValueError, OSError) as exc:
                raise ObjectLoadError(f"object '{spec.id}': MuJoCo cannot build {spec.urdf_path}: {exc}") from exc
            self._worlds[key] = (world, mujoco.MjData(world.model))
        return self._worlds[key]

    def build(self, start: WorldStart) -> None:
        """The object's world reset to ``start``."""
        self.world, self.data = world, data = self._world(start.spec, start.table)
        model = world.model
        self.substeps = self.config.labelling.mujoco.substeps * self.step_division
        model.opt.timestep = self.config.scene.time_step_s / self.substeps
        mujoco.mj_resetData(model, data)
        self.set_gravity(start.gravity)
        link = pose_matrix(*start.object_pose)
        if start.object_frame == "com":
            link = link @ np.linalg.inv(pose_matrix(world.com_in_link[0], world.com_in_link[1][XYZW_FROM_WXYZ]))
        self._set_free_joint(world.object_qpos, link)
        self._set_free_joint(world.hand_qpos, pose_matrix(start.hand_position, start.hand_quat) @ world.hand_in_target)
        # The fingers open, and the set points of servos that have them (the URDF hand's) with them.
        data.qpos[list(world.finger_qpos)] = world.finger_open_qpos
        data.act[:] = world.finger_ctrl(self.robot.gripper.finger_joint_value(self.robot.gripper.open_width_m))
        self.command_fingers(self.robot.gripper.open_width_m)
        self.quat = np.asarray(start.hand_quat, dtype=float)
        self.move(start.hand_position)
        data.mocap_pos[0], data.mocap_quat[0] = self.target_position, self.target_quat
        mujoco.mj_forward(model, data)

    def _set_free_joint(self, address: int, pose: np.ndarray) -> None:
        self.data.qpos[address : address + 3] = pose[:3, 3]
        self.data.qpos[address + 3 : address + 7] = Rotation.from_matrix(pose[:3, :3]).as_quat()[WXYZ_FROM_XYZW]

    # -- motion --------------------------------------------------------------------------------------
    def set_gravity(self, on: bool) -> None:
        self.world.model.opt.gravity[:] = (0.0, 0.0, self.config.scene.gravity_m_s2 if on else 0.0)

    def command_fingers(self, width_m: float) -> None:
        self.data.ctrl[:] = self.world.finger_ctrl(self.robot.gripper.finger_joint_value(width_m))

    def step(self, steps: int) -> None:
        """``steps`` protocol steps, the first carrying the hand's target to where ``move`` last sent it."""
        if steps <= 0:
            return
        world, data, first = self.world, self.data, 0
        # A target that moved glides there in the first step; a still one (the close, the hold) needs no substep of Python.
        if not (np.array_equal(data.mocap_pos[0], self.target_position) and np.array_equal(data.mocap_quat[0], self.target_quat)):
            self._glide(self.target_position[None], self.target_quat[None])
            first = 1
        if world.grip_force_caps is None:
            mujoco.mj_step(world.model, data, nstep=(steps - first) * self.substeps)
            return
        # A linkage's grip force is set again each step for where its fingers stand (1.6 us a step).
        for _ in range(steps - first):
            world.cap_grip_force(data)
            mujoco.mj_step(world.model, data, nstep=self.substeps)

    def move(self, position: Sequence[float], quat: Sequence[float] | None = None) -> None:
        """Send the hand's grasp target toward a pose; the weld pulls it there over the next steps."""
        self.target_position = np.asarray(position, dtype=float)
        self.target_quat = np.asarray(self.quat if quat is None else quat, dtype=float)[WXYZ_FROM_XYZW]

    def follow(self, positions: np.ndarray, quats: np.ndarray | None = None) -> np.ndarray:
        """``move`` to each of ``positions`` (T, 3), with ``quats`` (T, 4) or the hand's orientation, then
        ``step(1)``; (T, 7) the grasp target's pose (position, xyzw quaternion) after each step."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        targets = np.asarray(self.quat if quats is None else quats, dtype=float).reshape(-1, 4)[:, WXYZ_FROM_XYZW]
        targets = np.broadcast_to(targets, (len(positions), 4))
        poses = self._glide(positions, targets)
        self.target_position, self.target_quat = positions[-1], targets[-1]
        poses[:, 3:] = poses[:, 3:][:, XYZW_FROM_WXYZ]
        return poses

    def _glide(self, positions: np.ndarray, quats: np.ndarray) -> np.ndarray:
        """A protocol step to each of ``positions`` (T, 3) and ``quats`` (T, 4, wxyz), the weld's target moved on
        a straight line through the step's substeps; (T, 7) the grasp target's pose (wxyz) after each step.

        A target that jumps once a step has the weld pull the hand there within the step and stop it: a
        saw-tooth at the protocol's rate whose peaks (57 m/s^2 in a 0.5 m/s lift) passed the pads' friction, so
        a held object crept down the fingers (1.4 mm where an ideal grip keeps it still, twice an ideal grip's
        slide past the sliding threshold). The path is laid out before the loop, which only copies rows (a hand
        in free space: 5.9 us a substep, 9.9 with the path computed in the loop)."""
        model, data, substeps, body = self.world.model, self.data, self.substeps, self.world.grasp_target_body
        previous_positions = np.vstack([data.mocap_pos[:1], positions[:-1]])
        previous_quats = np.vstack([data.mocap_quat[:1], quats[:-1]])
        # The same rotation, on the near side of the quaternion sphere.
        previous_quats *= np.where(np.sum(previous_quats * quats, axis=1) < 0.0, -1.0, 1.0)[:, None]
        fractions = (np.arange(1, substeps + 1) / substeps)[None, :, None]
        path_positions = previous_positions[:, None] + (positions - previous_positions)[:, None] * fractions
        path_quats = previous_quats[:, None] + (quats - previous_quats)[:, None] * fractions
        path_quats /= np.linalg.norm(path_quats, axis=-1, keepdims=True)
        # Each step ends on its target to the last digit, where the next begins.
        path_positions[:, -1], path_quats[:, -1] = positions, quats
        poses = np.empty((len(positions), 7))
        caps_grip_force = self.world.grip_force_caps is not None
        for index in range(len(positions)):
            if caps_grip_force:
                self.world.cap_grip_force(data)
            for position, quat in zip(path_positions[index], path_quats[index]):
                data.mocap_pos[0], data.mocap_quat[0] = position, quat
                mujoco.mj_step(model, data)
            poses[index, :3], poses[index, 3:] = data.xpos[body], data.xquat[body]
        return poses

    # -- state ---------------------------------------------------------------------------------------
    def object_pose(self) -> Pose:
        """World pose of the object's centre-of-mass frame."""
        body, (com_position, com_quat) = self.world.object_body, self.world.com_in_link
        position, quat = np.empty(3), np.empty(4)
        mujoco.mju_rotVecQuat(position, com_position, self.data.xquat[body])
        mujoco.mju_mulQuat(quat, self.data.xquat[body], com_quat)
        return tuple(self.data.xpos[body] + position), tuple(quat[XYZW_FROM_WXYZ])

    def diverged(self) -> str | None:
        """Why the simulation since ``build`` has diverged (a warning, a non-finite state, the object
        faster than ``protocols.speed_past_bound`` allows relative to the hand), or None."""
        for warning, name in DIVERGENCE_WARNINGS.items():
            if self.data.warning[warning].number:
                return f"diverged: {name} warning"
        if not (np.isfinite(self.data.qpos).all() and np.isfinite(self.data.qvel).all()):
            return "diverged: non-finite state"
        velocities = np.empty((2, 6))
        for row, body in enumerate((self.world.object_body, self.world.grasp_target_body)):
            mujoco.mj_objectVelocity(self.world.model, self.data, mujoco.mjtObj.mjOBJ_BODY, body, velocities[row], 0)
        return speed_past_bound(float(np.linalg.norm(velocities[0, 3:] - velocities[1, 3:])), self.data.time, self.config)

    def hand_pose(self) -> Pose:
        """World pose of the hand's grasp target."""
        body = self.world.grasp_target_body
        return self.data.xpos[body].copy(), self.data.xquat[body][XYZW_FROM_WXYZ]

    def _contact_bodies(self) -> np.ndarray:
        """(n, 2) the bodies of the last step's contacts."""
        return self.world.model.geom_bodyid[self.data.contact.geom[: self.data.ncon]]

    def _hand_contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """Per contact of the last step, whether it is between the hand and the object, and between the
        hand and the table (never, without a table: no geom has its id -1)."""
        bodies, geoms = self._contact_bodies(), self.data.contact.geom[: self.data.ncon]
        hand = self.world.hand_body_mask[bodies].any(axis=1)
        return hand & (bodies == self.world.object_body).any(axis=1), hand & (geoms == self.world.table_geom).any(axis=1)

    def hand_in_contact(self) -> tuple[bool, bool]:
        """Whether the hand touches the object, and the table, before anything has moved."""
        with_object, with_table = self._hand_contacts()
        return bool(with_object.any()), bool(with_table.any())

    def hand_touching(self) -> bool:
        """Whether any part of the hand touched the object in the last step."""
        return bool(self._hand_contacts()[0].any())

    def table_push_n(self) -> float:
        """The normal force the hand pushes the table with (0 without a table)."""
        force, total = np.zeros(6), 0.0
        for index in np.flatnonzero(self._hand_contacts()[1]):
            mujoco.mj_contactForce(self.world.model, self.data, int(index), force)
            total += force[0]
        return total

    def fingers_touching(self) -> bool:
        """Whether every finger touches the object (the last step's contacts, the hulls' margin included, as PyBullet's)."""
        bodies = self._contact_bodies()
        on_object = bodies[(bodies == self.world.object_body).any(axis=1)].ravel()
        return all(finger in on_object for finger in self.world.finger_bodies)
