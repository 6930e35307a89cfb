"""Batched Panda inverse kinematics for reachability scoring: closed form, checked by forward kinematics.

Grasp poses are solved by the Panda's closed form (``sagp_batched_kernels.panda_ik``) over a grid
of joint-7 values, for all targets of a planning call at once; per target the solution nearest to a
deterministic reference posture is kept, so the same targets always give the same joints. Every
answer is then judged by the forward kinematics of pytorch-kinematics' chain (computed by
``sagp_batched_kernels.serial_kinematics``, which matches pk's own to float32 rounding at a
fraction of its cost), and the rare one that misses the tolerance (float32 rounding next to a
singularity) is polished by damped-least-squares steps on the chain's geometric Jacobian. The
arm's link offsets are read from the same chain (``kinematics``).
"""
from __future__ import annotations

import copy
import functools
from dataclasses import astuple, dataclass

import pytorch_kinematics as pk
import torch

from sagp_batched_kernels.panda_ik import panda_ik_closed_form, wrist_in_reach

from ..config import Config, IKConfig
from .description import RobotDescription, robot_of
from .kinematics import ChainFrames, arm_chain, link_moved_by, panda_arm_geometry



@dataclass
class IKResult:
    """IK outcome for N target poses (world frame)."""

    joints: torch.Tensor  # (N, 7) arm joints, radians, inside the joint limits
    success: torch.Tensor  # (N,) bool: position and rotation within tolerance, joints inside limits
    position_error_m: torch.Tensor  # (N,) distance of the reached grasp target from the requested one
    rotation_error_rad: torch.Tensor  # (N,) angle between the reached and requested orientation
    s_reach: torch.Tensor  # (N,) (1 + cos(rotation_error)) / 2, in [0, 1]


@dataclass
class WaypointTargets:
    """R waypoints of motions, one row each, motion by motion (``PandaIK.waypoint_targets``)."""

    start: torch.Tensor  # (R, 7) joints of the row's motion's known pose, radians
    position_base: torch.Tensor  # (R, 3) ``panda_grasptarget`` waypoint, base frame, metres
    rotation: torch.Tensor  # (R, 3, 3) orientation held there (grasp frame -> base)

    def rows(self, index: torch.Tensor) -> WaypointTargets:
        return WaypointTargets(self.start[index], self.position_base[index], self.rotation[index])


