"""The joints an attempt executes, through the waypoints of ``motion.motion_waypoints``.

The planner's joint path is executed as planned once PyBullet's forward kinematics confirms it
reaches every waypoint. Without one (or when it fails that check) the motion is solved here:
PyBullet's ``calculateInverseKinematics`` (``ik_iterations``) with joint limits, ranges and rest
poses, seeded by the planner's joints, then Franka's ready pose, mid-limits and seeded random
joints, every solution checked against the limits and by forward kinematics; the batched
``PandaIK`` where PyBullet fails. Those waypoints are each seeded by their neighbour and must stay
on the grasp solution's IK branch.
"""
from __future__ import annotations

import math
from typing import Any, Iterator, Sequence

import numpy as np
import pybullet
import torch

from ..attempt import AttemptDiagnostics
from ..config import Config
from ..grasps import as_finite_vector
from ..robot.ik import panda_ik
from ..robot.motion import grasp_waypoint_index
from ..seeds import ik_restart_seed
from ..world.scene import Scene
from .poses import quat_angle_deg

# Joint-limit slack for accepting an IK solution: PyBullet clamps to the limits within float noise.
LIMIT_SLACK_RAD = 1e-6


class _ArmIK:
    """Validated IK for ``panda_grasptarget`` in one scene (teleports the arm; call before stepping)."""

    def __init__(self, scene: Scene, config: Config):
        self.scene = scene
        self.config = config
        client, robot = scene.client, scene.robot_id
        movable = list(scene.robot_indices.movable_joints)
        info = [pybullet.getJointInfo(robot, j, physicsClientId=client) for j in movable]
        self.lower = np.array([i[8] for i in info])
        self.upper = np.array([i[9] for i in info])
        self.arm_slots = [movable.index(j) for j in scene.robot_indices.arm_joints]
        self.rng = np.random.default_rng(ik_restart_seed(config, scene.trial or 0))
        self.source = "pybullet"

    def _full(self, arm_joints: np.ndarray) -> list[float]:
        full = (self.lower + self.upper) / 2.0
        full[self.arm_slots] = arm_joints
        return full.tolist()

    def check(self, arm_joints: np.ndarray, position: np.ndarray, quat: np.ndarray) -> tuple[bool, float, float]:
        """(valid, position error m, rotation error rad) of arm joints against a grasptarget pose."""
        lower, upper = self.lower[self.arm_slots], self.upper[self.arm_slots]
        inside = bool(np.all(arm_joints >= lower - LIMIT_SLACK_RAD) and np.all(arm_joints <= upper + LIMIT_SLACK_RAD))
        for joint, angle in zip(self.scene.robot_indices.arm_joints, arm_joints):
            pybullet.resetJointState(self.scene.robot_id, joint, float(angle), physicsClientId=self.scene.client)
        reached_position, reached_quat = self.scene.grasptarget_pose()
        position_error = float(np.linalg.norm(reached_position - position))
        rotation_error = math.radians(quat_angle_deg(reached_quat, quat))
        robot = self.scene.robot
        valid = inside and position_error <= robot.ik_position_tolerance_m and rotation_error <= robot.ik_rotation_tolerance_rad
        return valid, position_error, rotation_error

    def _pybullet(self, position: np.ndarray, quat: np.ndarray, seed: np.ndarray) -> np.ndarray | None:
        client, robot = self.scene.client, self.scene.robot_id
        # PyBullet's IK iterates from the body's current joints, so the seed is set first.
        for joint, angle in zip(self.scene.robot_indices.arm_joints, seed):
            pybullet.resetJointState(robot, joint, float(angle), physicsClientId=client)
        solution = pybullet.calculateInverseKinematics(
            robot,
            self.scene.robot_indices.grasp_target_link,
            position.tolist(),
            quat.tolist(),
            lowerLimits=self.lower.tolist(),
            upperLimits=self.upper.tolist(),
            jointRanges=(self.upper - self.lower).tolist(),
            restPoses=self._full(seed),
            maxNumIterations=self.config.execution.ik_iterations,
            residualThreshold=1e-6,
            physicsClientId=client,
        )
        arm_joints = np.array(solution)[self.arm_slots]
        return arm_joints if self.check(arm_joints, position, quat)[0] else None

    def _panda_ik(self, position: np.ndarray, quat: np.ndarray, seed: np.ndarray) -> np.ndarray | None:
        rotation = np.array(pybullet.getMatrixFromQuaternion(quat.tolist())).reshape(3, 3)
        result = panda_ik(self.config).solve(
            torch.tensor(position, dtype=torch.float32).view(1, 3),
            torch.tensor(rotation, dtype=torch.float32).view(1, 3, 3),
            torch.tensor(seed, dtype=torch.float32).view(1, -1),
        )
        arm_joints = result.joints[0].double().numpy()
        return arm_joints if self.check(arm_joints, position, quat)[0] else None

    def _seeds(self, given: Sequence[np.ndarray]) -> Iterator[np.ndarray]:
        lower, upper = self.lower[self.arm_slots], self.upper[self.arm_slots]
        yield from (np.clip(seed, lower, upper) for seed in given)
        yield np.asarray(self.scene.robot.ik_reference_joints, dtype=float)
        yield (lower + upper) / 2.0
        for _ in range(self.config.execution.ik_random_restarts):
            yield self.rng.uniform(lower, upper)

    def grasp_solutions(self, position: np.ndarray, quat: np.ndarray, seeds: Sequence[np.ndarray]) -> Iterator[np.ndarray]:
        """Valid solutions for one pose, one per seed that converges (PyBullet, then PandaIK)."""
        for seed in self._seeds(seeds):
            arm_joints = self._pybullet(position, quat, seed)
            if arm_joints is not None:
                yield arm_joints
        arm_joints = self._panda_ik(position, quat, next(self._seeds(seeds)))
        if arm_joints is not None:
            self.source = "panda_ik"
            yield arm_joints

    def path(self, start_joints: np.ndarray, positions: Sequence[np.ndarray], quat: np.ndarray) -> list[np.ndarray] | None:
        """Joints for each position in order, each seeded by the previous one; None if IK switches branch."""
        solutions = [start_joints]
        for position in positions:
            arm_joints = self._pybullet(position, quat, solutions[-1])
            if arm_joints is None or np.abs(arm_joints - solutions[-1]).max() > self.config.motion.max_waypoint_joint_step_rad:
                return None
            solutions.append(arm_joints)
        return solutions[1:]

    def plan(self, waypoints: np.ndarray, quat: np.ndarray, seeds: Sequence[np.ndarray], grasp_index: int) -> np.ndarray | None:
        """(W, 7) joints through ``waypoints`` (the motion's positions, the grasp at ``grasp_index``)
        from the first grasp solution whose descent and lift both stay on one IK branch; the
        descent is solved backwards from the grasp."""
        for grasp_joints in self.grasp_solutions(waypoints[grasp_index], quat, seeds):
            backwards = self.path(grasp_joints, list(waypoints[:grasp_index])[::-1], quat)
            lift_joints = self.path(grasp_joints, list(waypoints[grasp_index + 1:]), quat) if backwards is not None else None
            if lift_joints is not None:
                return np.array([*backwards[::-1], grasp_joints, *lift_joints])
        return None

    def reproduces(self, joint_path: np.ndarray, waypoints: np.ndarray, quat: np.ndarray) -> bool:
        """Whether PyBullet's own kinematics puts the grasp target on every waypoint with these joints."""
        return all(self.check(joints, position, quat)[0] for joints, position in zip(joint_path, waypoints))


def path_to_execute(
    scene: Scene, config: Config, waypoints: np.ndarray, quat: np.ndarray, joint_path: np.ndarray | None, ik_seed: Any, diagnostics: AttemptDiagnostics
) -> np.ndarray | None:
    """The planner's joint path if PyBullet's kinematics confirms it reaches the waypoints, else
    PyBullet IK's (None if it finds none); ``diagnostics`` records which and why."""
    ik = _ArmIK(scene, config)
    if joint_path is not None and ik.reproduces(joint_path, waypoints, quat):
        diagnostics.ik_source = "planner"
        return joint_path
    diagnostics.ik_fallback = "no planned path" if joint_path is None else "planned joints miss a waypoint in PyBullet"
    seeds = [as_finite_vector(ik_seed, 7, "ik_seed")] if ik_seed is not None else []
    path = ik.plan(waypoints, quat, seeds, grasp_waypoint_index(config.motion))
    diagnostics.ik_source = ik.source
    return path
