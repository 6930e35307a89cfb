"""Every antipodal candidate with the planner's verdict on it, for labelled datasets.

``plan`` returns only the grasps it calls feasible, and screens no more candidates than it needs to
find them. A dataset needs the rest as well: negatives, and the planner's calibration (how often a
grasp it rejected for each reason would in fact have held). ``classify_grasps`` takes every
(candidate, approach) pose of a cloud, keeps a set that covers the object (pose-space
non-maximum suppression, ``kernels.pose_nms``), runs each of the planner's checks on it in the
order the planner runs them, and picks the requested number across the verdicts.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from sagp_batched_kernels.pose_nms import pose_nms, same_grasp

from ..config import Config, DatasetConfig
from ..grasps import GraspCandidates, GraspPoses
from ..planning import ScreenedCandidates, jaw_width_limit, motion_checker, screen_candidates
from ..robot.motion import grasp_waypoint_index, waypoint_count
from ..types import PerceivedCloud
from .protocols import label_protocol

# The planner's verdicts on a grasp, in the order its checks run; a grasp's verdict is the first
# check it fails, or "feasible" when it passes them all. "boundary" is no check of the planner's: a
# floating dataset's variant of a clear grasp moved toward failure (``boundary_grasps``).
VERDICTS: tuple[str, ...] = ("feasible", "table", "volume", "hand_sweep", "grasp_ik", "motion", "boundary")
FEASIBLE = VERDICTS.index("feasible")
# Poses a floating capture tests against the mesh at once, at the least, while it draws its picks.
CLEAR_TEST_BLOCK = 64
@dataclass
class ClassifiedGrasps:
    """Grasps of one cloud (one approach each) with the planner's verdict and its reason.

    ``candidates`` holds their poses, widths and contacts (world frame), ``s_geom``, ``s_reach``
    (0 where grasp IK was not reached or failed), the joint path (zeros where not feasible) and the
    hand's swept clearance (inf where the sweep was not reached).
    """

    candidates: GraspCandidates
    verdict: torch.Tensor  # (N,) int64 index into VERDICTS
    reasons: tuple[str, ...]  # (N,) why each verdict was given
    pool_size: int  # (candidate, approach) poses the object offered
    covering_size: int  # of them, left by the pose-space suppression

    def __len__(self) -> int:
        return len(self.candidates)

    def verdict_names(self) -> list[str]:
        return [VERDICTS[v] for v in self.verdict.tolist()]


def _reason(verdict: str, planner, jaw_limit_m: float, clearance_m: float, too_wide: bool) -> str:
    if verdict == "table":
        if too_wide:
            return f"table: contacts wider than the open jaws can descend around ({jaw_limit_m:.3f} m)"
        return "table: the hand passes below the table's clearance at the grasp or the pre-grasp"
    if verdict == "volume":
        return f"volume: the closed gripper's volume holds more than {planner.occupancy_max_fraction:.0%} of the cloud's points"
    if verdict == "hand_sweep":
        return f"hand_sweep: the hand swept along the descent comes {clearance_m:.4f} m from the scene (margin {planner.hand_clearance_margin_m} m)"
    if verdict == "grasp_ik":
        return f"grasp_ik: no arm solution reaches the grasp pose within tolerance with S_reach >= {planner.min_reach}"
    if verdict == "motion":
        return "motion: a pre-grasp, descent or lift waypoint is out of reach on the grasp's IK branch, jumps a joint, or puts the arm near the table"
    return "feasible: passes the table, volume, swept-hand, grasp-IK and whole-motion checks"


def _verdict_quotas(available: dict[int, int], n_grasps: int, feasible_fraction: float, caps: dict[int, int] | None = None) -> dict[int, int]:
    """How many grasps to take of each verdict: ``feasible_fraction`` of them feasible, the rest
    spread evenly over the rejection verdicts present; a verdict short of its share passes the
    remainder on to the others. A verdict in ``caps`` takes at most that many, even where the others
    run short (fewer grasps then)."""
    caps = caps or {}
    available = {v: min(count, caps.get(v, count)) for v, count in available.items()}
    quotas = dict.fromkeys(available, 0)
    wanted = {FEASIBLE: round(n_grasps * feasible_fraction)} if FEASIBLE in available else {}
    rejected = [v for v in available if v != FEASIBLE]
    for position, verdict in enumerate(rejected):
        share = n_grasps - sum(wanted.values())
        wanted[verdict] = share // (len(rejected) - position)
    remaining = min(n_grasps, sum(available.values()))
    while remaining > 0:
        open_verdicts = [v for v in available if quotas[v] < available[v]]
        below_share = [v for v in open_verdicts if quotas[v] < wanted.get(v, 0)] or open_verdicts
        for verdict in below_share:
            if remaining == 0:
                break
            quotas[verdict] += 1
            remaining -= 1
    return quotas


@dataclass
class _Poses:
    """(candidate, approach) poses of a cloud: each one's screened candidate row and approach slot,
    (K, 3) approach, (K, 3, 3) grasp frame and (K, 3) centre, world frame."""

    rows: torch.Tensor
    slots: torch.Tensor
    approach: torch.Tensor
    rotation: torch.Tensor
    centre: torch.Tensor

    def select(self, kept: torch.Tensor | slice) -> _Poses:
        return _Poses(*(getattr(self, field.name)[kept] for field in dataclasses.fields(self)))

    @staticmethod
    def cat(parts: list[_Poses]) -> _Poses:
        return _Poses(*(torch.cat([getattr(part, field.name) for part in parts]) for field in dataclasses.fields(_Poses)))


@dataclass
class CaptureVerdicts:
    """One capture's covering poses with the planner's verdict on each (``capture_verdicts``): its cloud's
    poses that pose-space suppression keeps, before any earlier capture's grasps are set aside."""

    screened: ScreenedCandidates  # the candidates of every cloud screened with this one
    poses: _Poses
    verdict: torch.Tensor  # (N,) int64 index into VERDICTS
    clearance: torch.Tensor  # (N,) swept clearance, inf where the sweep was not reached
    joint_path: torch.Tensor  # (N, W, 7), zeros where the motion was not reached
    s_reach: torch.Tensor  # (N,), zeros where grasp IK was not reached
    pool_size: int  # (candidate, approach) poses the cloud offered

    def subset(self, kept: torch.Tensor) -> CaptureVerdicts:
        """The poses ``kept`` (indices or an (N,) mask) with their verdicts."""
        return CaptureVerdicts(self.screened, self.poses.select(kept), self.verdict[kept], self.clearance[kept], self.joint_path[kept], self.s_reach[kept],
                               self.pool_size)