class PandaIK:
    """Inverse kinematics of the Panda arm to ``panda_grasptarget``, batched over targets.

    The robot's base stands at its ``base_xyz_m`` in the world with identity orientation (facing
    +x); ``robot`` also gives the tolerances an answer must meet and the posture answers stay near.
    """

    def __init__(self, config: IKConfig, robot: RobotDescription):
        self.config = config
        self.robot = robot
        self.n_joints = robot.n_arm_joints
        self.chain = arm_chain(robot)
        self.frames = ChainFrames.of(self.chain)
        self.lower, self.upper = (torch.tensor(bound, dtype=torch.float32) for bound in self.chain.get_joint_limits())
        self.reference_joints = torch.tensor(robot.ik_reference_joints, dtype=torch.float32).clamp(self.lower, self.upper)
        self.base_xyz_world = torch.tensor(robot.base_xyz_m, dtype=torch.float32)
        self.arm_geometry = panda_arm_geometry(self.chain, robot)
        # The closed form runs in float64: near its singularities (elbow straight at its extreme,
        # sin q5 = +-1) float32 input rounding alone moves the answer by ~1e-3 rad.
        chain64 = arm_chain(robot).to(dtype=torch.float64)  # ``to`` converts in place: a chain of its own
        frames = chain64.forward_kinematics(torch.zeros(1, self.n_joints, dtype=torch.float64), end_only=False)
        link7_in_target = frames[robot.gripper.grasp_target_link].get_matrix()[0].inverse() @ frames[link_moved_by(self.chain, robot.arm_joints[-1])].get_matrix()[0]
        self._link7_in_target = link7_in_target  # (4, 4): fixed flange, hand and grasp-target offsets
        self._q7_grid = torch.linspace(float(self.lower[-1]), float(self.upper[-1]), config.q7_samples, dtype=torch.float64)
        self._q7_fine_grid = torch.linspace(float(self.lower[-1]), float(self.upper[-1]), config.q7_fine_samples, dtype=torch.float64)
        self._damping = torch.eye(6) * config.damping**2  # the damped-least-squares steps' (6, 6) damping, made once
        self._on_devices = {torch.device("cpu"): self}

    def on(self, device: torch.device) -> PandaIK:
        """This solver with every constant on ``device``: made once per device and kept, so a plan on a
        GPU moves the robot there once, not per call."""
        if device not in self._on_devices:
            moved = copy.copy(self)
            moved.frames = self.frames.to(device)
            for name in ("lower", "upper", "reference_joints", "base_xyz_world", "_link7_in_target", "_q7_grid", "_q7_fine_grid", "_damping"):
                setattr(moved, name, getattr(self, name).to(device))
            self._on_devices[device] = moved
        return self._on_devices[device]

    def forward(self, joints: torch.Tensor) -> torch.Tensor:
        """(N, 7) arm joints -> (N, 4, 4) pose of ``panda_grasptarget`` in the world frame."""
        matrix = self.chain.forward_kinematics(joints.to(torch.float32)).get_matrix().clone()
        matrix[:, :3, 3] += self.base_xyz_world
        return matrix

    def lowest_link_point_z(self, joints: torch.Tensor, hulls: dict[str, torch.Tensor]) -> torch.Tensor:
        """(M,) lowest world height (m) of any hull vertex of the named links at each of M (M, 7) joint configurations.

        ``hulls`` maps link names of the chain to (V, 3) hull vertices in that link's frame.
        """
        return self._lowest_hull_z(self.frames.poses(joints.to(torch.float32)), hulls)

    def _lowest_hull_z(self, link_poses: torch.Tensor, hulls: dict[str, torch.Tensor]) -> torch.Tensor:
        """(M,) lowest world height (m) of the ``hulls`` vertices placed by (F, 3, 4, M) frame poses (``ChainFrames.poses``, base frame)."""
        lowest = None
        for name, vertices in hulls.items():
            height_row = link_poses[self.frames.names.index(name), 2]  # (4, M): the z row of the link's transform
            # The link's height is added to the lowest vertex only, not to all V: rounding is
            # monotonic, so the minimum of the sums is the sum with the minimum, bit for bit.
            heights = (height_row[:3].T @ vertices.T).amin(dim=1) + height_row[3]
            lowest = heights if lowest is None else torch.minimum(lowest, heights)
        return lowest + self.base_xyz_world[2]

    def preferred_joints(self, positions_base: torch.Tensor, seed_joints: torch.Tensor | None) -> torch.Tensor:
        """(N, 7) posture each target's solution should stay near: ``seed_joints`` if given, else the
        reference joints with joint 1 turned toward the target (``positions_base``: (N, 3), base frame)."""
        if seed_joints is not None:
            return seed_joints.to(torch.float32).clamp(self.lower, self.upper)
        preferred = self.reference_joints.repeat(positions_base.shape[0], 1)
        azimuth = torch.atan2(positions_base[:, 1], positions_base[:, 0])
        preferred[:, 0] = (preferred[:, 0] + azimuth).clamp(self.lower[0], self.upper[0])
        return preferred

    def _closed_form_nearest(
        self, rotation_link7: torch.Tensor, position_link7: torch.Tensor, q7_grid: torch.Tensor, preferred: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, 7) float64 closed-form solution per target, and (M,) bool: one exists.

        The solution nearest in joint space to ``preferred`` (M, 7) among those keeping
        ``limit_margin_rad`` from every joint limit (or as far as ``preferred`` itself keeps, if
        less), else among all. Joint 7 takes the (K,) ``q7_grid`` values and the preferred
        posture's own, which the nearest solution most often has.
        """
        preferred = preferred.double()
        q7 = torch.cat((preferred[:, 6:], q7_grid.expand(len(preferred), -1)), dim=1)
        solutions = panda_ik_closed_form(rotation_link7, position_link7, q7, self.arm_geometry, self.lower, self.upper)
        candidates = solutions.joints.flatten(1, 2)  # (M, (K + 1) * 8, 7)
        valid = solutions.valid.flatten(1)
        # Less 0.01 rad, so that float32 rounding of a target does not rule out the preferred posture itself.
        required_margin = self._limit_margin(preferred).clamp_max(self.config.limit_margin_rad) - 0.01
        near_limit = self._limit_margin(candidates) < required_margin[:, None]
        # Squared joint distances stay under 7 (2 pi)^2 < 300: the offset ranks every solution
        # clear of the limits before any near them.
        rank_key = _squared_distances(candidates, preferred) + 300.0 * near_limit
        nearest = rank_key.masked_fill(~valid, float("inf")).argmin(dim=1)
        return candidates[torch.arange(len(candidates), device=nearest.device), nearest], valid.any(dim=1)

    def _link7_targets(self, positions_base: torch.Tensor, rotations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, 3, 3) orientation and (M, 3) position of ``panda_link7`` (float64, base frame) that put the
        grasp target at (M, 3) base-frame ``positions_base`` with (M, 3, 3) ``rotations``."""
        rotation_link7 = rotations.double() @ self._link7_in_target[:3, :3]
        position_link7 = positions_base.double() + rotations.double() @ self._link7_in_target[:3, 3]
        return rotation_link7, position_link7

    def _limit_margin(self, joints: torch.Tensor) -> torch.Tensor:
        """(...) smallest distance (rad) of any joint of (..., 7) ``joints`` from its limits.

        Joint by joint (the minimum is exact in any order): on the closed form's joint-major
        candidates each joint's values are contiguous, and the temporaries a seventh of the size.
        """
        margin = None
        for joint, lower, upper in zip(joints.unbind(-1), self.lower.tolist(), self.upper.tolist()):
            gap = torch.minimum(joint - lower, upper - joint)
            margin = gap if margin is None else torch.minimum(margin, gap, out=margin)
        return margin

    def solve(
        self,
        positions_world: torch.Tensor,
        rotations_world: torch.Tensor,
        seed_joints: torch.Tensor | None = None,
    ) -> IKResult:
        """Solve IK for N grasp-target poses at once.

        Args:
            positions_world: (N, 3) requested ``panda_grasptarget`` positions, world frame, metres.
            rotations_world: (N, 3, 3) requested orientations (grasp frame -> world).
            seed_joints: optional (N, 7) joints the solution of each target should stay near
                (replaces the reference posture).

        Returns:
            ``IKResult``; per target the closed-form solution inside the limits nearest in joint
            space to the preferred posture (``preferred_joints``), preferring those clear of the
            limits by ``limit_margin_rad``, over ``q7_samples`` values of joint 7
            (``q7_fine_samples`` for targets with none), judged by forward kinematics. A
            target without any solution keeps the preferred posture and its errors.
        """
        n_targets = positions_world.shape[0]
        if positions_world.shape != (n_targets, 3) or rotations_world.shape != (n_targets, 3, 3):
            raise ValueError(
                f"positions_world must be (N, 3) and rotations_world (N, 3, 3), got "
                f"{tuple(positions_world.shape)} and {tuple(rotations_world.shape)}"
            )
        if seed_joints is not None and seed_joints.shape != (n_targets, self.n_joints):
            raise ValueError(f"seed_joints must be ({n_targets}, {self.n_joints}), got {tuple(seed_joints.shape)}")
        if n_targets == 0:
            empty = torch.zeros(0, device=positions_world.device)
            return IKResult(torch.zeros(0, self.n_joints, device=positions_world.device), torch.zeros(0, dtype=torch.bool, device=positions_world.device),
                            empty, empty, empty)
        positions_base = positions_world.to(torch.float32) - self.base_xyz_world
        rotations = rotations_world.to(torch.float32)
        preferred = self.preferred_joints(positions_base, seed_joints)

        joints, found = self._nearest_on_grids(positions_base, rotations, preferred)
        joints = torch.where(found[:, None], joints.to(torch.float32), preferred)
        joints = torch.minimum(torch.maximum(joints, self.lower), self.upper)  # float32 rounding at a limit
        joints, position_error, rotation_error = self._judged_and_polished(joints, found, positions_base, rotations)
        inside_limits = ((joints >= self.lower) & (joints <= self.upper)).all(dim=1)
        success = self._within_tolerance(position_error, rotation_error) & inside_limits
        return IKResult(
            joints=joints,
            success=success,
            position_error_m=position_error,
            rotation_error_rad=rotation_error,
            s_reach=(1.0 + torch.cos(rotation_error)) / 2.0,
        )

    def _nearest_on_grids(
        self, positions_base: torch.Tensor, rotations: torch.Tensor, preferred: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(N, 7) float64 closed-form solution nearest to (N, 7) ``preferred`` per target, over the
        coarse joint-7 grid and, for targets with none there, the fine one; and (N,) bool: one exists."""
        n_targets = positions_base.shape[0]
        rotation_link7, position_link7 = self._link7_targets(positions_base, rotations)
        joints = torch.zeros(n_targets, self.n_joints, dtype=torch.float64, device=positions_base.device)
        found = torch.zeros(n_targets, dtype=torch.bool, device=positions_base.device)
        # Targets beyond the arm's reach at every joint-7 value have no solution on either grid.
        in_reach = wrist_in_reach(rotation_link7, position_link7, self.arm_geometry).nonzero().squeeze(1)
        if in_reach.numel():
            joints[in_reach], found[in_reach] = self._closed_form_nearest(
                rotation_link7[in_reach], position_link7[in_reach], self._q7_grid, preferred[in_reach]
            )
        missing = in_reach[~found[in_reach]]
        if missing.numel():
            # Some targets admit joint 7 only in a window narrower than the coarse grid's spacing.
            joints[missing], found[missing] = self._closed_form_nearest(
                rotation_link7[missing], position_link7[missing], self._q7_fine_grid, preferred[missing]
            )
        return joints, found

    def _judged_and_polished(
        self, joints: torch.Tensor, found: torch.Tensor, positions_base: torch.Tensor, rotations: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(N, 7) joints and their (N,) position and rotation errors, after ``polish_iterations``
        damped-least-squares steps for each ``found`` target whose closed-form answer misses the tolerance."""
        position_error, rotation_error = self._pose_errors(joints, positions_base, rotations)
        missed = found & ~self._within_tolerance(position_error, rotation_error)
        polish = missed.nonzero().squeeze(1)
        if polish.numel():
            joints[polish] = self._damped_least_squares(
                joints[polish], positions_base[polish], rotations[polish], self.config.polish_iterations
            )
            position_error[polish], rotation_error[polish] = self._pose_errors(joints[polish], positions_base[polish], rotations[polish])
        return joints, position_error, rotation_error

    def _within_tolerance(self, position_error: torch.Tensor, rotation_error: torch.Tensor) -> torch.Tensor:
        return (position_error < self.robot.ik_position_tolerance_m) & (rotation_error < self.robot.ik_rotation_tolerance_rad)

    def _pose_errors(
        self, joints: torch.Tensor, positions_base: torch.Tensor, rotations: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(M,) position (m) and rotation (rad) error of the forward kinematics of (M, 7) ``joints``
        against (M, 3) base-frame positions and (M, 3, 3) orientations."""
        return _errors_of_pose(self.frames.poses(joints)[-1], positions_base, rotations)

    def _damped_least_squares(
        self, joints: torch.Tensor, positions_base: torch.Tensor, rotations: torch.Tensor, iterations: int
    ) -> torch.Tensor:
        """(M, 7) joints after ``iterations`` damped-least-squares steps from (M, 7) ``joints`` toward
        (M, 3) base-frame positions and (M, 3, 3) orientations, clamped to the joint limits after every step."""
        damping = self._damping
        for _ in range(iterations):
            poses = self.frames.poses(joints)
            jacobian, pose = self.frames.jacobian(poses), poses[-1]
            error = torch.cat((positions_base - pose[:, 3].T, _rotation_error_vector(rotations, pose[:, :3].permute(2, 0, 1))), dim=1)
            step = jacobian.transpose(1, 2) @ torch.linalg.solve(jacobian @ jacobian.transpose(1, 2) + damping, error.unsqueeze(-1))
            joints = torch.minimum(torch.maximum(joints + step.squeeze(-1), self.lower), self.upper)
        return joints

    def waypoint_targets(self, start_joints: torch.Tensor, positions_world: torch.Tensor, rotations_world: torch.Tensor) -> WaypointTargets:
        """The W waypoints of each of N motions as N x W rows, motion by motion (``WaypointTargets``).

        Args:
            start_joints: (N, 7) joints of each motion's known pose (inside the limits).
            positions_world: (N, W, 3) ``panda_grasptarget`` waypoints, world frame, metres.
            rotations_world: (N, 3, 3) orientation held along each motion (grasp frame -> world).
        """
        n_motions, n_waypoints = positions_world.shape[:2]
        if start_joints.shape != (n_motions, self.n_joints) or rotations_world.shape != (n_motions, 3, 3):
            raise ValueError(
                f"start_joints must be (N, 7) and rotations_world (N, 3, 3) for positions_world (N, W, 3), got "
                f"{tuple(start_joints.shape)}, {tuple(rotations_world.shape)} and {tuple(positions_world.shape)}"
            )
        return WaypointTargets(
            start=start_joints.to(torch.float32).repeat_interleave(n_waypoints, dim=0),
            position_base=(positions_world.to(torch.float32) - self.base_xyz_world).reshape(-1, 3),
            rotation=rotations_world.to(torch.float32).repeat_interleave(n_waypoints, dim=0),
        )

    def held_joint7(self, targets: WaypointTargets) -> tuple[torch.Tensor, torch.Tensor]:
        """(R, 7) joints of each waypoint in closed form with joint 7 held at its start's value, of
        the (up to 8) solutions the one nearest in joint space to the start (the same IK branch),
        clamped to the limits; and (R,) bool: one exists (else the start's joints)."""
        start = targets.start
        rotation_link7, position_link7 = self._link7_targets(targets.position_base, targets.rotation)
        solutions = panda_ik_closed_form(rotation_link7, position_link7, start[:, 6:].double(), self.arm_geometry, self.lower, self.upper)
        branches, valid = solutions.joints[:, 0], solutions.valid[:, 0]  # (R, 8, 7), (R, 8)
        distance = _squared_distances(branches, start.double()).masked_fill(~valid, float("inf"))
        nearest = branches[torch.arange(len(branches), device=branches.device), distance.argmin(dim=1)].to(torch.float32)
        found = valid.any(dim=1)
        return torch.where(found[:, None], torch.minimum(torch.maximum(nearest, self.lower), self.upper), start), found

    def free_joints(self, targets: WaypointTargets) -> torch.Tensor:
        """(R, 7) joints of each waypoint after ``path_iterations`` damped-least-squares steps on the
        chain's geometric Jacobian from its start, which move every joint, 7 included, the least."""
        return self._damped_least_squares(targets.start, targets.position_base, targets.rotation, self.config.path_iterations)

    def judged(self, joints: torch.Tensor, targets: WaypointTargets, hulls: dict[str, torch.Tensor]) -> torch.Tensor:
        """(R, 10): (R, 7) ``joints`` of the waypoint ``targets``, then the position error (m) and the
        rotation error (rad) forward kinematics finds at them, then the world height (m) of the
        lowest vertex of ``hulls`` (link name -> (V, 3) vertices in its frame), from one pass.

        Fewer than 8 rows are judged padded to 8: MKL sums a GEMM of fewer than 4 rows in another
        order, and every row must round as it would among many."""
        n_rows = joints.shape[0]
        padded = torch.cat((joints, joints[:1].expand(max(0, 8 - n_rows), -1))) if 0 < n_rows < 8 else joints
        link_poses = self.frames.poses(padded)
        position_error, rotation_error = _errors_of_pose(link_poses[-1, ..., :n_rows], targets.position_base, targets.rotation)
        lowest = self._lowest_hull_z(link_poses, hulls)[:n_rows]
        return torch.cat((joints, position_error[:, None], rotation_error[:, None], lowest[:, None]), dim=1)


@functools.lru_cache(maxsize=4)
def _cached_ik(ik_values: tuple, robot: RobotDescription) -> PandaIK:
    return PandaIK(IKConfig(*ik_values), robot)


def panda_ik(config: Config) -> PandaIK:
    """The ``PandaIK`` of this configuration, built once per distinct ``[ik]`` settings and robot
    and shared by planning and execution."""
    return _cached_ik(astuple(config.ik), robot_of(config))


def _squared_distances(candidates: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """(M, C) squared joint-space distances of (M, C, 7) ``candidates`` from (M, 7) ``reference``.

    The differences are summed from a contiguous (M, C, 7) tensor whatever ``candidates``' own
    layout (the closed form's is joint-major): torch's sum of a row of 7 is no left-to-right sum,
    and a sum over another layout takes another order, so could round differently.
    """
    offsets = torch.empty(candidates.shape, dtype=candidates.dtype, device=candidates.device)
    torch.sub(candidates, reference[:, None], out=offsets)
    return offsets.square_().sum(dim=-1)


def _errors_of_pose(pose: torch.Tensor, positions_base: torch.Tensor, rotations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(M,) position (m) and rotation (rad) error of (3, 4, M) reached poses (a frame of
    ``ChainFrames.poses``) against (M, 3) positions and (M, 3, 3) orientations, all in the base frame."""
    position_error = (positions_base - pose[:, 3].T).norm(dim=1)
    rotation_error = _rotation_error_vector(rotations, pose[:, :3].permute(2, 0, 1)).norm(dim=1)
    return position_error, rotation_error


# (4, 3) signs of m00, m11 and m22 in the four squared quaternion components of a rotation matrix.
_QUATERNION_DIAGONAL_SIGNS = torch.tensor([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])


def _rotation_error_vector(target: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
    """(M, 3) rotation vector (axis x angle, base frame) turning ``current`` into ``target``, both (M, 3, 3).

    ``pk.matrix_to_axis_angle``'s value bit for bit, at a third fewer tensor operations (which
    are what these small calls cost): where the quaternion's real part is its largest component
    (turns under 90 degrees, every IK error but gross ones) its own arithmetic for that
    component alone, without the three other candidate quaternions it builds and picks from;
    its function itself for the other rows.
    """
    matrix = target @ current.transpose(1, 2)
    _, m01, m02, m10, _, m12, m20, m21, _ = matrix.reshape(-1, 9).unbind(dim=1)
    # pk's 1 +- m00 +- m11 +- m22 for all four components in one pass (each (M, 4), signed per
    # component): x - y is x + (-y) exactly.
    signs = _QUATERNION_DIAGONAL_SIGNS.to(matrix.device)
    signed00, signed11, signed22 = (matrix.diagonal(dim1=1, dim2=2)[:, None, :] * signs).unbind(dim=2)
    q_abs = (1.0 + signed00 + signed11 + signed22).clamp(min=0.0).sqrt()
    quaternion = torch.stack((q_abs[:, 0] ** 2, m21 - m12, m02 - m20, m10 - m01), dim=-1) / (2.0 * q_abs[:, :1].clamp(min=0.1))
    vector = pk.quaternion_to_axis_angle(quaternion)
    others = (q_abs.argmax(dim=-1) != 0).nonzero().squeeze(1)
    if others.numel():
        vector[others] = pk.matrix_to_axis_angle(matrix[others])
    return vector
