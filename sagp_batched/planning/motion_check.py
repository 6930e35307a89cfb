"""The motion check: whether grasps can be executed as planned, along the motion execution runs."""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import torch

from ..config import Config
from ..robot.description import RobotDescription
from ..robot.hand import link_hulls
from ..robot.ik import PandaIK
from ..robot.motion import grasp_waypoint_index, motion_waypoints


@dataclass
class MotionCheck:
    """Whether R (candidate, approach) grasps can be executed as planned, with their joint paths."""

    STAGES = ("grasp_ik", "motion")  # the check that rejected a grasp, in the order they run

    feasible: torch.Tensor  # (R,) bool: grasp pose and whole motion reachable on one IK branch
    joint_path: torch.Tensor  # (R, W, J) joints at every waypoint of ``motion_waypoints`` (zeros where infeasible)
    s_reach: torch.Tensor  # (R,) IK margin of the grasp pose
    rejected_by: torch.Tensor  # (R, 2) int64 one-hot over ``STAGES``: the check that rejected it
    ik_targets: int  # grasp poses and waypoints handed to IK
    ik_s: float  # seconds solving the grasp poses
    motion_s: float  # seconds following and checking the motions


def check_motions(centre: torch.Tensor, approach: torch.Tensor, rotation: torch.Tensor, ik: PandaIK, config: Config) -> MotionCheck:
    """The reachability checks execution's motion has to pass for R grasps at (R, 3) ``centre``
    with (R, 3) ``approach`` directions and (R, 3, 3) grasp frames ``rotation`` (world frame):
    the second check on the survivors of the first.

    1. The grasp pose is reachable (IK within tolerance and S_reach over its floor): execution
       sends the requested pose, so the reached orientation must match it.
    2. Every waypoint of the motion (pre-grasp, descent, lift) is reachable from the grasp
       solution on its IK branch: within tolerance, inside the limits, and no joint moving more
       than ``max_waypoint_joint_step_rad`` between neighbouring waypoints; and at every
       waypoint the arm's links (their URDF collision hulls placed by forward kinematics) stay
       ``arm_table_clearance_m`` above the table.
    """
    clock = time.perf_counter()
    planner, motion = config.planner, config.motion
    n_rows = centre.shape[0]
    waypoints = motion_waypoints(centre, approach, motion)
    grasp_index = grasp_waypoint_index(motion)
    joint_path = torch.zeros(n_rows, waypoints.shape[1], len(ik.robot.arm_joints))
    s_reach = torch.zeros(n_rows)
    rejected_by = torch.zeros(n_rows, len(MotionCheck.STAGES), dtype=torch.int64)

    grasp = ik.solve(centre, rotation)
    reached = grasp.success & (grasp.s_reach >= planner.min_reach)
    rejected_by[~reached, 0] = 1
    candidates, grasp_joints = reached.nonzero().squeeze(1), grasp.joints[reached]
    s_reach[candidates] = grasp.s_reach[reached]
    solved_at = time.perf_counter()

    others = torch.arange(waypoints.shape[1]) != grasp_index
    # Joint 7 held at the grasp's value first (closed form). Motions that reach every waypoint
    # that way but fail a step or the table, mostly near the shoulder singularity where holding
    # joint 7 swings joints 1 and 3, are followed again with every joint free to move; a waypoint
    # out of reach at the held value was already given that chance inside ``follow``.
    # The arm at the grasp itself is placed once: a retried motion keeps its grasp joints.
    grasp_lowest_z = ik.lowest_link_point_z(grasp_joints, _arm_hulls(ik.robot))
    joints, reached_all, motion_ok = _checked_motion(
        ik, grasp_joints, grasp_lowest_z, waypoints[candidates], rotation[candidates], grasp_index, config, hold_joint7=True
    )
    retry = (reached_all & ~motion_ok).nonzero().squeeze(1)
    if retry.numel():
        joints[retry], _, motion_ok[retry] = _checked_motion(
            ik, grasp_joints[retry], grasp_lowest_z[retry], waypoints[candidates[retry]], rotation[candidates[retry]], grasp_index, config,
            hold_joint7=False,
        )
    rejected_by[candidates[~motion_ok], 1] = 1
    joint_path[candidates[motion_ok]] = joints[motion_ok]
    feasible = torch.zeros(n_rows, dtype=torch.bool)
    feasible[candidates[motion_ok]] = True
    return MotionCheck(
        feasible=feasible,
        joint_path=joint_path,
        s_reach=s_reach,
        rejected_by=rejected_by,
        ik_targets=n_rows + int(candidates.numel()) * int(others.sum()),
        ik_s=solved_at - clock,
        motion_s=time.perf_counter() - solved_at,
    )


def _checked_motion(
    ik: PandaIK,
    grasp_joints: torch.Tensor,
    grasp_lowest_z: torch.Tensor,
    waypoints: torch.Tensor,
    rotation: torch.Tensor,
    grasp_index: int,
    config: Config,
    hold_joint7: bool,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(M, W, J) joints along M motions through (M, W, 3) ``waypoints`` from their grasp solutions
    (M, J) at waypoint ``grasp_index`` (where the arm's lowest point is (M,) ``grasp_lowest_z``,
    ``PandaIK.lowest_link_point_z``), holding (M, 3, 3) ``rotation``; (M,) bool whether every
    waypoint is within the IK tolerances; and (M,) bool whether each motion passes all of
    execution's checks: those tolerances, no joint moving more than ``max_waypoint_joint_step_rad``
    between waypoints, and the arm's links clear of the table."""
    planner = config.planner
    others = torch.arange(waypoints.shape[1]) != grasp_index
    hulls = _arm_hulls(ik.robot)
    path = ik.follow(grasp_joints, waypoints[:, others], rotation, hold_joint7=hold_joint7, hulls=hulls)
    joints = torch.zeros(grasp_joints.shape[0], waypoints.shape[1], grasp_joints.shape[1])
    joints[:, others], joints[:, grasp_index] = path.joints, grasp_joints
    steps = (joints[:, 1:] - joints[:, :-1]).abs().amax(dim=(1, 2))
    arm_lowest_z = torch.minimum(path.lowest_link_z_m.amin(dim=1), grasp_lowest_z)
    reached_all = (path.position_error_m < ik.robot.ik_position_tolerance_m).all(dim=1) & (
        path.rotation_error_rad < ik.robot.ik_rotation_tolerance_rad
    ).all(dim=1)
    ok = (
        reached_all
        & (steps <= config.motion.max_waypoint_joint_step_rad)
        & (arm_lowest_z >= config.scene.table_top_z_m + planner.arm_table_clearance_m)
    )
    return joints, reached_all, ok


@functools.lru_cache(maxsize=4)
def _arm_hulls(robot: RobotDescription) -> dict[str, torch.Tensor]:
    """Hull vertices of the links checked against the table, in their link frames (built once per robot)."""
    return {name: torch.tensor(vertices, dtype=torch.float32) for name, vertices in link_hulls(robot.urdf_path, robot.table_check_links).items()}
