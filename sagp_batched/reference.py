"""The grasp planner written the straightforward way: a Python loop over pairs and approaches,
PyBullet's ``calculateInverseKinematics`` one pose at a time.

It is the correctness oracle and speed baseline for ``planner.plan``'s published part: same random
draws (``planning.sample_inputs``), same candidate tests and thresholds (antipodal filter, table,
the 12 % gripper volume, grasp-pose IK), same order of trying candidates (S_geom order) and
approaches (top-down-first prior), but no batching anywhere. It stops there: the planner's
whole-motion reachability and swept-hand checks are beyond the published method. Geometry is
hand-written with NumPy on purpose, independently of the kernels it checks.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pybullet
import torch

from .config import Config
from .planning import hand_geometry, jaw_width_limit, sample_inputs
from .robot import robot_of
from .types import GraspCandidates, PerceivedCloud


@dataclass
class ReferencePlan:
    """The loop planner's result and the intermediate decisions tests compare against."""

    candidates: GraspCandidates
    ranked_pairs: np.ndarray  # (A, 2) antipodal pair indices, ranked by S_geom (sampling order among ties)
    s_geom: np.ndarray  # (A,) in the same order
    approaches: np.ndarray  # (A, K, 3) approach directions in prior order
    usable: np.ndarray  # (A, K) bool: clear of the table and under the occupancy limit
    ik_trials: list[dict] = field(default_factory=list)  # one per IK call: position, rotation, feasible
    counts: dict[str, int] = field(default_factory=dict)  # sampled / antipodal / collision_free / ik_feasible


class PyBulletPandaIK:
    """One Panda in its own DIRECT client, solved pose by pose with ``calculateInverseKinematics``."""

    def __init__(self, config: Config):
        self.config = config
        self.description = robot = robot_of(config)
        self.client = pybullet.connect(pybullet.DIRECT)
        self.robot = pybullet.loadURDF(
            str(robot.urdf_path), basePosition=robot.base_xyz_m, useFixedBase=True, physicsClientId=self.client
        )
        joints = [pybullet.getJointInfo(self.robot, j, physicsClientId=self.client) for j in range(pybullet.getNumJoints(self.robot, physicsClientId=self.client))]
        self.end_link = next(j[0] for j in joints if j[12].decode() == robot.grasp_target_link)
        self.movable = [j[0] for j in joints if j[2] != pybullet.JOINT_FIXED]
        self.lower = np.array([joints[j][8] for j in self.movable])
        self.upper = np.array([joints[j][9] for j in self.movable])
        # Rest pose mid-limits: PyBullet's null-space IK keeps solutions near it (measured on
        # 200 random targets: 63 % inside limits from mid-limit joints versus 13 % from zero).
        self.rest = list((self.lower + self.upper) / 2)

    def close(self) -> None:
        pybullet.disconnect(self.client)

    def solve(self, position: np.ndarray, quat_xyzw: np.ndarray) -> tuple[np.ndarray, float, float]:
        """Arm joints, position error (m) and rotation error (rad) of the reached grasp target."""
        for joint, value in zip(self.movable, self.rest):
            pybullet.resetJointState(self.robot, joint, value, physicsClientId=self.client)
        solution = pybullet.calculateInverseKinematics(
            self.robot,
            self.end_link,
            position.tolist(),
            quat_xyzw.tolist(),
            lowerLimits=self.lower.tolist(),
            upperLimits=self.upper.tolist(),
            jointRanges=(self.upper - self.lower).tolist(),
            restPoses=self.rest,
            maxNumIterations=self.config.execution.ik_iterations,
            physicsClientId=self.client,
        )
        for joint, value in zip(self.movable, solution):
            pybullet.resetJointState(self.robot, joint, value, physicsClientId=self.client)
        state = pybullet.getLinkState(self.robot, self.end_link, computeForwardKinematics=True, physicsClientId=self.client)
        position_error = float(np.linalg.norm(np.array(state[4]) - position))
        relative = pybullet.getDifferenceQuaternion(quat_xyzw.tolist(), state[5])
        rotation_error = 2.0 * math.acos(min(1.0, abs(relative[3])))
        joints = np.array(solution)
        inside = bool(np.all(joints >= self.lower - 1e-6) and np.all(joints <= self.upper + 1e-6))
        return joints[: self.description.n_arm_joints], position_error, rotation_error if inside else math.pi


