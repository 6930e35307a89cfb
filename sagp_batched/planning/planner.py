"""``plan`` and ``plan_batch``: screened candidates searched for their first executable approach,
each object's best ``max_candidates`` returned with what the plan counted and what it cost."""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from ..config import Config
from ..grasps import GraspCandidates
from ..robot.motion import grasp_waypoint_index, waypoint_count
from ..types import PerceivedCloud
from .lookahead import MotionVerdicts, ScreenVerdicts, window_with_verdicts
from .block_search import search_in_blocks
from .device import planning_device
from .motion_check import MotionCheck, motion_checker
from .sampling import check_cloud
from .screens import ScreenedCandidates, screen_candidates
from .search import CandidateSearch, CandidateStatus, SearchTuning, segment_exclusive_cumsum
from .stages import STAGES, StageClock


@dataclass(frozen=True)
class PlanCounts:
    """What one object's plan counted at each stage."""

    sampled: int  # point pairs drawn
    antipodal: int  # of them, antipodal within the width range
    # screened candidates with an approach clear of the table, under the occupancy limit and clear
    # of the swept hand (screened in S_geom order only until ``max_candidates`` are feasible)
    collision_free: int
    ik_feasible: int  # feasible candidates found (the search stops once ``max_candidates`` are)
    rejected_hand: int  # (candidate, approach) grasps the swept hand rejected
    rejected_grasp_ik: int  # grasps whose pose IK could not reach
    rejected_motion: int  # grasps whose motion (waypoints, steps, arm above the table) failed

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class PlanStageTimes:
    """Seconds one ``plan_batch`` call spent per stage (``STAGES``), for all its clouds together,
    and the work each stage did."""

    sampling_s: float
    antipodal_s: float  # the antipodal filter and the ranking
    frames_volume_s: float  # grasp frames, the table check and the 12 % volume
    hand_sweep_s: float
    ik_s: float  # grasp-pose IK
    motion_s: float  # the whole motion's IK and arm clearance
    ik_targets: int  # grasp poses and waypoints solved, those checked ahead and never reached included
    pairs: int  # pairs drawn and filtered
    screened_poses: int  # (candidate, approach) poses the table and volume screens decided
    swept_poses: int  # poses the swept hand was checked on
    grasp_targets: int  # grasp poses solved (the rest of ``ik_targets`` are waypoints)

    @classmethod
    def of(cls, clock: StageClock) -> PlanStageTimes:
        seconds, items = clock.seconds, clock.items
        return cls(
            *(seconds[stage] for stage in STAGES), ik_targets=items["ik"] + items["motion"], pairs=items["sampling"],
            screened_poses=items["frames_volume"], swept_poses=items["hand_sweep"], grasp_targets=items["ik"],
        )

    def stage_seconds(self) -> dict[str, float]:
        return {stage: getattr(self, f"{stage}_s") for stage in STAGES}

    def stage_items(self) -> dict[str, int]:
        """The work of each stage: pairs (sampling, antipodal), poses (frames_volume, hand_sweep), IK targets (ik, motion)."""
        return {"sampling": self.pairs, "antipodal": self.pairs, "frames_volume": self.screened_poses, "hand_sweep": self.swept_poses,
                "ik": self.grasp_targets, "motion": self.ik_targets - self.grasp_targets}


@dataclass(frozen=True)
class PlanResult:
    """One object's plan: its candidates ranked by S_geom, its counts, and the call's stage times
    (shared by every result of one ``plan_batch``)."""

    candidates: GraspCandidates
    counts: PlanCounts
    times: PlanStageTimes


def plan_batch(
    clouds: Sequence[PerceivedCloud], config: Config, seeds: Sequence[int | None] | None = None, tuning: SearchTuning | None = None,
) -> list[PlanResult]:
    """Plan grasps for several objects with shared kernel calls and one IK call per round.

    ``clouds`` are perceived objects (world frame, outward normals), planned on ``[planner] device``
    and answered on the first cloud's own device; ``seeds`` one sampling seed per
    cloud (``None`` entries, or no list, use ``config.planner.seed``); ``tuning`` how far ahead
    verdicts are computed (it changes no result). Each result's candidates are at most
    ``max_candidates`` feasible ones ranked by S_geom (ties in sampling order), ``score = s_geom``,
    zone -1, semantic terms 0.
    """
    planner = config.planner
    seeds = [planner.seed] * len(clouds) if seeds is None else [planner.seed if s is None else s for s in seeds]
    if len(seeds) != len(clouds):
        raise ValueError(f"got {len(seeds)} seeds for {len(clouds)} clouds")
    for position, cloud in enumerate(clouds):
        check_cloud(cloud, position)
    if not clouds:
        return []
    device, home = planning_device(planner), clouds[0].points_world.device
    clouds = [cloud.on(device) for cloud in clouds]
    tuning = SearchTuning() if tuning is None else tuning
    clock = StageClock()
    screened = screen_candidates(clouds, config, seeds, clock)
    motion_check = motion_checker(config, clock)
    verdicts = ScreenVerdicts(screened, tuning)
    motions = MotionVerdicts(screened.n_candidates, planner.n_approaches, waypoint_count(config.motion), screened.robot.n_arm_joints,
                             planner.max_candidates, tuning, device)

    def check(rows: torch.Tensor, slots: torch.Tensor) -> MotionCheck:
        return motion_check(screened.centre_world[rows], *screened.frames(rows, slots))

    if planner.search == "blocks":
        search = search_in_blocks(verdicts, motions, planner.max_candidates, check)
    else:
        search = _search_with_lookahead(verdicts, motions, planner.max_candidates, check)
    times = PlanStageTimes.of(clock)
    candidates = _planned_candidates(screened, search, motions, config)
    counts = _plan_counts(screened, search, planner.n_pairs)
    return [PlanResult(c.to(home), object_counts, times) for c, object_counts in zip(candidates, counts)]


