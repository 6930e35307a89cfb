"""Antipodal candidates of several clouds and the screens that need no IK: the table, the 12 %
gripper volume, and the real hand swept along the descent, each computed for the rows asked for."""
from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.grasp_frames import approach_directions, grasp_rotations
from sagp_batched_kernels.hand_clearance import HandClearance, hand_clearance
from sagp_batched_kernels.occupancy_verdict import gripper_occupancy_within
from sagp_batched_kernels.table_penetration import table_cover, table_penetration

from ..config import Config, MemoryConfig, PlannerConfig
from ..robot.description import RobotDescription, robot_of
from ..robot.hand import DOP_DIRECTIONS, hulls_in_grasp_frame
from ..types import PerceivedCloud
from .gripper import gripper_geometry, hand_geometry, jaw_width_limit, widest_pair_m
from .sampling import sample_inputs
from .stages import StageClock

# Approach 0 of every closing axis is the one closest to straight down: top-down grasps clear
# the table and the arm most often, so they are the prior's first choice.
WORLD_DOWN = torch.tensor([0.0, 0.0, -1.0])
# A linkage's closing sweep: the opening in this many bins, the fingers placed every this much of width (m).
CLOSING_WIDTH_BINS = 8
CLOSING_SWEEP_STEP_M = 0.005


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
    memory: MemoryConfig
    robot: RobotDescription
    pregrasp_offset_m: float
    table_top_z_m: float
    clock: StageClock  # the plan's stage times, the draws and the antipodal filter already on it

    @property
    def n_candidates(self) -> int:
        return self.width_m.shape[0]

    @property
    def n_objects(self) -> int:
        return self.occupancy_points.shape[0]

    def frames(self, rows: torch.Tensor, slots: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Approach directions (R, K, 3), in prior order, and grasp frames (R, K, 3, 3) of candidates
        ``rows``; with ``slots`` (R,), only those approaches: (R, 3) and (R, 3, 3).

        Computed the first time a candidate is asked for: a plan reaches a small share of a large
        cloud's candidates, and a candidate's frames do not depend on which others are framed with it.
        """
        new = rows[~self.framed[rows]]
        if new.numel():
            new = new.unique()  # a candidate may be asked for once per approach
            closing_axis = self.closing_axis[new]
            approach = approach_directions(closing_axis, self.planner.n_approaches, WORLD_DOWN.to(closing_axis.device))
            self.approach_buffer[new] = approach
            self.rotation_buffer[new] = grasp_rotations(closing_axis[:, None, :], approach)
            self.framed[new] = True
        if slots is None:
            return self.approach_buffer[rows], self.rotation_buffer[rows]
        return self.approach_buffer[rows, slots], self.rotation_buffer[rows, slots]

    @property
    def approach(self) -> torch.Tensor:
        """(A, K, 3) every candidate's approaches (framing all of them; for tests)."""
        return self.frames(torch.arange(self.n_candidates, device=self.width_m.device))[0]

    @property
    def rotation_world(self) -> torch.Tensor:
        """(A, K, 3, 3) every candidate's grasp frames (framing all of them; for tests)."""
        return self.frames(torch.arange(self.n_candidates, device=self.width_m.device))[1]

    def clear_of_table(self, rows: torch.Tensor, rotation: torch.Tensor | None = None) -> torch.Tensor:
        """(R, K) bool: the hand of candidates ``rows`` stays above the table at the grasp and the
        pre-grasp (fingers and the rest by their own clearances), and the jaws fit the width.
        ``rotation``: their (R, K, 3, 3) frames, where the caller has them (default: ``frames``).
        """
        planner = self.planner
        (fingers, fingers_cover), (rest, rest_cover) = table_check_points(self.robot, self.width_m.device)
        centre = self.centre_world[rows]
        rotation = self.frames(rows)[1] if rotation is None else rotation
        through_table = table_penetration(
            centre, rotation, fingers, self.pregrasp_offset_m, self.table_top_z_m + planner.finger_table_clearance_m, fingers_cover
        ) | table_penetration(centre, rotation, rest, self.pregrasp_offset_m, self.table_top_z_m + planner.arm_table_clearance_m, rest_cover)
        if self.robot.gripper.finger_motion == "linkage":
            through_table |= self._closing_through_table(rows, centre, rotation)
        return ~through_table & (self.width_m[rows] <= jaw_width_limit(self.robot, planner))[:, None]

    def _closing_through_table(self, rows: torch.Tensor, centre: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
        """(R, K) bool: a linkage's fingers, closing at the grasp from open to the candidate's width, dip below the
        table: its fingertips reach further along the approach as they close (``closing_finger_points``)."""
        widths, swept = closing_finger_points(self.robot, self.width_m.device)
        bins = (torch.searchsorted(widths, self.width_m[rows], right=True) - 1).clamp(0, len(swept) - 1)
        through = torch.zeros(rotation.shape[:2], dtype=torch.bool, device=rotation.device)
        for index in bins.unique().tolist():
            members = (bins == index).nonzero().squeeze(1)
            vertices, cover = swept[index]
            through[members] = table_penetration(centre[members], rotation[members], vertices, 0.0,
                                                 self.table_top_z_m + self.planner.finger_table_clearance_m, cover)
        return through

    def table_and_volume_ok(self, rows: torch.Tensor) -> torch.Tensor:
        """(R, K) bool: candidates ``rows`` clear the table and their gripper volumes are under the
        published 12 % limit. Volumes are counted only for the poses that clear the table."""
        rotation = self.frames(rows)[1]  # gathered once for both checks
        return self.volume_within(rows, rotation, self.clear_of_table(rows, rotation))

    def volume_within(self, rows: torch.Tensor, rotation: torch.Tensor, poses: torch.Tensor) -> torch.Tensor:
        """(R, K) bool: the gripper volumes of candidates ``rows`` in frames ``rotation`` (R, K, 3, 3) hold at
        most ``occupancy_max_fraction`` of their cloud's points; counted only where ``poses`` (R, K) is True."""
        planner = self.planner
        return gripper_occupancy_within(
            self.occupancy_points, self.object_index[rows], self.centre_world[rows], rotation,
            self.width_m[rows], gripper_geometry(self.robot, planner), planner.occupancy_max_fraction * self.occupancy_total[self.object_index[rows]],
            self.memory.occupancy_chunk_elements, poses, planner.compile,
        )

    def hand_clearance(self, rows: torch.Tensor, slots: torch.Tensor) -> HandClearance:
        """Whether the real hand (its collision hulls) swept along the descent of candidates ``rows``
        with approaches ``slots`` comes within the margin of the scene's object and obstacle points,
        and its clearance from them (exact where not blocked). The coarse subset is probed first:
        most blocked grasps (a mug's) strike one of its points."""
        low, high = swept_hand(self.robot, self.pregrasp_offset_m, self.width_m.device)
        return hand_clearance(
            self.hand_check_points, self.hand_screen_points, self.object_index[rows], self.centre_world[rows], self.frames(rows, slots)[1],
            DOP_DIRECTIONS.to(low.device), low, high, self.planner.hand_clearance_margin_m, self.memory.hand_check_chunk_elements, self.planner.compile,
        )

    @property
    def usable(self) -> torch.Tensor:
        """(A, K) bool: the published screen (table, 12 % volume) on every candidate, eagerly (for
        tests); the candidate search adds the swept hand and the motion."""
        return self.table_and_volume_ok(torch.arange(self.n_candidates, device=self.width_m.device))


def screen_candidates(
    clouds: Sequence[PerceivedCloud], config: Config, seeds: Sequence[int], clock: StageClock | None = None
) -> ScreenedCandidates:
    """Sampling and the antipodal filter for all clouds at once; the screens run on demand, timed on
    ``clock`` (a fresh one by default) as the draws and the filter are."""
    planner, robot = config.planner, robot_of(config)
    clock = StageClock() if clock is None else clock
    if planner.compile:
        use_compile_cache()
    n_objects = len(clouds)
    n_pairs = planner.n_pairs * n_objects
    with clock.stage("sampling", n_pairs):
        sampled = [sample_inputs(cloud, robot, planner, config.memory, seed) for cloud, seed in zip(clouds, seeds)]
        device = clouds[0].points_world.device
        point_offsets = torch.tensor([0] + [cloud.n_points for cloud in clouds], device=device).cumsum(0)[:-1]
        pairs = torch.cat([s.pair_indices + offset for s, offset in zip(sampled, point_offsets)])
        pair_object = torch.arange(n_objects, device=device).repeat_interleave(planner.n_pairs)
        points = torch.cat([cloud.points_world.to(torch.float32) for cloud in clouds])
        normals = torch.cat([cloud.normals_world.to(torch.float32) for cloud in clouds])
    with clock.stage("antipodal", n_pairs):
        pair_eval = antipodal_pairs(points, normals, pairs, planner.min_width_m, widest_pair_m(robot, planner), planner.max_contact_angle_deg)
        antipodal = pair_eval["antipodal"].nonzero().squeeze(1)
        # Rank by S_geom within each object; stable sorts keep sampling order among ties.
        antipodal = antipodal[torch.sort(pair_eval["s_geom"][antipodal], descending=True, stable=True).indices]
        if n_objects > 1:  # one object's candidates are already grouped
            antipodal = antipodal[torch.sort(pair_object[antipodal], stable=True).indices]
        candidate_object = pair_object[antipodal]
        contacts = points[pairs[antipodal]]  # (A, 2, 3)
        pair_values = {name: pair_eval[name][antipodal] for name in ("closing_axis", "width_m", "s_geom")}
    return _screened(config, robot, sampled, clock, pairs[antipodal] - point_offsets[candidate_object, None], candidate_object, contacts,
                     pair_values)


def _screened(
    config: Config, robot: RobotDescription, sampled: list, clock: StageClock, pair_indices: torch.Tensor,
    candidate_object: torch.Tensor, contacts: torch.Tensor, pair_values: dict[str, torch.Tensor],
) -> ScreenedCandidates:
    """The ``ScreenedCandidates`` of ranked candidates (their (A, 2) point indices within their
    clouds, (A,) clouds, (A, 2, 3) contacts, and ``antipodal_pairs``' values for them) and the
    clouds' ``sampled`` point subsets."""
    planner, n_candidates, device = config.planner, candidate_object.numel(), candidate_object.device
    return ScreenedCandidates(
        object_index=candidate_object,
        pair_indices=pair_indices,
        contacts_world=contacts,
        centre_world=contacts.mean(dim=1),  # once for every candidate, not per block of candidates
        **pair_values,
        approach_buffer=torch.empty(n_candidates, planner.n_approaches, 3, device=device),
        rotation_buffer=torch.empty(n_candidates, planner.n_approaches, 3, 3, device=device),
        framed=torch.zeros(n_candidates, dtype=torch.bool, device=device),
        occupancy_points=_padded([s.occupancy_points for s in sampled]),
        occupancy_total=torch.tensor([s.occupancy_total for s in sampled], dtype=torch.float32, device=device),
        hand_check_points=_padded([s.hand_check_points for s in sampled]),
        hand_screen_points=_padded([s.hand_screen_points for s in sampled]),
        planner=planner,
        memory=config.memory,
        robot=robot,
        pregrasp_offset_m=config.motion.pregrasp_offset_m,
        table_top_z_m=config.scene.table_top_z_m,
        clock=clock,
    )


def use_compile_cache() -> None:
    """Inductor keeps the kernels it compiles under the project's cache root (``inductor/``), where
    a later process loads them instead of compiling again; ``$TORCHINDUCTOR_CACHE_DIR``, if set, wins."""
    from ..world.objects import sagp_cache_root  # the cache root's one home; world is not otherwise needed here

    os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(sagp_cache_root() / "inductor"))


@functools.lru_cache(maxsize=8)
def swept_hand(robot: RobotDescription, pregrasp_offset_m: float, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """The hand's hulls' k-DOP extents (low, high) swept from the pre-grasp to the grasp, on ``device``:
    built once per robot, motion and device, not on every block of candidates."""
    low, high = hand_geometry(robot).swept((0.0, 0.0, -pregrasp_offset_m))
    return low.to(device), high.to(device)


@functools.lru_cache(maxsize=8)
def table_check_points(robot: RobotDescription, device: torch.device) -> tuple[tuple[torch.Tensor, tuple[torch.Tensor, float]], ...]:
    """The fingers' and the other links' hull vertices (grasp frame) the table check tests, each
    with its ``table_cover``, on ``device``: built once per robot and device, not on every block of candidates."""
    hand = hand_geometry(robot)
    fingers = hand.vertices(robot.gripper.finger_links)
    rest = hand.vertices(tuple(name for name in hand.links if name not in robot.gripper.finger_links))

    def on_device(vertices: torch.Tensor) -> tuple[torch.Tensor, tuple[torch.Tensor, float]]:
        cover, reach = table_cover(vertices)
        return vertices.to(device), (cover.to(device), reach)

    return on_device(fingers), on_device(rest)


@functools.lru_cache(maxsize=8)
def closing_finger_points(robot: RobotDescription, device: torch.device) -> tuple[torch.Tensor, tuple[tuple[torch.Tensor, tuple[torch.Tensor, float]], ...]]:
    """A linkage's fingers swept by the close: (B,) the lower edges of ``CLOSING_WIDTH_BINS`` equal bins of the
    opening, and per bin the finger links' hull vertices (grasp frame) at openings from fully open down to the
    bin's lower edge, each every ``CLOSING_SWEEP_STEP_M`` of width, with their ``table_cover``: a candidate in a bin
    is tested against fingers that close at most one bin further than its own width."""
    gripper = robot.gripper
    edges = np.linspace(0.0, gripper.open_width_m, CLOSING_WIDTH_BINS + 1)[:-1]
    swept = []
    for narrowest in edges:
        steps = max(2, int(np.ceil((gripper.open_width_m - narrowest) / CLOSING_SWEEP_STEP_M)) + 1)
        vertices = torch.cat([torch.cat(hulls_in_grasp_frame(robot, gripper.finger_links, float(width)))
                              for width in np.linspace(gripper.open_width_m, narrowest, steps)])
        cover, reach = table_cover(vertices)
        swept.append((vertices.to(device), (cover.to(device), reach)))
    return torch.tensor(edges, dtype=torch.float32, device=device), tuple(swept)


def _padded(point_sets: list[torch.Tensor]) -> torch.Tensor:
    """(B, max N, 3) the point sets stacked, shorter ones padded with NaN rows (never inside anything)."""
    padded = torch.full((len(point_sets), max(len(points) for points in point_sets), 3), float("nan"), device=point_sets[0].device)
    for index, points in enumerate(point_sets):
        padded[index, : len(points)] = points
    return padded