def pool_for(config: Config, n_grasps: int | None, dataset: DatasetConfig | None = None) -> Config:
    """``config`` with the antipodal pairs a capture asked for ``n_grasps`` grasps samples
    (``dataset.pairs_per_grasp`` a grasp, within ``dataset.min_pairs`` and ``planner.n_pairs``); all
    ``planner.n_pairs`` where ``n_grasps`` is None."""
    if n_grasps is None:
        return config
    dataset = config.dataset if dataset is None else dataset
    return config.override("planner", n_pairs=min(config.planner.n_pairs, max(dataset.min_pairs, dataset.pairs_per_grasp * n_grasps)))


def capture_verdicts(clouds: Sequence[PerceivedCloud], config: Config, seeds: Sequence[int], dataset: DatasetConfig | None = None,
                     n_grasps: int | None = None) -> list[CaptureVerdicts]:
    """Each cloud's covering poses and the planner's verdicts on them, the clouds planned as one batch:
    one sampling and screening call for all of them (``screen_candidates``) and each check run once
    over every cloud's poses, so an object's captures share the checks' calls. A pose's verdict is
    the one it gets planned alone: the suppression runs per cloud and every check decides each pose
    on its own cloud's points. Each cloud's pool is sized for ``n_grasps`` picks (``pool_for``)."""
    dataset = config.dataset if dataset is None else dataset
    config = pool_for(config, n_grasps, dataset)
    n_approaches = config.planner.n_approaches
    screened = screen_candidates(list(clouds), config, list(seeds))
    per_cloud = torch.bincount(screened.object_index, minlength=len(clouds)).tolist()
    starts = [sum(per_cloud[:index]) for index in range(len(clouds))]
    covering = [_covering_poses(screened, range(start, start + count), n_approaches, dataset) for start, count in zip(starts, per_cloud)]
    poses = _Poses.cat(covering)
    verdicts = CaptureVerdicts(screened, poses, *_planner_verdicts(screened, config, poses), 0)
    results, first = [], 0
    for cloud_poses, n_candidates in zip(covering, per_cloud):
        end = first + cloud_poses.rows.numel()
        results.append(dataclasses.replace(verdicts.subset(slice(first, end)), pool_size=n_candidates * n_approaches))
        first = end
    return results


