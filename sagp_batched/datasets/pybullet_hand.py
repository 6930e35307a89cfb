"""The PyBullet engine of hand-mode labels: one floating hand (the configured gripper) and one object, in
a world built from nothing for every simulation.

The engine knows how to simulate, not what to test: a protocol (``protocols.LabelProtocol``) says
what to build (``protocols.WorldStart``), moves the hand and judges the outcome through the methods
here, so a second engine implements the same methods and the protocols stay as they are.

The hand is the gripper's subtree of its URDF (collision meshes only), carried by a fixed constraint on
its grasp target. A "slide" gripper (the Panda) drives its prismatic fingers with the grip force, the
mimic finger geared to its leader as the hand's one motor couples them; a "linkage" gripper (the
Robotiq) has its mimic joints geared to the driven joint and the driven joint's torque set every step
from the linkage's leverage, so each pad presses with the grip force wherever the fingers stop; its world
steps in the gripper's ``pybullet_substeps`` with its ``pybullet_solver_iterations``, without which the
gears give under the grip and the pads tilt onto the finger links behind them.

Substeps are stepped here, one ``stepSimulation`` each, not by PyBullet's ``numSubSteps``: the hand's
carrying constraint would then meet a target that jumps once a protocol step and pull the hand there within
its first substeps, a saw-tooth at the protocol's rate whose peaks passed the pads' friction (a cylinder
pinched by the 2F-85 at 0.4 of its sliding limit crept 21 mm down the pads in the lift and fell). The
target moves on a straight line through a step's substeps instead, as MuJoCo's weld target does.

Simulations do not share a world: PyBullet's solver stops on the residual of the whole world, sorts
constraints and contact manifolds by island with an unstable quicksort (the several manifolds between a
finger and a decomposed object tie, so their order depends on the other pairs' bodies), and drops stale
broadphase pairs a few per step across the whole world. Hands at the same pose beside others then differ
after one step, and outcomes after a lift and a shake.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np
import pybullet

from .. import description_files
from ..config import Config
from ..execution.contact_model import engine_pad
from ..execution.pick import fingers_touching, push_n, set_finger_friction
from ..robot.description import robot_of
from ..world.objects import ObjectLoadError, ObjectSpec
from ..world.scene import command_fingers, configure_physics, create_table
from .collision_urdf import collision_only_urdf, labelling_hand_urdf
from .protocols import Pose, WorldStart, speed_past_bound


def solver_iterations(config: Config, object_mass_kg: float) -> int:
    """PyBullet's solver iterations for a slide hand holding an object of ``object_mass_kg``: the scene's, in
    proportion to how much lighter the object is than ``pybullet_full_iterations_mass_kg``, capped."""
    labelling, base = config.labelling, config.scene.solver_iterations
    scaled = math.ceil(base * labelling.pybullet_full_iterations_mass_kg / object_mass_kg)
    return max(base, min(scaled, labelling.pybullet_max_solver_iterations))


class PyBulletHand:
    """A PyBullet client in which one floating hand at a time labels one grasp."""

    name = "pybullet"

    def __init__(self, config: Config):
        self.config = config
        self.client = pybullet.connect(pybullet.DIRECT)
        self.robot = robot_of(config)
        self.hand_urdf = str(labelling_hand_urdf(config))
        self.gripper = self.robot.gripper
        self.pad = engine_pad(config.execution, self.robot)
        self.grasp_offset_m = self.gripper.grasp_depth_m
        self.mimics = description_files.mimics(Path(self.hand_urdf))
        self._object_urdfs: dict[str, str] = {}
        self.table: int | None = None
        self.step_division = 1
        self.substeps = 1
        self.steps_taken = 0

    def _object_urdf(self, spec: ObjectSpec) -> str:
        key = str(spec.urdf_path)
        if key not in self._object_urdfs:
            self._object_urdfs[key] = str(collision_only_urdf(spec.urdf_path, self.config.labelling.hand_urdf_cache_dir))
        return self._object_urdfs[key]

    def close(self) -> None:
        if pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)

    def __enter__(self) -> "PyBulletHand":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- building ------------------------------------------------------------------------------------
    def build(self, start: WorldStart) -> None:
        """A new world as ``start`` has it."""
        client, config, spec, object_pose = self.client, self.config, start.spec, start.object_pose
        hand_position, quat = start.hand_position, start.hand_quat
        pybullet.resetSimulation(physicsClientId=client)
        configure_physics(client, config.scene)
        self.set_gravity(start.gravity)
        pybullet.setPhysicsEngineParameter(erp=config.labelling.hand_constraint_erp,
                                           solverResidualThreshold=config.labelling.pybullet_solver_residual_threshold, physicsClientId=client)
        if self.gripper.finger_motion == "linkage":
            iterations = self.gripper.pybullet_solver_iterations or config.scene.solver_iterations
            self.substeps = self.gripper.pybullet_substeps * self.step_division
        else:
            iterations, self.substeps = solver_iterations(config, spec.mass_kg), self.step_division
        # numSubSteps 0: one stepSimulation a substep (``step``); the client keeps settings past resetSimulation.
        pybullet.setPhysicsEngineParameter(fixedTimeStep=config.scene.time_step_s / self.substeps, numSubSteps=0,
                                           numSolverIterations=iterations, physicsClientId=client)
        self.steps_taken = 0
        self.table = create_table(client, config.scene) if start.table else None
        try:
            # loadURDF places the link frame; resetBasePositionAndOrientation the centre-of-mass frame.
            link_pose = object_pose if start.object_frame == "link" else ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
            self.target = description_files.load_urdf(client, self._object_urdf(spec), basePosition=link_pose[0], baseOrientation=link_pose[1],
                                                      flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
        except pybullet.error as exc:
            raise ObjectLoadError(f"object '{spec.id}': PyBullet cannot load {spec.urdf_path}: {exc}") from exc
        if start.object_frame == "com":
            pybullet.resetBasePositionAndOrientation(self.target, object_pose[0], object_pose[1], physicsClientId=client)
        self.hand = description_files.load_urdf(client, self.hand_urdf)
        infos = [pybullet.getJointInfo(self.hand, j, physicsClientId=client) for j in range(pybullet.getNumJoints(self.hand, physicsClientId=client))]
        joints = {info[1].decode(): info[0] for info in infos}
        links = {info[12].decode(): info[0] for info in infos}  # a link's index is its parent joint's
        self.finger_joints = tuple(joints[name] for name in self.gripper.finger_joints)
        self.pad_links = tuple(links[name] for name in self.gripper.pad_links)
        # The constraint holds the grasp target; PyBullet pins a base by its inertial frame.
        inertial = pybullet.getDynamicsInfo(self.hand, -1, physicsClientId=client)[3:5]
        self.target_in_base = pybullet.multiplyTransforms(*pybullet.invertTransform(*inertial), [0.0, 0.0, self.grasp_offset_m], [0.0, 0.0, 0.0, 1.0])
        base = pybullet.multiplyTransforms(list(hand_position), list(quat), *pybullet.invertTransform(*self.target_in_base))
        pybullet.resetBasePositionAndOrientation(self.hand, *base, physicsClientId=client)
        if self.gripper.finger_motion == "slide":
            for joint in self.finger_joints:
                pybullet.resetJointState(self.hand, joint, self.gripper.open_width_m / 2.0, physicsClientId=client)
            self._couple_fingers(joints)
        else:
            self._tie_linkage(joints)
        self.command_fingers(self.gripper.open_width_m)
        set_finger_friction(client, self.hand, self.pad_links, self.pad, self.target)
        self.constraint = pybullet.createConstraint(
            self.hand, -1, -1, -1, pybullet.JOINT_FIXED, [0.0, 0.0, 0.0],
            parentFramePosition=self.target_in_base[0], childFramePosition=list(hand_position),
            parentFrameOrientation=self.target_in_base[1], childFrameOrientation=list(quat),
            physicsClientId=client,
        )
        self.quat = tuple(quat)
        self.hand_goal = self.hand_goal_before = (tuple(map(float, hand_position)), self.quat)
        self._place_target(*self.hand_goal)

    # -- motion --------------------------------------------------------------------------------------
    def set_gravity(self, on: bool) -> None:
        pybullet.setGravity(0.0, 0.0, self.config.scene.gravity_m_s2 if on else 0.0, physicsClientId=self.client)

    def command_fingers(self, width_m: float) -> None:
        if self.gripper.finger_motion == "slide":
            command_fingers(self.client, self.hand, self.finger_joints, width_m, self.config.execution.gripper_force_n)
        else:
            self.finger_target = self.gripper.finger_joint_value(width_m)
            self._drive_linkage()

    def step(self, steps: int) -> None:
        """``steps`` protocol steps, the first carrying the hand's target to where ``move`` last sent it on a
        straight line through its substeps (its orientation by slerp); a linkage's drive set every substep."""
        linkage = self.gripper.finger_motion == "linkage"
        for _ in range(steps):
            (start, start_quat), (end, end_quat) = self.hand_goal_before, self.hand_goal
            moved = self.hand_goal != self.hand_goal_before
            for substep in range(1, self.substeps + 1):
                if moved and substep < self.substeps:
                    fraction = substep / self.substeps
                    self._place_target([a + (b - a) * fraction for a, b in zip(start, end)],
                                       pybullet.getQuaternionSlerp(start_quat, end_quat, fraction))
                elif moved:
                    self._place_target(end, end_quat)  # each step ends on its target to the last digit
                if linkage:
                    self._drive_linkage()
                pybullet.stepSimulation(physicsClientId=self.client)
            self.hand_goal_before = self.hand_goal
        self.steps_taken += max(steps, 0)

    def _tie_linkage(self, joints: dict[str, int]) -> None:
        """Every driven and mimic joint at the open configuration, each mimic joint geared to its leader:
        PyBullet ignores ``<mimic>``, and without the gears the pads neither stay parallel nor move together."""
        client, open_value = self.client, self.gripper.finger_joint_value(self.gripper.open_width_m)
        # A gear carries a follower's share of the drive: the driven joint's effort limit (URDF) bounds it.
        gear_max_torque = pybullet.getJointInfo(self.hand, self.finger_joints[0], physicsClientId=client)[10]
        for joint in self.finger_joints:
            pybullet.resetJointState(self.hand, joint, open_value, physicsClientId=client)
        for name, rule in self.mimics.items():
            leader, follower = joints[rule.leader], joints[name]
            pybullet.resetJointState(self.hand, follower, rule.multiplier * open_value + rule.offset, physicsClientId=client)
            # PyBullet gives every joint a velocity motor; a follower's would fight its gear.
            pybullet.setJointMotorControl2(self.hand, follower, pybullet.VELOCITY_CONTROL, force=0.0, physicsClientId=client)
            self._gear(leader, follower, rule, gear_max_torque)

    def _couple_fingers(self, joints: dict[str, int]) -> None:
        """Each mimic finger geared to its leader: the Panda's one motor drives both fingers through a
        coupling. Free, force-capped fingers let an object the shake pushes along the closing axis carry
        both with it until one meets its limit and its pad lets go. The gear is as strong as the hand's
        carrying constraint, a mechanism rather than a motor (the driven joint's effort limit, 20 N, is
        under the grip forces the hand takes). The object's balance makes each pad press the mean of the
        two motors' forces: each capped at the grip force."""
        for name, rule in self.mimics.items():
            self._gear(joints[rule.leader], joints[name], rule, self.config.labelling.hand_constraint_max_force_n)

    def _gear(self, leader: int, follower: int, rule: description_files.Mimic, max_force: float) -> None:
        gear = pybullet.createConstraint(self.hand, leader, self.hand, follower, pybullet.JOINT_GEAR, [1.0, 0.0, 0.0],
                                         [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=self.client)
        # The gear holds leader + ratio * follower at the target: follower = multiplier * leader + offset.
        pybullet.changeConstraint(gear, gearRatio=-1.0 / rule.multiplier, relativePositionTarget=-rule.offset / rule.multiplier,
                                  erp=1.0, maxForce=max_force, physicsClientId=self.client)

    def _drive_linkage(self) -> None:
        """The driven joint toward its target with the torque that presses each pad with the grip force
        where the fingers stand now: the linkage's leverage changes along the stroke, and the fingers stop
        wherever the object is."""
        client = self.client
        joint_value = pybullet.getJointState(self.hand, self.finger_joints[0], physicsClientId=client)[0]
        torque = self.config.execution.gripper_force_n * self.gripper.drive_torque_per_pad_newton(joint_value)
        pybullet.setJointMotorControlArray(self.hand, list(self.finger_joints), pybullet.POSITION_CONTROL,
                                           targetPositions=[self.finger_target] * len(self.finger_joints),
                                           forces=[torque] * len(self.finger_joints), physicsClientId=client)

    def move(self, position: Sequence[float], quat: Sequence[float] | None = None) -> None:
        """Send the hand's grasp target toward a pose: the next step carries the constraint's target there."""
        self.hand_goal = (tuple(map(float, position)), tuple(map(float, quat or self.quat)))

    def _place_target(self, position: Sequence[float], quat: Sequence[float]) -> None:
        pybullet.changeConstraint(
            self.constraint, jointChildPivot=list(position), jointChildFrameOrientation=list(quat),
            maxForce=self.config.labelling.hand_constraint_max_force_n, physicsClientId=self.client,
        )

    def follow(self, positions: Sequence[Sequence[float]], quats: Sequence[Sequence[float]] | None = None) -> np.ndarray:
        """``move`` to each of ``positions`` (T, 3), with ``quats`` (T, 4) or the hand's orientation,
        then ``step(1)``; (T, 7) the grasp target's pose (position, xyzw quaternion) after each step."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 3).tolist()
        quats = [None] * len(positions) if quats is None else np.asarray(quats, dtype=float).reshape(-1, 4).tolist()
        poses = np.empty((len(positions), 7))
        for index, (position, quat) in enumerate(zip(positions, quats)):
            self.move(position, quat)
            self.step(1)
            poses[index, :3], poses[index, 3:] = self.hand_pose()
        return poses

    # -- state ---------------------------------------------------------------------------------------
    def object_pose(self) -> Pose:
        """World pose of the object's centre-of-mass frame."""
        return pybullet.getBasePositionAndOrientation(self.target, physicsClientId=self.client)

    def diverged(self) -> str | None:
        """Why the simulation since ``build`` has diverged (a non-finite pose or velocity of the object
        or the hand, the object faster than ``protocols.speed_past_bound`` allows relative to the hand), or None."""
        velocities = []
        for body in (self.target, self.hand):
            position, quat = pybullet.getBasePositionAndOrientation(body, physicsClientId=self.client)
            linear, angular = pybullet.getBaseVelocity(body, physicsClientId=self.client)
            if not all(math.isfinite(value) for value in (*position, *quat, *linear, *angular)):
                return "diverged: non-finite state"
            velocities.append(np.array(linear))
        speed = float(np.linalg.norm(velocities[0] - velocities[1]))
        return speed_past_bound(speed, self.steps_taken * self.config.scene.time_step_s, self.config)

    def hand_pose(self) -> Pose:
        """World pose of the hand's grasp target."""
        base = pybullet.getBasePositionAndOrientation(self.hand, physicsClientId=self.client)
        return pybullet.multiplyTransforms(*base, *self.target_in_base)

    def _contacts(self, body: int | None) -> list[tuple]:
        if body is None:
            return []
        return pybullet.getContactPoints(bodyA=self.hand, bodyB=body, physicsClientId=self.client)

    def hand_in_contact(self) -> tuple[bool, bool]:
        """Whether the hand touches the object, and the table, before anything has moved."""
        pybullet.performCollisionDetection(physicsClientId=self.client)
        return bool(self._contacts(self.target)), bool(self._contacts(self.table))

    def hand_touching(self) -> bool:
        """Whether any part of the hand touched the object in the last step (its contacts, not detected anew)."""
        return bool(self._contacts(self.target))

    def table_push_n(self) -> float:
        """The normal force the hand pushes the table with (0 without a table)."""
        return push_n(self._contacts(self.table))

    def fingers_touching(self) -> bool:
        return fingers_touching(self.client, self.hand, self.pad_links, self.target)
