"""Batched antipodal grasp planner: sampled pairs -> antipodal filter -> approaches and gripper
collision proxies -> IK reachability, ranked by S_geom.

Every stage is a tensor kernel over all candidates (and, in ``plan_batch``, over all objects at
once). Choosing each candidate's approach "by IK feasibility" is done in rounds so that IK runs
only where it can change the answer: approaches are ordered by a top-down-first prior, and each
round applies the motion check of the next untried approach of every undecided candidate that
could still enter its object's top ``max_candidates``. Checks are computed ahead of the rounds
in batches (``_MotionVerdicts``), as the screens are (``_ScreenVerdicts``); results are applied
only when a round reaches them. The result equals trying candidates one by one in S_geom order,
each approach in prior order, until ``max_candidates`` are feasible (which is what
``reference.plan_reference`` does).
"""
from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.grasp_frames import approach_directions, grasp_rotations
from sagp_batched_kernels.gripper_volume import GripperGeometry, gripper_occupancy_within, table_cover, table_penetration
from sagp_batched_kernels.hand_clearance import HandClearance, hand_clearance
from sagp_batched_kernels.sampling import (
    sample_guided_pair_indices,
    sample_pair_indices,
    sample_subset_indices,
    voxel_representatives,
)

from .config import Config, PlannerConfig
from .hand import DOP_DIRECTIONS, HandGeometry, link_hulls, load_hand_geometry
from .ik import PandaIK, panda_ik
from .motion import grasp_waypoint_index, motion_waypoints, waypoint_count
from .robot import PANDA
from .types import GraspCandidates, PerceivedCloud

# Approach 0 of every closing axis is the one closest to straight down: top-down grasps clear
# the table and the arm most often, so they are the prior's first choice.
WORLD_DOWN = torch.tensor([0.0, 0.0, -1.0])

UNDECIDED, FEASIBLE, EXHAUSTED = 0, 1, 2


def gripper_geometry(config: PlannerConfig) -> GripperGeometry:
    return GripperGeometry(
        open_width_m=PANDA.open_width_m,
        finger_width_m=config.finger_width_m,
        finger_thickness_m=config.finger_thickness_m,
        finger_length_m=config.finger_length_m,
        fingertip_offset_m=config.fingertip_offset_m,
        palm_width_m=config.palm_width_m,
        palm_span_m=config.palm_span_m,
        palm_depth_m=config.palm_depth_m,
        contact_clearance_m=config.contact_clearance_m,
    )


def hand_geometry(config: PlannerConfig) -> HandGeometry:
    """The open Panda hand's collision hulls, derived from the robot's URDF."""
    return load_hand_geometry(PANDA.urdf_path, PANDA.open_width_m)


def _check_cloud(cloud: PerceivedCloud, position: int) -> None:
    points, normals = cloud.points_world, cloud.normals_world
    if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape:
        raise ValueError(
            f"cloud {position} ({cloud.object_id}): points_world and normals_world must both be (N, 3), "
            f"got {tuple(points.shape)} and {tuple(normals.shape)}"
        )
    if points.shape[0] < 2:
        raise ValueError(f"cloud {position} ({cloud.object_id}) has {points.shape[0]} points; planning needs at least 2")
    if cloud.obstacle_points_world.ndim != 2 or cloud.obstacle_points_world.shape[1] != 3:
        raise ValueError(f"cloud {position} ({cloud.object_id}): obstacle_points_world must be (M, 3)")


@dataclass
class SampledInputs:
    """The random draws of one planning call for one cloud (identical for every method)."""

    pair_indices: torch.Tensor  # (P, 2) int64 indices into the cloud's points
    occupancy_points: torch.Tensor  # (M, 3) object points then obstacle points the occupancy check counts
    occupancy_total: int  # object points in ``occupancy_points``: the occupancy fraction's denominator
    hand_check_points: torch.Tensor  # (H, 3) object then obstacle points the swept-hand check tests
    hand_screen_points: torch.Tensor  # (S, 3) a coarser subset of them, probed first


def sample_inputs(cloud: PerceivedCloud, planner: PlannerConfig, seed: int) -> SampledInputs:
    """Draw the contact pairs and the occupancy subset of ``cloud`` from one generator seeded by ``seed``."""
    generator = torch.Generator().manual_seed(int(seed))
    if planner.pair_sampling == "guided":
        # Proposals wider than the open jaws can descend around pass the width filter but are
        # never usable, so the guided sampler's reach is the narrower of the two limits.
        pair_indices = sample_guided_pair_indices(
            cloud.points_world.to(torch.float32),
            cloud.normals_world.to(torch.float32),
            planner.n_pairs,
            planner.pair_proposals,
            planner.min_width_m,
            min(planner.max_width_m, jaw_width_limit(planner)),
            generator,
            planner.pair_proposal_chunk_elements,
        )
    else:
        pair_indices = sample_pair_indices(cloud.n_points, planner.n_pairs, generator)
    object_subset = sample_subset_indices(cloud.n_points, planner.occupancy_max_points, generator)
    n_obstacles = cloud.obstacle_points_world.shape[0]
    n_obstacles_kept = round(n_obstacles * len(object_subset) / cloud.n_points)
    obstacle_subset = sample_subset_indices(n_obstacles, n_obstacles_kept, generator)
    occupancy_points = torch.cat(
        (
            cloud.points_world.to(torch.float32)[object_subset],
            cloud.obstacle_points_world.to(torch.float32)[obstacle_subset],
        )
    )
    scene_points = torch.cat((cloud.points_world.to(torch.float32), cloud.obstacle_points_world.to(torch.float32)))
    hand_check_points = scene_points[voxel_representatives(scene_points, planner.hand_check_voxel_m)]
    hand_screen_points = hand_check_points[voxel_representatives(hand_check_points, planner.hand_screen_voxel_m)]
    return SampledInputs(pair_indices, occupancy_points, len(object_subset), hand_check_points, hand_screen_points)


def _segment_exclusive_cumsum(values: torch.Tensor, object_index: torch.Tensor, n_objects: int) -> torch.Tensor:
    """Exclusive running sum of ``values`` restarting at each object (rows sorted by object)."""
    exclusive = torch.cumsum(values, 0) - values
    first_row = torch.searchsorted(object_index, torch.arange(n_objects))
    base = torch.zeros(n_objects, dtype=values.dtype)
    has_rows = first_row < object_index.shape[0]
    base[has_rows] = exclusive[first_row[has_rows]]
    return exclusive - base[object_index]