def _search_with_lookahead(
    verdicts: ScreenVerdicts, motions: MotionVerdicts, max_candidates: int, check: Callable[[torch.Tensor, torch.Tensor], MotionCheck],
) -> CandidateSearch:
    """The lookahead search (``search``, ``lookahead``): the window's screens applied, then each
    undecided candidate's next approach checked, round after round, until every object's window is decided."""
    screened = verdicts.screened
    search = CandidateSearch.start(screened.n_candidates, screened.planner.n_approaches, screened.object_index.device)
    while True:
        in_window = window_with_verdicts(search, verdicts, motions, max_candidates)
        undecided = in_window & (search.status == CandidateStatus.UNDECIDED)
        to_screen = (undecided & ~search.screened).nonzero().squeeze(1)
        if to_screen.numel():
            search.apply_screens(to_screen, verdicts)
            continue
        pending = undecided.nonzero().squeeze(1)
        if pending.numel() == 0:
            break
        slots = search.cursor[pending]
        motions.ensure(pending, slots, search, verdicts, check)
        search.apply_motions(pending, slots, *motions.verdicts(pending, slots))
    return search


def plan(cloud: PerceivedCloud, config: Config, seed: int | None = None) -> PlanResult:
    """Plan grasps for one object; deterministic for a given ``seed`` (default ``config.planner.seed``)."""
    return plan_batch([cloud], config, [seed])[0]


def _planned_candidates(screened: ScreenedCandidates, search: CandidateSearch, motions: MotionVerdicts, config: Config) -> list[GraspCandidates]:
    """One ``GraspCandidates`` per object: its first ``max_candidates`` feasible candidates.

    Every object's kept candidates are gathered at once and then cut into objects, so no step
    masks all candidates once per object."""
    candidate_object, n_objects, device = screened.object_index, screened.n_objects, screened.object_index.device
    feasible = search.status == CandidateStatus.FEASIBLE
    rank_in_object = segment_exclusive_cumsum(feasible.to(torch.int64), candidate_object, n_objects)
    kept = (feasible & (rank_in_object < config.planner.max_candidates)).nonzero().squeeze(1)  # by object, then rank
    slot = search.cursor[kept].clamp_max(search.usable.shape[1] - 1)
    approach, rotation = screened.frames(kept, slot)
    joint_path, s_reach = motions.kept(kept, slot)
    per_object = torch.bincount(candidate_object[kept], minlength=n_objects).tolist()
    fields = {
        "contacts": screened.contacts_world[kept],
        "closing_axis": screened.closing_axis[kept],
        "width_m": screened.width_m[kept],
        "s_geom": screened.s_geom[kept],
        "approach": approach,
        "rotation": rotation,
        "s_reach": s_reach,
        "ik_solution": joint_path[:, grasp_waypoint_index(config.motion)],
        "joint_path": joint_path,
        "hand_clearance_m": search.clearance_m[kept, slot],
    }
    # Each object's rows as tensors of their own (clones of the cut), not views of the batch's.
    parts = {name: [part.clone() for part in values.split(per_object)] for name, values in fields.items()}
    results = []
    for index, n_kept in enumerate(per_object):
        zeros = torch.zeros(n_kept, device=device)
        results.append(
            GraspCandidates(
                **{name: values[index] for name, values in parts.items()},
                zone=torch.full((n_kept,), -1, dtype=torch.int64, device=device),
                s_afford=zeros.clone(),
                s_avoid=zeros.clone(),
                s_task=zeros.clone(),
                score=parts["s_geom"][index].clone(),
            )
        )
    return results


def _plan_counts(screened: ScreenedCandidates, search: CandidateSearch, n_pairs: int) -> list[PlanCounts]:
    """Each object's ``PlanCounts``, counted for all objects at once."""
    candidate_object, n_objects = screened.object_index, screened.n_objects

    def per_object(mask: torch.Tensor) -> list[int]:
        return torch.bincount(candidate_object[mask], minlength=n_objects).tolist()

    antipodal = torch.bincount(candidate_object, minlength=n_objects).tolist()
    collision_free = per_object(search.screened & search.usable.any(dim=1))
    feasible = per_object(search.status == CandidateStatus.FEASIBLE)
    hand, grasp_ik, motion = torch.zeros(n_objects, search.rejected.shape[1], dtype=torch.int64, device=candidate_object.device).index_add_(
        0, candidate_object, search.rejected).T.tolist()
    return [PlanCounts(n_pairs, *values) for values in zip(antipodal, collision_free, feasible, hand, grasp_ik, motion)]