def classify_grasps(
    cloud: PerceivedCloud,
    config: Config,
    seed: int,
    n_grasps: int,
    dataset: DatasetConfig | None = None,
    taken_object: GraspPoses | None = None,
    open_hand_clear: Callable[[GraspPoses], np.ndarray] | None = None,
    verdicts: CaptureVerdicts | None = None,
) -> ClassifiedGrasps:
    """Up to ``n_grasps`` grasps of ``cloud`` covering the object, each with the planner's verdict.

    Every (candidate, approach) pose of the screened antipodal candidates is a grasp; those within
    ``dataset.nms_translation_m`` and ``dataset.nms_rotation_deg`` of a better one (S_geom, then
    approach order) are dropped, and so are those that are the same grasp as one in
    ``taken_object`` (grasp poses in the object's link frame: grasps picked
    from earlier captures of the object); the checks run on the rest; ``dataset.feasible_fraction`` of the
    picked grasps are feasible where the object offers them, the rest spread over the rejection
    verdicts, each drawn at random (``seed``) within its verdict so no region of the object is favoured.
    ``open_hand_clear`` (world-frame poses -> (N,) bool), where given, says which open hands stay out of
    the object's mesh: a floating dataset takes its grasps among those (``_pick``). ``verdicts``: the
    cloud's ``capture_verdicts``, where its captures were planned as a batch (planned here otherwise).
    """
    dataset = config.dataset if dataset is None else dataset
    planner = config.planner
    verdicts = capture_verdicts([cloud], config, [seed], dataset, n_grasps)[0] if verdicts is None else verdicts
    if taken_object is not None and len(taken_object):
        verdicts = verdicts.subset(_new_grasps(verdicts.poses, cloud, dataset, taken_object))
    screened, poses, verdict, clearance, joint_path, s_reach = (
        verdicts.screened, verdicts.poses, verdicts.verdict, verdicts.clearance, verdicts.joint_path, verdicts.s_reach)
    clear_of = None if open_hand_clear is None else (
        lambda tested: torch.as_tensor(open_hand_clear(GraspPoses(poses.centre[tested].double(), poses.rotation[tested].double(), "world"))))
    picked = _pick(verdict, seed, n_grasps, dataset, clear_of)
    chosen_rows = poses.rows[picked]
    jaw_limit_m = jaw_width_limit(screened.robot, planner)
    too_wide = screened.width_m[chosen_rows] > jaw_limit_m
    candidates = GraspCandidates(
        contacts=screened.contacts_world[chosen_rows],
        closing_axis=screened.closing_axis[chosen_rows],
        width_m=screened.width_m[chosen_rows],
        s_geom=screened.s_geom[chosen_rows],
        approach=poses.approach[picked],
        rotation=poses.rotation[picked],
        s_reach=s_reach[picked],
        ik_solution=joint_path[picked, grasp_waypoint_index(config.motion)],
        joint_path=joint_path[picked],
        hand_clearance_m=clearance[picked],
        zone=torch.full((picked.numel(),), -1, dtype=torch.int64),
        s_afford=torch.zeros(picked.numel()),
        s_avoid=torch.zeros(picked.numel()),
        s_task=torch.zeros(picked.numel()),
        score=screened.s_geom[chosen_rows].clone(),
    )
    reasons = tuple(
        _reason(VERDICTS[v], planner, jaw_limit_m, float(c), bool(w))
        for v, c, w in zip(verdict[picked].tolist(), clearance[picked].tolist(), too_wide.tolist())
    )
    return ClassifiedGrasps(candidates, verdict[picked], reasons, verdicts.pool_size, poses.rows.numel())