@dataclass
class ScreenedCandidates:
    """Antipodal candidates of several clouds before IK, ranked by S_geom within each cloud.

    Rows are sorted by cloud, then S_geom descending (sampling order among ties); approaches are
    in prior order (most downward first).
    """

    object_index: torch.Tensor  # (A,) int64 cloud of each candidate
    pair_indices: torch.Tensor  # (A, 2) int64 point indices within its cloud
    contacts_world: torch.Tensor  # (A, 2, 3)
    centre_world: torch.Tensor  # (A, 3) contact midpoints, the grasp centres
    closing_axis: torch.Tensor  # (A, 3)
    width_m: torch.Tensor  # (A,)
    s_geom: torch.Tensor  # (A,)
    # (A, K, 3) approaches and (A, K, 3, 3) grasp frames, written for a candidate the first time
    # ``frames`` is asked for it (unwritten rows are uninitialised memory, never read)
    approach_buffer: torch.Tensor
    rotation_buffer: torch.Tensor
    framed: torch.Tensor  # (A,) bool: the candidate's rows of the buffers are written
    occupancy_points: torch.Tensor  # (B, M, 3) per-cloud occupancy subsets (object then obstacles), NaN-padded
    occupancy_total: torch.Tensor  # (B,) object points of each subset: the occupancy fractions' denominator
    hand_check_points: torch.Tensor  # (B, H, 3) per-cloud points for the swept-hand check, NaN-padded
    hand_screen_points: torch.Tensor  # (B, S, 3) their coarse subsets, NaN-padded
    planner: PlannerConfig
    pregrasp_offset_m: float
    table_top_z_m: float

    @property
    def n_candidates(self) -> int:
        return self.width_m.shape[0]

    @property
    def n_objects(self) -> int:
        return self.occupancy_points.shape[0]

    def frames(self, rows: torch.Tensor, slots: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Approach directions (R, K, 3), in prior order, and grasp frames (R, K, 3, 3) of candidates
        ``rows``; with ``slots`` (R,), only those approaches: (R, 3) and (R, 3, 3).

        Computed the first time a candidate is asked for: at 500,000 pairs a plan reaches a few
        hundred of a soup can's 416,000 candidates, and framing every one took ~0.3 s and 160 MB. A
        candidate's frames do not depend on which others are framed with it.
        """
        new = rows[~self.framed[rows]]
        if new.numel():
            new = new.unique()  # a candidate may be asked for once per approach
            closing_axis = self.closing_axis[new]
            approach = approach_directions(closing_axis, self.planner.n_approaches, WORLD_DOWN)
            self.approach_buffer[new] = approach
            self.rotation_buffer[new] = grasp_rotations(closing_axis[:, None, :], approach)
            self.framed[new] = True
        if slots is None:
            return self.approach_buffer[rows], self.rotation_buffer[rows]
        return self.approach_buffer[rows, slots], self.rotation_buffer[rows, slots]

    @property
    def approach(self) -> torch.Tensor:
        """(A, K, 3) every candidate's approaches (framing all of them; for references and tests)."""
        return self.frames(torch.arange(self.n_candidates))[0]

    @property
    def rotation_world(self) -> torch.Tensor:
        """(A, K, 3, 3) every candidate's grasp frames (framing all of them; for references and tests)."""
        return self.frames(torch.arange(self.n_candidates))[1]

    def clear_of_table(self, rows: torch.Tensor, rotation: torch.Tensor | None = None) -> torch.Tensor:
        """(R, K) bool: the hand of candidates ``rows`` stays above the table at the grasp and the
        pre-grasp (fingers and the rest by their own clearances), and the jaws fit the width.
        ``rotation``: their (R, K, 3, 3) frames, where the caller has them (default: ``frames``).

        Computed on demand: ``plan_batch`` needs it only for the candidates its window reaches.
        """
        planner = self.planner
        (fingers, fingers_cover), (rest, rest_cover) = _table_check_points(hand_geometry(planner))
        centre = self.centre_world[rows]
        rotation = self.frames(rows)[1] if rotation is None else rotation
        through_table = table_penetration(
            centre, rotation, fingers, self.pregrasp_offset_m, self.table_top_z_m + planner.finger_table_clearance_m, fingers_cover
        ) | table_penetration(centre, rotation, rest, self.pregrasp_offset_m, self.table_top_z_m + planner.arm_table_clearance_m, rest_cover)
        return ~through_table & (self.width_m[rows] <= jaw_width_limit(planner))[:, None]

    def table_and_volume_ok(self, rows: torch.Tensor) -> torch.Tensor:
        """(R, K) bool: candidates ``rows`` clear the table and their gripper volumes are under the
        published 12 % limit. Volumes are counted only for the poses that clear the table.

        ``plan_batch`` runs it only on candidates that can still enter the kept set, in S_geom order.
        """
        # Gathered once for both checks: a second frames() call cost ~40 ms of a 500,000-pair mug plan.
        rotation = self.frames(rows)[1]
        return self.volume_within(rows, rotation, self.clear_of_table(rows, rotation))

    def volume_within(self, rows: torch.Tensor, rotation: torch.Tensor, poses: torch.Tensor) -> torch.Tensor:
        """(R, K) bool: the gripper volumes of candidates ``rows`` in frames ``rotation`` (R, K, 3, 3) hold at
        most ``occupancy_max_fraction`` of their cloud's points; counted only where ``poses`` (R, K) is True."""
        planner = self.planner
        return gripper_occupancy_within(
            self.occupancy_points, self.object_index[rows], self.centre_world[rows], rotation,
            self.width_m[rows], gripper_geometry(planner), planner.occupancy_max_fraction * self.occupancy_total[self.object_index[rows]],
            planner.occupancy_chunk_elements, poses,
        )

    def hand_clearance(self, rows: torch.Tensor, slots: torch.Tensor) -> HandClearance:
        """Whether the real hand (its collision hulls) swept along the descent of candidates ``rows``
        with approaches ``slots`` comes within the margin of the scene's object and obstacle points,
        and its clearance from them (exact where not blocked). The coarse subset is probed first:
        most blocked grasps (a mug's) strike one of its points."""
        low, high = hand_geometry(self.planner).swept((0.0, 0.0, -self.pregrasp_offset_m))
        return hand_clearance(
            self.hand_check_points, self.hand_screen_points, self.object_index[rows], self.centre_world[rows], self.frames(rows, slots)[1],
            DOP_DIRECTIONS, low, high, self.planner.hand_clearance_margin_m, self.planner.hand_check_chunk_elements,
        )

    @property
    def usable(self) -> torch.Tensor:
        """(A, K) bool: the published screen (table, 12 % volume) on every candidate, eagerly (for
        references and benchmarks); ``plan_batch`` adds the swept hand and the motion."""
        return self.table_and_volume_ok(torch.arange(self.n_candidates))


def screen_candidates(
    clouds: Sequence[PerceivedCloud], config: Config, seeds: Sequence[int], stage_time: dict[str, float] | None = None
) -> ScreenedCandidates:
    """Sampling, antipodal filter, approaches and gripper collision proxies for all clouds at once.

    ``stage_time``, if given, receives seconds for ``sampling``, ``antipodal`` and ``frames_volume``.
    """
    planner = config.planner
    stage_time = {} if stage_time is None else stage_time
    clock = time.perf_counter()
    n_objects = len(clouds)
    sampled = [sample_inputs(cloud, planner, seed) for cloud, seed in zip(clouds, seeds)]
    point_offsets = torch.tensor([0] + [cloud.n_points for cloud in clouds]).cumsum(0)[:-1]
    pairs = torch.cat([s.pair_indices + offset for s, offset in zip(sampled, point_offsets)])
    pair_object = torch.arange(n_objects).repeat_interleave(planner.n_pairs)
    points = torch.cat([cloud.points_world.to(torch.float32) for cloud in clouds])
    normals = torch.cat([cloud.normals_world.to(torch.float32) for cloud in clouds])
    now = time.perf_counter()
    stage_time["sampling"], clock = now - clock, now

    pair_eval = antipodal_pairs(points, normals, pairs, planner.min_width_m, planner.max_width_m, planner.max_contact_angle_deg)
    antipodal = pair_eval["antipodal"].nonzero().squeeze(1)
    # Rank by S_geom within each object; stable sorts keep sampling order among ties.
    antipodal = antipodal[torch.sort(pair_eval["s_geom"][antipodal], descending=True, stable=True).indices]
    if n_objects > 1:  # one object's candidates are already grouped (a 35 ms sort at 500,000 pairs)
        antipodal = antipodal[torch.sort(pair_object[antipodal], stable=True).indices]
    candidate_object = pair_object[antipodal]
    closing_axis = pair_eval["closing_axis"][antipodal]
    width = pair_eval["width_m"][antipodal]
    contacts = points[pairs[antipodal]]  # (A, 2, 3)
    now = time.perf_counter()
    stage_time["antipodal"], clock = now - clock, now

    n_candidates = antipodal.numel()
    stage_time["frames_volume"] = time.perf_counter() - clock
    return ScreenedCandidates(
        object_index=candidate_object,
        pair_indices=pairs[antipodal] - point_offsets[candidate_object, None],
        contacts_world=contacts,
        # Once, not per block of candidates: at 500,000 pairs the mean over every candidate cost
        # more than the blocks' screens.
        centre_world=contacts.mean(dim=1),
        closing_axis=closing_axis,
        width_m=width,
        s_geom=pair_eval["s_geom"][antipodal],
        approach_buffer=torch.empty(n_candidates, planner.n_approaches, 3),
        rotation_buffer=torch.empty(n_candidates, planner.n_approaches, 3, 3),
        framed=torch.zeros(n_candidates, dtype=torch.bool),
        occupancy_points=_padded([s.occupancy_points for s in sampled]),
        occupancy_total=torch.tensor([s.occupancy_total for s in sampled], dtype=torch.float32),
        hand_check_points=_padded([s.hand_check_points for s in sampled]),
        hand_screen_points=_padded([s.hand_screen_points for s in sampled]),
        planner=planner,
        pregrasp_offset_m=config.execution.pregrasp_offset_m,
        table_top_z_m=config.scene.table_top_z_m,
    )


@functools.lru_cache(maxsize=4)
def _arm_hulls_of(links: tuple[str, ...]) -> dict[str, torch.Tensor]:
    return {name: torch.tensor(vertices, dtype=torch.float32) for name, vertices in link_hulls(PANDA.urdf_path, links).items()}


def _arm_hulls(planner: PlannerConfig) -> dict[str, torch.Tensor]:
    """Hull vertices of the links checked against the table, in their link frames (built once per link set)."""
    return _arm_hulls_of(tuple(planner.arm_table_links))


@functools.lru_cache(maxsize=4)
def _table_check_points(hand: HandGeometry) -> tuple[tuple[torch.Tensor, tuple[torch.Tensor, float]], ...]:
    """The fingers' and the other links' hull vertices (grasp frame) the table check tests, each
    with its ``table_cover``: built once per hand, not on every block of candidates."""
    fingers = hand.vertices(PANDA.finger_links)
    rest = hand.vertices(tuple(name for name in hand.links if name not in PANDA.finger_links))
    return (fingers, table_cover(fingers)), (rest, table_cover(rest))


def _padded(point_sets: list[torch.Tensor]) -> torch.Tensor:
    """(B, max N, 3) the point sets stacked, shorter ones padded with NaN rows (never inside anything)."""
    padded = torch.full((len(point_sets), max(len(points) for points in point_sets), 3), float("nan"))
    for index, points in enumerate(point_sets):
        padded[index, : len(points)] = points
    return padded


def jaw_width_limit(planner) -> float:
    """Widest pair the open jaws can descend around with ``jaw_clearance_m`` on each side."""
    return PANDA.open_width_m - 2.0 * planner.jaw_clearance_m


@dataclass
class MotionCheck:
    """Whether R (candidate, approach) grasps can be executed as planned, with their joint paths."""

    STAGES = ("grasp_ik", "motion")  # the check that rejected a grasp, in the order they run

    feasible: torch.Tensor  # (R,) bool: grasp pose and whole motion reachable on one IK branch
    joint_path: torch.Tensor  # (R, W, 7) joints at every waypoint of ``motion_waypoints`` (zeros where infeasible)
    s_reach: torch.Tensor  # (R,) IK margin of the grasp pose
    rejected_by: torch.Tensor  # (R, 2) int64 one-hot over ``STAGES``: the check that rejected it
    ik_targets: int  # grasp poses and waypoints handed to IK


def check_motions(
    centre: torch.Tensor,
    approach: torch.Tensor,
    rotation: torch.Tensor,
    ik: PandaIK,
    config: Config,
    stage_time: dict[str, float] | None = None,
) -> MotionCheck:
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

    ``stage_time``, if given, accumulates seconds under ``ik`` (grasp poses) and ``motion``.
    """
    stage_time = {"ik": 0.0, "motion": 0.0} if stage_time is None else stage_time
    clock = time.perf_counter()
    planner, execution = config.planner, config.execution
    n_rows = centre.shape[0]
    waypoints = motion_waypoints(centre, approach, execution)
    grasp_index = grasp_waypoint_index(execution)
    joint_path = torch.zeros(n_rows, waypoints.shape[1], 7)
    s_reach = torch.zeros(n_rows)
    rejected_by = torch.zeros(n_rows, len(MotionCheck.STAGES), dtype=torch.int64)

    grasp = ik.solve(centre, rotation)
    reached = grasp.success & (grasp.s_reach >= planner.min_reach)
    rejected_by[~reached, 0] = 1
    candidates, grasp_joints = reached.nonzero().squeeze(1), grasp.joints[reached]
    s_reach[candidates] = grasp.s_reach[reached]
    now = time.perf_counter()
    stage_time["ik"], clock = stage_time["ik"] + now - clock, now

    others = torch.arange(waypoints.shape[1]) != grasp_index
    # Joint 7 held at the grasp's value first (closed form). Motions that reach every waypoint
    # that way but fail a step or the table, mostly near the shoulder singularity where holding
    # joint 7 swings joints 1 and 3, are followed again with every joint free to move; a waypoint
    # out of reach at the held value was already given that chance inside ``follow``.
    # The arm at the grasp itself is placed once: a retried motion keeps its grasp joints.
    grasp_lowest_z = ik.lowest_link_point_z(grasp_joints, _arm_hulls(planner))
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
    stage_time["motion"] += time.perf_counter() - clock
    return MotionCheck(
        feasible=feasible,
        joint_path=joint_path,
        s_reach=s_reach,
        rejected_by=rejected_by,
        ik_targets=n_rows + int(candidates.numel()) * int(others.sum()),
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
    """(M, W, 7) joints along M motions through (M, W, 3) ``waypoints`` from their grasp solutions
    (M, 7) at waypoint ``grasp_index`` (where the arm's lowest point is (M,) ``grasp_lowest_z``,
    ``PandaIK.lowest_link_point_z``), holding (M, 3, 3) ``rotation``; (M,) bool whether every
    waypoint is within the IK tolerances; and (M,) bool whether each motion passes all of
    execution's checks: those tolerances, no joint moving more than ``max_waypoint_joint_step_rad``
    between waypoints, and the arm's links clear of the table."""
    planner = config.planner
    others = torch.arange(waypoints.shape[1]) != grasp_index
    hulls = _arm_hulls(planner)
    path = ik.follow(grasp_joints, waypoints[:, others], rotation, hold_joint7=hold_joint7, hulls=hulls)
    joints = torch.zeros(grasp_joints.shape[0], waypoints.shape[1], 7)
    joints[:, others], joints[:, grasp_index] = path.joints, grasp_joints
    steps = (joints[:, 1:] - joints[:, :-1]).abs().amax(dim=(1, 2))
    arm_lowest_z = torch.minimum(path.lowest_link_z_m.amin(dim=1), grasp_lowest_z)
    reached_all = (path.position_error_m < ik.robot.ik_position_tolerance_m).all(dim=1) & (
        path.rotation_error_rad < ik.robot.ik_rotation_tolerance_rad
    ).all(dim=1)
    ok = (
        reached_all
        & (steps <= config.execution.max_waypoint_joint_step_rad)
        & (arm_lowest_z >= config.scene.table_top_z_m + planner.arm_table_clearance_m)
    )
    return joints, reached_all, ok


class _ScreenVerdicts:
    """Table, gripper-volume and swept-hand verdicts of candidates, computed ahead of
    ``plan_batch``'s window and applied (counted, stored) only when the window reaches them."""

    # Verdict blocks cover this many times the candidates the window still needs at the survival
    # rate seen so far: a little more than the expected need, so one block usually suffices.
    LOOKAHEAD_MARGIN = 1.25
    # A block may add this many candidates beyond those needed even where half the computed ones
    # are fewer. Growing from ~250 by halves took a power drill or a banana (one candidate in ten
    # survives) 5-8 calls of ~1.5-3 ms fixed cost at 5,000 pairs, 3-4 with this. The cap binds only
    # where few candidates survive, and there the hand is swept for few and a candidate costs
    # ~0.01 ms, so 1,024 never needed cost about what the calls saved (512 still took 4-5 calls).
    MIN_BLOCK_GROWTH = 1024

    def __init__(self, screened: ScreenedCandidates):
        self.screened = screened
        n_candidates, n_approaches = screened.n_candidates, screened.planner.n_approaches
        self.ready = torch.zeros(n_candidates, dtype=torch.bool)
        self.usable = torch.zeros(n_candidates, n_approaches, dtype=torch.bool)  # table, volume and hand clear
        # (A,) some approach usable: kept as verdicts come, since the window asks every round and
        # reducing (A, K) each time cost ~0.1 s a plan at 500,000 pairs
        self.any_usable = torch.zeros(n_candidates, dtype=torch.bool)
        # Those candidates' rows, ascending (ranking order within each object): the motion lookahead
        # walks them every window round, and masking all (A,) rows cost ~6 ms a round at 500,000 pairs.
        self.usable_rows = torch.zeros(0, dtype=torch.int64)
        # (B,) candidates with verdicts per object, counted as they come for the same reason
        self.computed = torch.zeros(screened.n_objects, dtype=torch.int64)
        self.hand_blocked = torch.zeros(n_candidates, n_approaches, dtype=torch.bool)
        self.clearance_m = torch.full((n_candidates, n_approaches), float("inf"))
        self.volume_s = self.hand_s = 0.0

    def block_sizes(self, missing: torch.Tensor) -> torch.Tensor:
        """(B,) candidates to compute next per object, given (B,) ``missing``: candidates in its
        window without verdicts. The survival rate seen so far says how many are needed; a block
        adds at most half of what is computed (at least ``MIN_BLOCK_GROWTH``), since survival grows
        down a mug's ranking (its top pairs lie on the rim and body, where the hand hits) and the
        early rate would overshoot."""
        computed, survived = self.computed, self.usable_per_object()
        rate_based = (missing * self.LOOKAHEAD_MARGIN * computed.clamp_min(1) / survived.clamp_min(1)).ceil().to(torch.int64)
        return torch.minimum(rate_based, missing + (computed // 2).clamp_min(self.MIN_BLOCK_GROWTH)).clamp_min(missing)

    def usable_per_object(self) -> torch.Tensor:
        """(B,) int64 candidates with verdicts and a usable approach, per object."""
        return torch.bincount(self.screened.object_index[self.usable_rows], minlength=self.screened.n_objects)

    def compute_ahead(self, unknown: torch.Tensor, missing: torch.Tensor) -> None:
        """Verdicts for each object's first ``block_sizes(missing)`` candidates, in ranking order,
        among the (A,) ``unknown`` ones; (B,) ``missing``: candidates each object needs verdicts for."""
        candidate_object = self.screened.object_index
        block = self.block_sizes(missing)
        rank = _segment_exclusive_cumsum(unknown.to(torch.int64), candidate_object, missing.shape[0])
        rows = (unknown & (rank < block[candidate_object])).nonzero().squeeze(1)
        if rows.numel():  # none where the objects short of candidates have no unknown ones left
            self.compute(rows)

    def compute(self, rows: torch.Tensor) -> None:
        clock = time.perf_counter()
        self.usable[rows] = self.screened.table_and_volume_ok(rows)
        hand_clock = time.perf_counter()
        self.volume_s += hand_clock - clock
        # The real hand on every approach still usable, so IK rounds only retry for reachability.
        candidate, slots = self.usable[rows].nonzero(as_tuple=True)
        swept = self.screened.hand_clearance(rows[candidate], slots)
        self.clearance_m[rows[candidate], slots] = swept.clearance_m
        self.hand_blocked[rows[candidate[swept.blocked]], slots[swept.blocked]] = True
        self.usable[rows[candidate[swept.blocked]], slots[swept.blocked]] = False
        self.any_usable[rows] = self.usable[rows].any(dim=1)
        self.usable_rows = torch.cat((self.usable_rows, rows[self.any_usable[rows]])).sort().values
        self.computed.index_add_(0, self.screened.object_index[rows], torch.ones_like(rows))
        self.ready[rows] = True
        self.hand_s += time.perf_counter() - hand_clock


class _MotionVerdicts:
    """Motion checks of (candidate, approach) grasps, computed ahead of ``plan_batch``'s rounds and
    applied (counted, stored) only when the search reaches them.

    A round costs ~8-10 ms on its own and a check ~0.1 ms more (1 thread), so the checks are
    gathered into as few rounds as the search allows. A check's outcome depends on its own grasp
    alone, so checking ahead changes no result; it only moves work between batches. When a round
    meets pending grasps without a result, one batch checks the grasps the search is expected to
    need: walking each object's undecided candidates in ranking order (the window's, then those past
    it, screening further where too few are screened), until their expected feasible count covers
    the feasible candidates the object still lacks. A candidate counts 1 once an approach it will
    reach is known feasible, else the share of candidates expected to end feasible (observed, with
    its losses taken ``LOOKAHEAD_MARGIN`` times over). Before any of an object's candidates is
    decided that share is a guess, and each candidate gets only its next approach checked; once it
    is observed, every unchecked approach a candidate may need, so that a candidate whose first
    approach fails needs no round of its own (it left a mustard bottle 12 rounds at 5,000 pairs).
    A round is filled up to ``SMALL_ROUND_CHECKS`` grasps: its fixed cost buys those at little more.
    """

    # The share of candidates that run out of approaches is taken this many times over: a little
    # more lookahead than expected, so that one round usually suffices.
    LOOKAHEAD_MARGIN = 1.25
    # That share before any candidate is decided (one in ten; at 5,000 pairs a power drill's is
    # 0.02-0.04, a soup can's 0.07-0.10, a cracker box's ~0.4) and how many decided candidates it
    # weighs as: a guess the first observations soon outweigh.
    PRIOR_EXHAUSTED_SHARE = 0.1
    PRIOR_WEIGHT = 4
    # Where nearly every candidate is lost, the expected feasible share used is at least this: the
    # lookahead (and the screening past the window it pays for) stays within ten times the
    # feasible candidates still needed, and later rounds correct a shortfall.
    MIN_SUCCESS_SHARE = 0.1
    # A round costs ~8-10 ms on its own and a check ~0.1 ms more, so a round of fewer grasps than
    # this is mostly fixed cost.
    SMALL_ROUND_CHECKS = 32

    def __init__(self, n_candidates: int, n_approaches: int, n_waypoints: int, max_candidates: int):
        self.ready = torch.zeros(n_candidates, n_approaches, dtype=torch.bool)
        self.feasible = torch.zeros(n_candidates, n_approaches, dtype=torch.bool)
        self.grasp_ik_rejected = torch.zeros(n_candidates, n_approaches, dtype=torch.bool)  # else, if infeasible, the motion
        # Joint paths and IK margins of the feasible grasps only (a few hundred), and where each is.
        self.kept_index = torch.full((n_candidates, n_approaches), -1, dtype=torch.int32)
        self.kept_paths = torch.zeros(0, n_waypoints, 7)
        self.kept_s_reach = torch.zeros(0)
        self.ik_targets = 0
        self.max_candidates = max_candidates
        # Candidates with any grasp checked, ascending: the only ones that can be decided with a
        # usable approach (a few hundred; masking all (A,) rows cost ~6 ms a round at 500,000 pairs).
        self.checked_rows = torch.zeros(0, dtype=torch.int64)

    def outcomes(self, search: "_CandidateSearch", screens: _ScreenVerdicts) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per object (B,): the share of candidates with a usable approach expected to end feasible
        (their observed loss rate, with the prior, taken ``LOOKAHEAD_MARGIN`` times over); bool,
        whether any of its candidates with a usable approach is decided; and float, the feasible
        candidates it still lacks."""
        status = search.status[self.checked_rows]
        row_object = screens.screened.object_index[self.checked_rows]
        count = torch.zeros(screens.screened.n_objects, dtype=torch.float32)
        exhausted = count.index_add(0, row_object, (status == EXHAUSTED).to(torch.float32))
        decided_count = count.index_add(0, row_object, (status != UNDECIDED).to(torch.float32))
        feasible = count.index_add(0, row_object, (status == FEASIBLE).to(torch.float32))
        share = (exhausted + self.PRIOR_EXHAUSTED_SHARE * self.PRIOR_WEIGHT) / (decided_count + self.PRIOR_WEIGHT)
        success = (1 - self.LOOKAHEAD_MARGIN * share).clamp_min(self.MIN_SUCCESS_SHARE)
        return success, decided_count > 0, (self.max_candidates - feasible).clamp_min(0)

    def ensure(
        self, pending: torch.Tensor, slots: torch.Tensor, search: "_CandidateSearch", screens: _ScreenVerdicts,
        check: Callable[[torch.Tensor, torch.Tensor], MotionCheck],
    ) -> None:
        """Have results for the (``pending``, ``slots``) grasps, checking ahead (see the class) where one is missing."""
        missing = ~self.ready[pending, slots]
        if not missing.any():
            return
        candidate_object = screens.screened.object_index
        n_objects = screens.screened.n_objects
        success, observed, needed = self.outcomes(search, screens)
        check_all = observed | (int(missing.sum()) < self.SMALL_ROUND_CHECKS)
        with_missing = torch.zeros(n_objects, dtype=torch.bool)
        with_missing[candidate_object[pending[missing]]] = True
        fill = torch.where(with_missing, math.ceil(self.SMALL_ROUND_CHECKS / int(with_missing.sum())), 0)
        rows, grasps, supply = self._open_candidates(search, screens, success, check_all)
        # Screen further where the screened candidates are expected to fall short.
        short = self._candidates_short(needed, fill, success, rows, grasps, supply, candidate_object)
        unknown = (search.status == UNDECIDED) & ~screens.ready
        if (short > 0).any() and unknown.any():
            screens.compute_ahead(unknown, short)
            rows, grasps, supply = self._open_candidates(search, screens, success, check_all)
        row_object = candidate_object[rows]
        taken = (_segment_exclusive_cumsum(supply, row_object, n_objects) < needed[row_object]) | (
            _segment_exclusive_cumsum(grasps.sum(dim=1), row_object, n_objects) < fill[row_object]
        )
        taken_rows, taken_slots = (grasps & taken[:, None]).nonzero(as_tuple=True)
        n_approaches = self.ready.shape[1]
        keys = torch.cat((rows[taken_rows] * n_approaches + taken_slots, pending[missing] * n_approaches + slots[missing])).unique()
        check_rows, check_slots = keys // n_approaches, keys % n_approaches
        self.store(check_rows, check_slots, check(check_rows, check_slots))

    def screening_shortfall(self, search: "_CandidateSearch", screens: _ScreenVerdicts) -> torch.Tensor:
        """(B,) int64 usable candidates each object is expected to need screened beyond those it has,
        for the feasible candidates it still lacks (0 before any outcome is observed): what the next
        round's lookahead would screen."""
        success, observed, needed = self.outcomes(search, screens)
        rows, grasps, supply = self._open_candidates(search, screens, success, observed)
        # Before any outcome the success share is the prior's guess: sizing the window's blocks for
        # it saved at most one ~2 ms call at 5,000 pairs but shifted a 500,000-pair mug's growing
        # blocks into a last one 12,000-25,000 candidates (~0.1-0.2 s) larger.
        needed = torch.where(observed, needed, 0)
        return self._candidates_short(
            needed, torch.zeros_like(observed, dtype=torch.int64), success, rows, grasps, supply, screens.screened.object_index
        )

    def _open_candidates(
        self, search: "_CandidateSearch", screens: _ScreenVerdicts, success: torch.Tensor, check_all: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The candidates the search may still reach, (C,) rows in ranking order (undecided, with a
        usable approach by the screens); the (C, K) unchecked approaches each needs before its
        outcome is known (all of them where its object's ``check_all``, else the next one); and
        (C,) its expected feasible count: 1 where an approach it will reach is known feasible, its
        object's ``success`` where one is still unchecked, else 0."""
        rows = screens.usable_rows[search.status[screens.usable_rows] == UNDECIDED]
        n_approaches = self.ready.shape[1]
        order = torch.arange(n_approaches)
        start = torch.where(search.screened[rows], search.cursor[rows], 0)  # past the window: from the first
        remaining = screens.usable[rows] & (order >= start[:, None])
        ready = self.ready[rows]
        first_feasible = torch.where(remaining & ready & self.feasible[rows], order, n_approaches).amin(dim=1)
        unchecked = remaining & ~ready & (order < first_feasible[:, None])
        row_object = screens.screened.object_index[rows]
        grasps = torch.where(check_all[row_object, None], unchecked, unchecked & (unchecked.cumsum(dim=1) == 1))
        supply = torch.where(first_feasible < n_approaches, 1.0, torch.where(unchecked.any(dim=1), success[row_object], 0.0))
        return rows, grasps, supply.to(torch.float64)

    @staticmethod
    def _candidates_short(
        needed: torch.Tensor, fill: torch.Tensor, success: torch.Tensor, rows: torch.Tensor, grasps: torch.Tensor,
        supply: torch.Tensor, candidate_object: torch.Tensor,
    ) -> torch.Tensor:
        """(B,) int64 usable candidates each object needs screened beyond those it has: to cover
        the feasible candidates it ``needed`` at its ``success`` share, and to ``fill`` a round."""
        n_objects = needed.shape[0]
        row_object = candidate_object[rows]
        expected = torch.zeros(n_objects, dtype=torch.float64).index_add_(0, row_object, supply)
        checks = torch.zeros(n_objects, dtype=torch.int64).index_add_(0, row_object, grasps.sum(dim=1))
        for_needed = ((needed - expected).clamp_min(0) / success).ceil().to(torch.int64)
        return torch.maximum(for_needed, (fill - checks).clamp_min(0))

    def store(self, rows: torch.Tensor, slots: torch.Tensor, motion: MotionCheck) -> None:
        feasible = motion.feasible
        self.ready[rows, slots] = True
        self.checked_rows = torch.cat((self.checked_rows, rows)).unique()
        self.feasible[rows, slots] = feasible
        self.grasp_ik_rejected[rows, slots] = motion.rejected_by[:, 0].bool()
        self.kept_index[rows[feasible], slots[feasible]] = torch.arange(int(feasible.sum()), dtype=torch.int32) + self.kept_paths.shape[0]
        self.kept_paths = torch.cat((self.kept_paths, motion.joint_path[feasible]))
        self.kept_s_reach = torch.cat((self.kept_s_reach, motion.s_reach[feasible]))
        self.ik_targets += motion.ik_targets

    def verdicts(self, rows: torch.Tensor, slots: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(R,) bool feasible and (R, 2) int64 ``MotionCheck.rejected_by`` of (``rows``, ``slots``) grasps, all checked."""
        feasible, grasp_ik = self.feasible[rows, slots], self.grasp_ik_rejected[rows, slots]
        return feasible, torch.stack((grasp_ik, ~feasible & ~grasp_ik), dim=1).to(torch.int64)

    def kept(self, rows: torch.Tensor, slots: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(R, W, 7) joint paths and (R,) IK margins of (``rows``, ``slots``) grasps, all feasible."""
        index = self.kept_index[rows, slots].to(torch.int64)
        return self.kept_paths[index], self.kept_s_reach[index]


@dataclass
class _CandidateSearch:
    """Where the search for each screened candidate's first executable approach stands.

    Approaches are tried in prior order: a candidate is UNDECIDED while an untried approach that
    passed the screens is left (``cursor``), FEASIBLE once one passes the motion check, EXHAUSTED
    when none is left.
    """

    usable: torch.Tensor  # (A, K) bool: approach passed table, gripper volume and swept hand
    next_usable: torch.Tensor  # (A, K + 1) first usable approach at or after prior position k (K: none left)
    cursor: torch.Tensor  # (A,) approach to try next (K: none)
    screened: torch.Tensor  # (A,) bool: the screens' verdicts are applied
    status: torch.Tensor  # (A,) UNDECIDED / FEASIBLE / EXHAUSTED
    clearance_m: torch.Tensor  # (A, K) swept hand's clearance where computed
    rejected: torch.Tensor  # (A, 3) int64 rejections per candidate: hand, grasp IK, motion

    @classmethod
    def start(cls, n_candidates: int, n_approaches: int) -> "_CandidateSearch":
        # Candidates without a table-clear approach are found, and exhausted, when screened.
        return cls(
            usable=torch.zeros(n_candidates, n_approaches, dtype=torch.bool),
            next_usable=torch.full((n_candidates, n_approaches + 1), n_approaches),
            cursor=torch.full((n_candidates,), n_approaches),
            screened=torch.zeros(n_candidates, dtype=torch.bool),
            status=torch.full((n_candidates,), UNDECIDED),
            clearance_m=torch.full((n_candidates, n_approaches), float("inf")),
            rejected=torch.zeros(n_candidates, 3, dtype=torch.int64),
        )

    def apply_screens(self, rows: torch.Tensor, verdicts: "_ScreenVerdicts") -> None:
        n_approaches = self.usable.shape[1]
        self.usable[rows] = verdicts.usable[rows]
        self.clearance_m[rows] = verdicts.clearance_m[rows]
        self.rejected[rows, 0] += verdicts.hand_blocked[rows].sum(dim=1)
        self.screened[rows] = True
        first_usable = torch.where(self.usable[rows], torch.arange(n_approaches), n_approaches)
        first_usable = torch.cat((first_usable, torch.full((rows.numel(), 1), n_approaches)), dim=1)
        self.next_usable[rows] = first_usable.flip(1).cummin(1).values.flip(1)
        self.cursor[rows] = self.next_usable[rows, 0]
        self.status[rows] = torch.where(self.cursor[rows] < n_approaches, UNDECIDED, EXHAUSTED)

    def apply_motions(self, rows: torch.Tensor, slots: torch.Tensor, feasible: torch.Tensor, rejected_by: torch.Tensor) -> None:
        """The motion checks' (R,) ``feasible`` and (R, 2) ``rejected_by`` of (``rows``, ``slots``) grasps."""
        self.rejected[rows, 1:] += rejected_by
        self.status[rows[feasible]] = FEASIBLE
        retry = rows[~feasible]
        self.cursor[retry] = self.next_usable[retry, slots[~feasible] + 1]
        self.status[retry] = torch.where(self.cursor[retry] < self.usable.shape[1], UNDECIDED, EXHAUSTED)


def _window_with_verdicts(
    search: _CandidateSearch, verdicts: "_ScreenVerdicts", motions: _MotionVerdicts, candidate_object: torch.Tensor, n_objects: int,
    max_candidates: int,
) -> torch.Tensor:
    """(A,) bool: each object's first ``max_candidates`` candidates still alive, with the screens'
    verdicts computed for every candidate in it.

    With verdicts known for the whole window, the window of the first candidates still alive after
    screening is the fixed point that screening round by round (each round moving the window past
    the candidates it exhausted) reaches, and it screens the same candidates. Verdicts are computed
    ahead, in blocks sized by the survival rate seen so far, so a mug (one antipodal candidate in
    several hundred survives) takes ~15 blocks at 500,000 pairs, not one round per 200 candidates
    each recounting every candidate's window. The blocks also cover the usable candidates the next
    motion round's lookahead is expected to want past the window (``_MotionVerdicts.screening_shortfall``,
    estimated once: it costs ~0.3 ms), which it would otherwise screen in a call of its own (~2 ms fixed).
    """
    usable_target = None  # (B,) usable candidates each object is expected to need screened in all
    while True:
        waiting = (search.status == UNDECIDED) & ~search.screened
        unknown = waiting & ~verdicts.ready
        alive = torch.where(waiting & verdicts.ready, verdicts.any_usable, search.status != EXHAUSTED)
        in_window = _segment_exclusive_cumsum(alive.to(torch.int64), candidate_object, n_objects) < max_candidates
        missing = unknown & in_window
        if not missing.any():
            return in_window
        wanted = torch.zeros(n_objects, dtype=torch.int64).index_add_(0, candidate_object, missing.to(torch.int64))
        usable = verdicts.usable_per_object()
        if usable_target is None:
            usable_target = usable + motions.screening_shortfall(search, verdicts)
        verdicts.compute_ahead(unknown, torch.maximum(wanted, usable_target - usable))


def _planned_candidates(
    screened: ScreenedCandidates, search: _CandidateSearch, motions: _MotionVerdicts, n_objects: int, config: Config
) -> list[GraspCandidates]:
    """One ``GraspCandidates`` per object: its first ``max_candidates`` feasible candidates, with counts.

    Every object's kept candidates and counts are gathered at once and then cut into objects:
    masking all candidates once per object grew as objects times candidates."""
    planner = config.planner
    candidate_object = screened.object_index
    feasible = search.status == FEASIBLE
    collision_free = search.screened & search.usable.any(dim=1)
    rank_in_object = _segment_exclusive_cumsum(feasible.to(torch.int64), candidate_object, n_objects)
    kept = (feasible & (rank_in_object < planner.max_candidates)).nonzero().squeeze(1)  # by object, then rank
    slot = search.cursor[kept].clamp_max(search.usable.shape[1] - 1)
    approach, rotation = screened.frames(kept, slot)
    joint_path, s_reach = motions.kept(kept, slot)
    per_object = torch.bincount(candidate_object[kept], minlength=n_objects).tolist()
    fields = {
        "contacts_world": screened.contacts_world[kept],
        "closing_axis": screened.closing_axis[kept],
        "width_m": screened.width_m[kept],
        "s_geom": screened.s_geom[kept],
        "approach": approach,
        "rotation_world": rotation,
        "s_reach": s_reach,
        "ik_solution": joint_path[:, grasp_waypoint_index(config.execution)],
        "joint_path": joint_path,
        "hand_clearance_m": search.clearance_m[kept, slot],
    }
    # Each object's rows as tensors of their own (clones of the cut), not views of the batch's.
    parts = {name: [part.clone() for part in values.split(per_object)] for name, values in fields.items()}

    def per_object_count(mask: torch.Tensor) -> list[int]:
        return torch.bincount(candidate_object[mask], minlength=n_objects).tolist()

    every = torch.ones_like(feasible)
    counted = {"antipodal": per_object_count(every), "collision_free": per_object_count(collision_free), "ik_feasible": per_object_count(feasible)}
    rejected = torch.zeros(n_objects, search.rejected.shape[1], dtype=torch.int64).index_add_(0, candidate_object, search.rejected).T.tolist()
    counted.update({f"rejected_{stage}": rejected[column] for column, stage in enumerate(("hand", *MotionCheck.STAGES))})
    results = []
    for index, n_kept in enumerate(per_object):
        zeros = torch.zeros(n_kept)
        results.append(
            GraspCandidates(
                **{name: values[index] for name, values in parts.items()},
                zone=torch.full((n_kept,), -1, dtype=torch.int64),
                s_afford=zeros.clone(),
                s_avoid=zeros.clone(),
                s_task=zeros.clone(),
                score=parts["s_geom"][index].clone(),
                counts={"sampled": planner.n_pairs, **{name: values[index] for name, values in counted.items()}},
            )
        )
    return results


def plan_batch(
    clouds: Sequence[PerceivedCloud],
    config: Config,
    seeds: Sequence[int | None] | None = None,
    timings: dict[str, float] | None = None,
) -> list[GraspCandidates]:
    """Plan grasps for several objects with shared kernel calls and one IK call per round.

    Args:
        clouds: perceived objects (world frame, outward normals).
        config: pipeline configuration (``planner``, ``scene.table_top_z_m``,
            ``scene.robot_base_xyz_m``, ``execution.pregrasp_offset_m``).
        seeds: one sampling seed per cloud (``None`` entries, or no list, use ``config.planner.seed``).
        timings: if given, filled with seconds spent per stage (``sampling``, ``antipodal``,
            ``frames_volume`` (frames, table and the 12 % volume), ``hand_sweep``, ``ik`` (grasp
            poses), ``motion`` (the whole motion's IK and arm clearance)) and ``ik_targets`` (grasp
            poses and waypoints solved, those checked ahead and never reached included).

    Returns:
        One ``GraspCandidates`` per cloud: at most ``max_candidates`` IK-feasible candidates ranked
        by S_geom (ties in sampling order), ``score = s_geom``, zone -1, semantic terms 0, and
        ``counts`` with ``sampled``, ``antipodal``, ``collision_free`` (screened candidates with at
        least one approach clear of the table and under the occupancy limits; volumes are screened
        in S_geom order only until ``max_candidates`` are feasible), ``ik_feasible`` (feasible
        candidates found; IK stops once ``max_candidates`` are known).
    """
    planner = config.planner
    seeds = [planner.seed] * len(clouds) if seeds is None else [planner.seed if s is None else s for s in seeds]
    if len(seeds) != len(clouds):
        raise ValueError(f"got {len(seeds)} seeds for {len(clouds)} clouds")
    for position, cloud in enumerate(clouds):
        _check_cloud(cloud, position)
    if not clouds:
        return []
    stage_time: dict[str, float] = {}
    screened = screen_candidates(clouds, config, seeds, stage_time)
    n_candidates, n_approaches = screened.n_candidates, planner.n_approaches
    n_waypoints = waypoint_count(config.execution)
    search = _CandidateSearch.start(n_candidates, n_approaches)
    verdicts = _ScreenVerdicts(screened)
    motions = _MotionVerdicts(n_candidates, n_approaches, n_waypoints, planner.max_candidates)
    ik = panda_ik(config)
    motion_time = {"ik": 0.0, "motion": 0.0}

    def check(rows: torch.Tensor, slots: torch.Tensor) -> MotionCheck:
        return check_motions(screened.centre_world[rows], *screened.frames(rows, slots), ik, config, motion_time)

    while True:
        in_window = _window_with_verdicts(search, verdicts, motions, screened.object_index, len(clouds), planner.max_candidates)
        to_screen = (in_window & (search.status == UNDECIDED) & ~search.screened).nonzero().squeeze(1)
        if to_screen.numel():
            search.apply_screens(to_screen, verdicts)
            continue
        pending = (in_window & (search.status == UNDECIDED)).nonzero().squeeze(1)
        if pending.numel() == 0:
            break
        slots = search.cursor[pending]
        motions.ensure(pending, slots, search, verdicts, check)
        search.apply_motions(pending, slots, *motions.verdicts(pending, slots))
    stage_time["frames_volume"] += verdicts.volume_s
    stage_time["hand_sweep"] = verdicts.hand_s
    stage_time.update(motion_time)
    if timings is not None:
        timings.update(stage_time)
        timings["ik_targets"] = motions.ik_targets
    return _planned_candidates(screened, search, motions, len(clouds), config)


def plan(cloud: PerceivedCloud, config: Config, seed: int | None = None, timings: dict[str, float] | None = None) -> GraspCandidates:
    """Plan grasps for one object; deterministic for a given ``seed`` (default ``config.planner.seed``)."""
    return plan_batch([cloud], config, [seed], timings)[0]
