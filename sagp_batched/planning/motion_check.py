"""The motion check: whether grasps can be executed as planned, along the motion execution runs."""
from __future__ import annotations

import functools
from dataclasses import dataclass

import torch

from ..config import Config
from ..description_files import link_hulls
from ..robot.description import RobotDescription, robot_of
from ..robot.ik import PandaIK, panda_ik
from ..robot.motion import grasp_waypoint_index, motion_waypoints, waypoint_count
from .stages import StageClock


@dataclass
class MotionCheck:
    """Whether R (candidate, approach) grasps can be executed as planned, with their joint paths."""

    STAGES = ("grasp_ik", "motion")  # the check that rejected a grasp, in the order they run

    feasible: torch.Tensor  # (R,) bool: grasp pose and whole motion reachable on one IK branch
    joint_path: torch.Tensor  # (R, W, J) joints at every waypoint of ``motion_waypoints`` (zeros where infeasible)
    s_reach: torch.Tensor  # (R,) IK margin of the grasp pose
    rejected_by: torch.Tensor  # (R, 2) int64 one-hot over ``STAGES``: the check that rejected it


def check_motions(
    centre: torch.Tensor, approach: torch.Tensor, rotation: torch.Tensor, ik: PandaIK, config: Config, clock: StageClock | None = None
) -> MotionCheck:
    """The reachability checks execution's motion has to pass for R grasps at (R, 3) ``centre``
    with (R, 3) ``approach`` directions and (R, 3, 3) grasp frames ``rotation`` (world frame):
    the second check on the survivors of the first, timed on ``clock`` (stages ``ik`` and
    ``motion``, their items the grasp poses and the waypoints solved) if given.

    1. The grasp pose is reachable (IK within tolerance and S_reach over its floor): execution
       sends the requested pose, so the reached orientation must match it.
    2. Every waypoint of the motion (pre-grasp, descent, lift) is reachable from the grasp
       solution on its IK branch: within tolerance, inside the limits, and no joint moving more
       than ``max_waypoint_joint_step_rad`` between neighbouring waypoints; and at every
       waypoint the arm's links (their URDF collision hulls placed by forward kinematics) stay
       ``arm_table_clearance_m`` above the table.
    """
    clock = StageClock() if clock is None else clock
    n_rows = centre.shape[0]
    waypoints = motion_waypoints(centre, approach, config.motion)
    ik = ik.on(centre.device)
    joint_path = torch.zeros(n_rows, waypoints.shape[1], len(ik.robot.arm_joints), device=centre.device)
    s_reach = torch.zeros(n_rows, device=centre.device)
    rejected_by = torch.zeros(n_rows, len(MotionCheck.STAGES), dtype=torch.int64, device=centre.device)
    with clock.stage("ik", n_rows):
        grasp = ik.solve(centre, rotation)
        reached = grasp.success & (grasp.s_reach >= config.planner.min_reach)
        rejected_by[~reached, 0] = 1
        candidates, grasp_joints = reached.nonzero().squeeze(1), grasp.joints[reached]
        s_reach[candidates] = grasp.s_reach[reached]
    with clock.stage("motion", candidates.numel() * (waypoints.shape[1] - 1)):
        joints, motion_ok = _followed_motion(ik, grasp_joints, waypoints[candidates], rotation[candidates], config)
        rejected_by[candidates[~motion_ok], 1] = 1
        joint_path[candidates[motion_ok]] = joints[motion_ok]
        feasible = torch.zeros(n_rows, dtype=torch.bool, device=centre.device)
        feasible[candidates[motion_ok]] = True
    return MotionCheck(feasible=feasible, joint_path=joint_path, s_reach=s_reach, rejected_by=rejected_by)


def motion_checker(config: Config, clock: StageClock | None = None):
    """``check(centre, approach, rotation) -> MotionCheck`` for the configured gripper: ``check_motions`` with the
    arm's IK where the robot carries the gripper; where no arm carries it (a gripper planned and labelled in
    hand mode) there is no arm to check, so every grasp passes with no joint path and S_reach 1."""
    robot = robot_of(config)
    if robot.gripper_mounted:
        ik = panda_ik(config)
        return lambda centre, approach, rotation: check_motions(centre, approach, rotation, ik, config, clock)

    def unchecked(centre: torch.Tensor, approach: torch.Tensor, rotation: torch.Tensor) -> MotionCheck:
        n_rows = centre.shape[0]
        return MotionCheck(
            feasible=torch.ones(n_rows, dtype=torch.bool, device=centre.device),
            joint_path=torch.zeros(n_rows, waypoint_count(config.motion), robot.n_arm_joints, device=centre.device),
            s_reach=torch.ones(n_rows, device=centre.device),
            rejected_by=torch.zeros(n_rows, len(MotionCheck.STAGES), dtype=torch.int64, device=centre.device),
        )

    return unchecked