def _covering_poses(screened: ScreenedCandidates, rows: range, n_approaches: int, dataset: DatasetConfig) -> _Poses:
    """The (candidate, approach) poses of candidates ``rows`` (one cloud's) that cover the object: those
    pose-space non-maximum suppression keeps of every pose."""
    rows = torch.arange(rows.start, rows.stop).repeat_interleave(n_approaches)
    slots = torch.arange(n_approaches).repeat(rows.numel() // n_approaches)
    approach, rotation = screened.frames(rows, slots)
    centre = screened.centre_world[rows]
    covering = pose_nms(centre, rotation, dataset.nms_translation_m, math.radians(dataset.nms_rotation_deg))
    return _Poses(rows[covering], slots[covering], approach[covering], rotation[covering], centre[covering])


def _new_grasps(poses: _Poses, cloud: PerceivedCloud, dataset: DatasetConfig, taken_object: GraspPoses) -> torch.Tensor:
    """(N,) bool: the ``poses`` of ``cloud`` that are not the same grasp as one of ``taken_object``."""
    object_from_world = torch.as_tensor(cloud.object_from_world, dtype=torch.float64)
    centre_object = poses.centre.double() @ object_from_world[:3, :3].T + object_from_world[:3, 3]
    rotation_object = object_from_world[:3, :3] @ poses.rotation.double()
    rotation_threshold = math.radians(dataset.nms_rotation_deg)
    return ~same_grasp(centre_object, rotation_object, taken_object.position, taken_object.rotation, dataset.nms_translation_m, rotation_threshold).any(dim=1)


def _planner_verdicts(screened: ScreenedCandidates, config: Config, poses: _Poses) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each pose's verdict, its checks run in the planner's order, each on the poses every earlier
    one passed: (N,) verdict index, (N,) swept clearance (inf where not reached), (N, W, 7) joint
    path and (N,) S_reach (zeros where not reached)."""
    rows, slots, approach, rotation, centre = poses.rows, poses.slots, poses.approach, poses.rotation, poses.centre
    n = rows.numel()
    verdict = torch.full((n,), FEASIBLE, dtype=torch.int64)
    verdict[~screened.clear_of_table(rows, rotation[:, None])[:, 0]] = VERDICTS.index("table")
    undecided = (verdict == FEASIBLE).nonzero().squeeze(1)
    if undecided.numel():
        single = torch.ones(undecided.numel(), 1, dtype=torch.bool)
        volume_ok = screened.volume_within(rows[undecided], rotation[undecided, None], single)[:, 0]
        verdict[undecided[~volume_ok]] = VERDICTS.index("volume")
    clearance = torch.full((n,), math.inf)
    undecided = (verdict == FEASIBLE).nonzero().squeeze(1)
    if undecided.numel():
        swept = screened.hand_clearance(rows[undecided], slots[undecided])
        clearance[undecided] = swept.clearance_m
        verdict[undecided[swept.blocked]] = VERDICTS.index("hand_sweep")
    joint_path = torch.zeros(n, waypoint_count(config.motion), screened.robot.n_arm_joints)
    s_reach = torch.zeros(n)
    undecided = (verdict == FEASIBLE).nonzero().squeeze(1)
    if undecided.numel():
        motion = motion_checker(config)(centre[undecided], approach[undecided], rotation[undecided])
        verdict[undecided[motion.rejected_by[:, 0] == 1]] = VERDICTS.index("grasp_ik")
        verdict[undecided[motion.rejected_by[:, 1] == 1]] = VERDICTS.index("motion")
        joint_path[undecided] = motion.joint_path
        s_reach[undecided] = motion.s_reach
    return verdict, clearance, joint_path, s_reach


def _pick(verdict: torch.Tensor, seed: int, n_grasps: int, dataset: DatasetConfig,
          clear_of: Callable[[torch.Tensor], torch.Tensor] | None) -> torch.Tensor:
    """The grasps a dataset takes: across the planner's verdicts (``tabletop``), or alike from every
    direction (``floating``: the arm's reach and the table do not bear on a floating object); in both,
    at most ``geometry_verdict_fraction`` of them from each class geometry alone fails: the protocol's
    ``geometry_verdicts``, or, where ``clear_of`` (pose indices -> bool) says which open hands stay out
    of the object's mesh, the rest (``_pick_clear``)."""
    cap = int(dataset.geometry_verdict_fraction * n_grasps)
    protocol = label_protocol(dataset.protocol)
    if clear_of is not None and not protocol.table:
        return _pick_clear(verdict.numel(), seed, n_grasps, cap, clear_of)
    geometry = [VERDICTS.index(name) for name in protocol.geometry_verdicts]
    caps = dict.fromkeys(geometry, cap)
    if protocol.table:
        return _pick_across_verdicts(verdict, seed, n_grasps, dataset.feasible_fraction, caps)
    drawn_alike = torch.where(torch.isin(verdict, torch.tensor(geometry)), verdict, torch.full_like(verdict, FEASIBLE))
    return _pick_across_verdicts(drawn_alike, seed, n_grasps, 1.0, caps)


def _pick_clear(n: int, seed: int, n_grasps: int, cap: int, clear_of: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """A floating dataset's picks: ``n_grasps`` open hands the mesh leaves clear, drawn at random
    (``_pick_across_verdicts``'s draw), and at most ``cap`` colliding ones where the clear run short.

    The draw's order is tested in blocks that double, and stops once it holds ``n_grasps`` clear
    hands: those are the picks a test of every pose gives (the colliding take none then), and the mesh
    test of thousands of poses, most of a floating capture's planning time, is spared; an object whose
    open hands mostly collide is still tested in a few calls."""
    order = torch.randperm(n, generator=torch.Generator().manual_seed(int(seed)))
    clear = torch.zeros(n, dtype=torch.bool)
    start, end = 0, min(n, max(CLEAR_TEST_BLOCK, 2 * n_grasps))
    while start < n:
        clear[order[start:end]] = clear_of(order[start:end])
        found = order[:end][clear[order[:end]]]
        if len(found) >= n_grasps:
            return found[:n_grasps].sort().values
        start, end = end, min(n, 2 * end)
    colliding = VERDICTS.index("volume")  # a class to draw by, not the verdict recorded
    classes = torch.where(clear, torch.full((n,), FEASIBLE), torch.full((n,), colliding))
    return _pick_across_verdicts(classes, seed, n_grasps, 1.0, {colliding: cap})


def _pick_across_verdicts(verdict: torch.Tensor, seed: int, n_grasps: int, feasible_fraction: float,
                          caps: dict[int, int] | None = None) -> torch.Tensor:
    """Indices of the picked grasps, in S_geom order: each verdict's quota (``_verdict_quotas``, at
    most ``caps``) drawn at random (``seed``) among its grasps."""
    n = verdict.numel()
    generator = torch.Generator().manual_seed(int(seed))
    order = torch.randperm(n, generator=generator)
    available = {v: count for v, count in enumerate(torch.bincount(verdict, minlength=len(VERDICTS)).tolist()) if count}
    quotas = _verdict_quotas(available, n_grasps, feasible_fraction, caps)
    picked = torch.cat([order[verdict[order] == v][:quota] for v, quota in quotas.items()] or [torch.zeros(0, dtype=torch.int64)])
    return picked.sort().values  # back in S_geom order