def _matrix_to_quat_xyzw(rotation: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(rotation).as_quat()


def plan_reference(cloud: PerceivedCloud, config: Config, seed: int | None = None) -> ReferencePlan:
    """Plan like ``planning.plan`` with loops; see the module docstring."""
    planner = config.planner
    seed = planner.seed if seed is None else seed
    robot = robot_of(config)
    boxes = robot.gripper_boxes
    inputs = sample_inputs(cloud, robot, planner, seed)
    points = cloud.points_world.double().numpy()
    normals = cloud.normals_world.double().numpy()
    min_cos = math.cos(math.radians(planner.max_contact_angle_deg))

    survivors = []
    for order, (i, j) in enumerate(inputs.pair_indices.tolist()):
        offset = points[j] - points[i]
        width = float(np.linalg.norm(offset))
        if not planner.min_width_m <= width <= planner.max_width_m:
            continue
        axis = offset / width
        cos_i = -float(normals[i] @ axis)  # outward n_i points away from contact j
        cos_j = float(normals[j] @ axis)
        if cos_i > min_cos and cos_j > min_cos:
            survivors.append((-(cos_i * cos_j), order, i, j, width, axis))
    survivors.sort(key=lambda s: (s[0], s[1]))

    occupancy_points = inputs.occupancy_points.double().numpy()
    down = np.array([0.0, 0.0, -1.0])
    finger_z_max = boxes.fingertip_offset_m
    finger_z_min = finger_z_max - boxes.finger_length_m
    palm_z_min = finger_z_min - boxes.palm_depth_m
    finger_y_max = robot.open_width_m / 2 + boxes.finger_thickness_m
    # The table check tests the hand's collision hulls (derived from the robot's URDF), as the
    # planner does: the fingers and the rest of the hand each with their own clearance.
    hand = hand_geometry(robot)
    table_levels = [
        (hull.double().numpy(), planner.finger_table_clearance_m if name in robot.finger_links else planner.arm_table_clearance_m)
        for name, hull in zip(hand.links, hand.hull_vertices)
    ]

    ranked_pairs, s_geoms, all_approaches, usable_rows, rotations_rows = [], [], [], [], []
    for negative_quality, _, i, j, width, axis in survivors:
        centre = (points[i] + points[j]) / 2
        first = down - (down @ axis) * axis
        if np.linalg.norm(first) < 1e-6:
            fallback = np.zeros(3)
            fallback[np.argmin(np.abs(axis))] = 1.0
            first = fallback - (fallback @ axis) * axis
        first /= np.linalg.norm(first)
        second = np.cross(axis, first)
        candidate_approaches = []
        # Most downward first, then alternately either side of it.
        for k in range(planner.n_approaches):
            step = (k + 1) // 2 * (1 if k % 2 else -1)
            angle = 2.0 * math.pi * step / planner.n_approaches
            candidate_approaches.append(math.cos(angle) * first + math.sin(angle) * second)
        row_usable, row_rotations = [], []
        for approach in candidate_approaches:
            rotation = np.stack((np.cross(axis, approach), axis, approach), axis=1)
            through_table = False
            for hull_points, clearance in table_levels:
                lowest = float((centre[2] + hull_points @ rotation[2]).min())
                lowest_pregrasp = lowest - config.execution.pregrasp_offset_m * approach[2]
                through_table |= min(lowest, lowest_pregrasp) < config.scene.table_top_z_m + clearance
            local = (occupancy_points - centre) @ rotation
            abs_x, abs_y, z = np.abs(local[:, 0]), np.abs(local[:, 1]), local[:, 2]
            in_fingers = (
                (abs_x <= boxes.finger_width_m / 2)
                & (abs_y >= width / 2 + planner.contact_clearance_m)
                & (abs_y <= finger_y_max)
                & (z >= finger_z_min)
                & (z <= finger_z_max)
            )
            under_palm = (abs_x <= boxes.palm_width_m / 2) & (abs_y <= boxes.palm_span_m / 2)
            in_palm = under_palm & (z >= palm_z_min) & (z <= finger_z_min)
            occupied = int(np.count_nonzero(in_fingers | in_palm))
            row_usable.append(not through_table and occupied <= planner.occupancy_max_fraction * inputs.occupancy_total
                              and width <= jaw_width_limit(robot, planner))
            row_rotations.append(rotation)
        ranked_pairs.append((i, j))
        s_geoms.append(-negative_quality)
        all_approaches.append(candidate_approaches)
        usable_rows.append(row_usable)
        rotations_rows.append(row_rotations)

    ik = PyBulletPandaIK(config)
    chosen = []  # (rank, approach slot, joints, s_reach)
    trials = []
    try:
        for rank in range(len(survivors)):
            if len(chosen) == planner.max_candidates:
                break
            i, j = ranked_pairs[rank]
            centre = (points[i] + points[j]) / 2
            for slot in range(planner.n_approaches):
                if not usable_rows[rank][slot]:
                    continue
                rotation = rotations_rows[rank][slot]
                joints, position_error, rotation_error = ik.solve(centre, _matrix_to_quat_xyzw(rotation))
                s_reach = (1.0 + math.cos(rotation_error)) / 2.0
                feasible = (position_error < robot.ik_position_tolerance_m and rotation_error < robot.ik_rotation_tolerance_rad
                            and s_reach >= planner.min_reach)
                trials.append({"rank": rank, "slot": slot, "position": centre, "rotation": rotation, "feasible": feasible})
                if feasible:
                    chosen.append((rank, slot, joints, s_reach))
                    break
    finally:
        ik.close()

    count = len(chosen)
    contacts = np.array([[points[ranked_pairs[r][0]], points[ranked_pairs[r][1]]] for r, *_ in chosen]).reshape(count, 2, 3)
    closing = contacts[:, 1] - contacts[:, 0]
    widths = np.linalg.norm(closing, axis=1)
    geom = np.array([s_geoms[r] for r, *_ in chosen])
    as_tensor = lambda values, shape: torch.as_tensor(np.asarray(values, dtype=np.float32).reshape(shape))  # noqa: E731
    candidates = GraspCandidates(
        contacts_world=as_tensor(contacts, (count, 2, 3)),
        closing_axis=as_tensor(closing / np.maximum(widths[:, None], 1e-12), (count, 3)),
        width_m=as_tensor(widths, (count,)),
        s_geom=as_tensor(geom, (count,)),
        approach=as_tensor([all_approaches[r][s] for r, s, *_ in chosen], (count, 3)),
        rotation_world=as_tensor([rotations_rows[r][s] for r, s, *_ in chosen], (count, 3, 3)),
        s_reach=as_tensor([reach for *_, reach in chosen], (count,)),
        ik_solution=as_tensor([joints for _, _, joints, _ in chosen], (count, robot.n_arm_joints)),
        zone=torch.full((count,), -1, dtype=torch.int64),
        s_afford=torch.zeros(count),
        s_avoid=torch.zeros(count),
        s_task=torch.zeros(count),
        score=as_tensor(geom, (count,)),
    )
    return ReferencePlan(
        candidates=candidates,
        ranked_pairs=np.array(ranked_pairs, dtype=np.int64).reshape(-1, 2),
        s_geom=np.array(s_geoms),
        approaches=np.array(all_approaches).reshape(len(survivors), planner.n_approaches, 3),
        usable=np.array(usable_rows, dtype=bool).reshape(len(survivors), planner.n_approaches),
        ik_trials=trials,
        counts={
            "sampled": planner.n_pairs,
            "antipodal": len(survivors),
            "collision_free": sum(any(row) for row in usable_rows),
            "ik_feasible": count,
        },
    )