def _followed_motion(
    ik: PandaIK, grasp_joints: torch.Tensor, waypoints: torch.Tensor, rotation: torch.Tensor, config: Config
) -> tuple[torch.Tensor, torch.Tensor]:
    """(M, W, J) joints along M motions through (M, W, 3) ``waypoints`` from their (M, J) grasp
    solutions, holding (M, 3, 3) ``rotation``, and (M,) bool whether each passes every check of
    ``_motion_checks``.

    Joint 7 is held at the grasp's value first (closed form). Motions that reach every waypoint
    that way but fail a step or the table, mostly near the shoulder singularity where holding
    joint 7 swings joints 1 and 3, are followed again with every joint free to move
    (``PandaIK.free_joints`` from the grasp joints); a waypoint out of reach at the held value
    takes that free answer in the held motion too. A waypoint's answer depends on it alone, so
    the free answers of every motion that may need them are one batch; the arm at the grasp
    itself is placed once."""
    grasp_index, hulls = grasp_waypoint_index(config.motion), _arm_hulls(ik.robot, waypoints.device)
    others = torch.arange(waypoints.shape[1], device=waypoints.device) != grasp_index
    n_others = int(others.sum())
    grasp_lowest_z = ik.lowest_link_point_z(grasp_joints, hulls)
    targets = ik.waypoint_targets(grasp_joints, waypoints[:, others], rotation)
    held, found = ik.held_joint7(targets)
    held = ik.judged(held, targets, hulls)
    free = torch.full_like(held, float("nan"))  # rows filled where a free answer is needed

    def checks(path: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return _motion_checks(path.view(-1, n_others, path.shape[1]), others, grasp_joints, grasp_lowest_z, ik.robot, config)

    complete = found.view(-1, n_others).all(dim=1)
    _, reached, ok = checks(held)
    # Free answers for every waypoint of the motions followed again and of those the held closed
    # form left incomplete (which it may yet send round again): one batch, never a second.
    rows = (~complete | (reached & ~ok)).repeat_interleave(n_others).nonzero().squeeze(1)
    if rows.numel():
        free[rows] = ik.judged(ik.free_joints(targets.rows(rows)), targets.rows(rows), hulls)
    held[~found] = free[~found]
    joints, reached, ok = checks(held)
    retry = reached & ~ok
    free_joints, _, free_ok = checks(free)
    return torch.where(retry[:, None, None], free_joints, joints), torch.where(retry, free_ok, ok)


def _motion_checks(
    path: torch.Tensor, others: torch.Tensor, grasp_joints: torch.Tensor, grasp_lowest_z: torch.Tensor, robot: RobotDescription,
    config: Config,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(M, W, J) joints along M motions whose waypoints but the grasp (``others`` (W,) bool) are
    (M, W - 1, 10) ``path`` rows (``PandaIK.judged``) and whose grasp is (M, J) ``grasp_joints``
    (the arm's lowest point there (M,) ``grasp_lowest_z``); (M,) bool whether every waypoint is
    within ``robot``'s IK tolerances; and (M,) bool whether each motion passes all of execution's checks:
    those tolerances, no joint moving more than ``max_waypoint_joint_step_rad`` between waypoints,
    and the arm's links clear of the table. NaN rows (no answer) pass none."""
    n_joints = grasp_joints.shape[1]
    joints = torch.zeros(path.shape[0], others.shape[0], n_joints, device=path.device)
    joints[:, others], joints[:, ~others] = path[..., :n_joints], grasp_joints[:, None]
    steps = (joints[:, 1:] - joints[:, :-1]).abs().amax(dim=(1, 2))
    arm_lowest_z = torch.minimum(path[..., n_joints + 2].amin(dim=1), grasp_lowest_z)
    reached_all = (path[..., n_joints] < robot.ik_position_tolerance_m).all(dim=1) & (
        path[..., n_joints + 1] < robot.ik_rotation_tolerance_rad
    ).all(dim=1)
    ok = (
        reached_all
        & (steps <= config.motion.max_waypoint_joint_step_rad)
        & (arm_lowest_z >= config.scene.table_top_z_m + config.planner.arm_table_clearance_m)
    )
    return joints, reached_all, ok


@functools.lru_cache(maxsize=8)
def _arm_hulls(robot: RobotDescription, device: torch.device) -> dict[str, torch.Tensor]:
    """Hull vertices of the links checked against the table, in their link frames, on ``device`` (built once per robot and device)."""
    hulls = link_hulls(robot.urdf_path, robot.table_check_links)
    return {name: torch.tensor(vertices, dtype=torch.float32, device=device) for name, vertices in hulls.items()}
