"""Verdicts computed ahead of the candidate search: the screens in blocks sized by the survival
rate seen so far, the motion checks in as few rounds as the search allows. A verdict depends on
its own grasp alone, so computing it ahead changes no result; it only moves work between batches."""
from __future__ import annotations

import math
from collections.abc import Callable

import torch

from .motion_check import MotionCheck
from .screens import ScreenedCandidates
from .search import CandidateSearch, CandidateStatus, SearchTuning, segment_exclusive_cumsum


class ScreenVerdicts:
    """Table, gripper-volume and swept-hand verdicts of candidates, computed ahead of the search's
    window and applied (counted, stored) only when the window reaches them."""

    def __init__(self, screened: ScreenedCandidates, tuning: SearchTuning):
        self.screened = screened
        self.tuning = tuning
        n_candidates, n_approaches, device = screened.n_candidates, screened.planner.n_approaches, screened.object_index.device
        self.ready = torch.zeros(n_candidates, dtype=torch.bool, device=device)
        self.usable = torch.zeros(n_candidates, n_approaches, dtype=torch.bool, device=device)  # table, volume and hand clear
        # (A,) some approach usable, kept as verdicts come: the window asks every round.
        self.any_usable = torch.zeros(n_candidates, dtype=torch.bool, device=device)
        # Those candidates' rows, ascending (ranking order within each object): the motion lookahead
        # walks them every round, and they are few where candidates are many.
        self.usable_rows = torch.zeros(0, dtype=torch.int64, device=device)
        # (B,) candidates with verdicts per object, counted as they come for the same reason
        self.computed = torch.zeros(screened.n_objects, dtype=torch.int64, device=device)
        self.hand_blocked = torch.zeros(n_candidates, n_approaches, dtype=torch.bool, device=device)
        self.clearance_m = torch.full((n_candidates, n_approaches), float("inf"), device=device)

    def block_sizes(self, missing: torch.Tensor) -> torch.Tensor:
        """(B,) candidates to compute next per object, given (B,) ``missing``: candidates in its
        window without verdicts. The survival rate seen so far says how many are needed; a block
        adds at most half of what is computed (at least ``min_block_growth``), since survival grows
        down a mug's ranking (its top pairs lie on the rim and body, where the hand hits) and the
        early rate would overshoot."""
        computed, survived = self.computed, self.usable_per_object()
        margin, growth = self.tuning.lookahead_margin, self.tuning.min_block_growth
        rate_based = (missing * margin * computed.clamp_min(1) / survived.clamp_min(1)).ceil().to(torch.int64)
        return torch.minimum(rate_based, missing + (computed // 2).clamp_min(growth)).clamp_min(missing)

    def usable_per_object(self) -> torch.Tensor:
        """(B,) int64 candidates with verdicts and a usable approach, per object."""
        return torch.bincount(self.screened.object_index[self.usable_rows], minlength=self.screened.n_objects)

    def compute_ahead(self, unknown: torch.Tensor, missing: torch.Tensor) -> None:
        """Verdicts for each object's first ``block_sizes(missing)`` candidates, in ranking order,
        among the (A,) ``unknown`` ones; (B,) ``missing``: candidates each object needs verdicts for."""
        candidate_object = self.screened.object_index
        block = self.block_sizes(missing)
        rank = segment_exclusive_cumsum(unknown.to(torch.int64), candidate_object, missing.shape[0])
        rows = (unknown & (rank < block[candidate_object])).nonzero().squeeze(1)
        if rows.numel():  # none where the objects short of candidates have no unknown ones left
            self.compute(rows)

    def compute(self, rows: torch.Tensor) -> None:
        clock = self.screened.clock
        with clock.stage("frames_volume", rows.numel() * self.usable.shape[1]):
            self.usable[rows] = self.screened.table_and_volume_ok(rows)
        # The real hand on every approach still usable, so IK rounds only retry for reachability.
        candidate, slots = self.usable[rows].nonzero(as_tuple=True)
        with clock.stage("hand_sweep", candidate.numel()):
            swept = self.screened.hand_clearance(rows[candidate], slots)
            self.clearance_m[rows[candidate], slots] = swept.clearance_m
            self.hand_blocked[rows[candidate[swept.blocked]], slots[swept.blocked]] = True
            self.usable[rows[candidate[swept.blocked]], slots[swept.blocked]] = False
            self.any_usable[rows] = self.usable[rows].any(dim=1)
            self.usable_rows = torch.cat((self.usable_rows, rows[self.any_usable[rows]])).sort().values
            self.computed.index_add_(0, self.screened.object_index[rows], torch.ones_like(rows))
            self.ready[rows] = True


class MotionVerdicts:
    """Motion checks of (candidate, approach) grasps, computed ahead of the search's rounds and
    applied (counted, stored) only when the search reaches them.

    A round has a fixed cost well above a check's, so the checks are gathered into as few rounds
    as the search allows. When a round meets pending grasps without a result, one batch checks the
    grasps the search is expected to need: walking each object's undecided candidates in ranking
    order (the window's, then those past it, screening further where too few are screened), until
    their expected feasible count covers the feasible candidates the object still lacks. A
    candidate counts 1 once an approach it will reach is known feasible, else the share of
    candidates expected to end feasible (observed, with its losses taken ``lookahead_margin`` times
    over). Before any of an object's candidates is decided that share is a guess, and each
    candidate gets only its next approach checked; once it is observed, every unchecked approach a
    candidate may need, so that a candidate whose first approach fails needs no round of its own.
    A round is filled up to ``small_round_checks`` grasps.
    """

    def __init__(
        self, n_candidates: int, n_approaches: int, n_waypoints: int, n_joints: int, max_candidates: int, tuning: SearchTuning,
        device: torch.device,
    ):
        self.tuning = tuning
        self.ready = torch.zeros(n_candidates, n_approaches, dtype=torch.bool, device=device)
        self.feasible = torch.zeros(n_candidates, n_approaches, dtype=torch.bool, device=device)
        self.grasp_ik_rejected = torch.zeros(n_candidates, n_approaches, dtype=torch.bool, device=device)  # else, if infeasible, the motion
        # Joint paths and IK margins of the feasible grasps only (a few hundred), and where each is.
        self.kept_index = torch.full((n_candidates, n_approaches), -1, dtype=torch.int32, device=device)
        self.kept_paths = torch.zeros(0, n_waypoints, n_joints, device=device)
        self.kept_s_reach = torch.zeros(0, device=device)
        self.max_candidates = max_candidates
        # Candidates with any grasp checked, ascending: the only ones that can be decided with a
        # usable approach (a few hundred, where the candidates may be hundreds of thousands).
        self.checked_rows = torch.zeros(0, dtype=torch.int64, device=device)

    def outcomes(self, search: CandidateSearch, screens: ScreenVerdicts) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per object (B,): the share of candidates with a usable approach expected to end feasible
        (their observed loss rate, with the prior, taken ``lookahead_margin`` times over); bool,
        whether any of its candidates with a usable approach is decided; and float, the feasible
        candidates it still lacks."""
        tuning = self.tuning
        status = search.status[self.checked_rows]
        row_object = screens.screened.object_index[self.checked_rows]
        count = torch.zeros(screens.screened.n_objects, dtype=torch.float32, device=row_object.device)
        exhausted = count.index_add(0, row_object, (status == CandidateStatus.EXHAUSTED).to(torch.float32))
        decided_count = count.index_add(0, row_object, (status != CandidateStatus.UNDECIDED).to(torch.float32))
        feasible = count.index_add(0, row_object, (status == CandidateStatus.FEASIBLE).to(torch.float32))
        share = (exhausted + tuning.prior_exhausted_share * tuning.prior_weight) / (decided_count + tuning.prior_weight)
        success = (1 - tuning.lookahead_margin * share).clamp_min(tuning.min_success_share)
        return success, decided_count > 0, (self.max_candidates - feasible).clamp_min(0)

    def ensure(
        self, pending: torch.Tensor, slots: torch.Tensor, search: CandidateSearch, screens: ScreenVerdicts,
        check: Callable[[torch.Tensor, torch.Tensor], MotionCheck],
    ) -> None:
        """Have results for the (``pending``, ``slots``) grasps, checking ahead (see the class) where one is missing."""
        missing = ~self.ready[pending, slots]
        if not missing.any():
            return
        small_round = self.tuning.small_round_checks
        candidate_object = screens.screened.object_index
        n_objects = screens.screened.n_objects
        success, observed, needed = self.outcomes(search, screens)
        check_all = observed | (int(missing.sum()) < small_round)
        with_missing = torch.zeros(n_objects, dtype=torch.bool, device=pending.device)
        with_missing[candidate_object[pending[missing]]] = True
        fill = torch.where(with_missing, math.ceil(small_round / int(with_missing.sum())), 0)
        rows, grasps, supply = self._open_candidates(search, screens, success, check_all)
        # Screen further where the screened candidates are expected to fall short.
        short = self._candidates_short(needed, fill, success, rows, grasps, supply, candidate_object)
        unknown = (search.status == CandidateStatus.UNDECIDED) & ~screens.ready
        if (short > 0).any() and unknown.any():
            screens.compute_ahead(unknown, short)
            rows, grasps, supply = self._open_candidates(search, screens, success, check_all)
        row_object = candidate_object[rows]
        taken = (segment_exclusive_cumsum(supply, row_object, n_objects) < needed[row_object]) | (
            segment_exclusive_cumsum(grasps.sum(dim=1), row_object, n_objects) < fill[row_object]
        )
        taken_rows, taken_slots = (grasps & taken[:, None]).nonzero(as_tuple=True)
        n_approaches = self.ready.shape[1]
        keys = torch.cat((rows[taken_rows] * n_approaches + taken_slots, pending[missing] * n_approaches + slots[missing])).unique()
        check_rows, check_slots = keys // n_approaches, keys % n_approaches
        self.store(check_rows, check_slots, check(check_rows, check_slots))

    def screening_shortfall(self, search: CandidateSearch, screens: ScreenVerdicts) -> torch.Tensor:
        """(B,) int64 usable candidates each object is expected to need screened beyond those it has,
        for the feasible candidates it still lacks (0 before any outcome is observed): what the next
        round's lookahead would screen."""
        success, observed, needed = self.outcomes(search, screens)
        rows, grasps, supply = self._open_candidates(search, screens, success, observed)
        # Before any outcome the success share is the prior's guess, and blocks sized for it would
        # overshoot on an object whose candidates mostly fail.
        needed = torch.where(observed, needed, 0)
        return self._candidates_short(
            needed, torch.zeros_like(observed, dtype=torch.int64), success, rows, grasps, supply, screens.screened.object_index
        )

    def _open_candidates(
        self, search: CandidateSearch, screens: ScreenVerdicts, success: torch.Tensor, check_all: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The candidates the search may still reach, (C,) rows in ranking order (undecided, with a
        usable approach by the screens); the (C, K) unchecked approaches each needs before its
        outcome is known (all of them where its object's ``check_all``, else the next one); and
        (C,) its expected feasible count: 1 where an approach it will reach is known feasible, its
        object's ``success`` where one is still unchecked, else 0."""
        rows = screens.usable_rows[search.status[screens.usable_rows] == CandidateStatus.UNDECIDED]
        n_approaches = self.ready.shape[1]
        order = torch.arange(n_approaches, device=rows.device)
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
        expected = torch.zeros(n_objects, dtype=torch.float64, device=rows.device).index_add_(0, row_object, supply)
        checks = torch.zeros(n_objects, dtype=torch.int64, device=rows.device).index_add_(0, row_object, grasps.sum(dim=1))
        for_needed = ((needed - expected).clamp_min(0) / success).ceil().to(torch.int64)
        return torch.maximum(for_needed, (fill - checks).clamp_min(0))

    def store(self, rows: torch.Tensor, slots: torch.Tensor, motion: MotionCheck) -> None:
        feasible = motion.feasible
        self.ready[rows, slots] = True
        self.checked_rows = torch.cat((self.checked_rows, rows)).unique()
        self.feasible[rows, slots] = feasible
        self.grasp_ik_rejected[rows, slots] = motion.rejected_by[:, 0].bool()
        self.kept_index[rows[feasible], slots[feasible]] = torch.arange(int(feasible.sum()), dtype=torch.int32, device=rows.device) + self.kept_paths.shape[0]
        self.kept_paths = torch.cat((self.kept_paths, motion.joint_path[feasible]))
        self.kept_s_reach = torch.cat((self.kept_s_reach, motion.s_reach[feasible]))

    def verdicts(self, rows: torch.Tensor, slots: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(R,) bool feasible and (R, 2) int64 ``MotionCheck.rejected_by`` of (``rows``, ``slots``) grasps, all checked."""
        feasible, grasp_ik = self.feasible[rows, slots], self.grasp_ik_rejected[rows, slots]
        return feasible, torch.stack((grasp_ik, ~feasible & ~grasp_ik), dim=1).to(torch.int64)

    def kept(self, rows: torch.Tensor, slots: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(R, W, J) joint paths and (R,) IK margins of (``rows``, ``slots``) grasps, all feasible."""
        index = self.kept_index[rows, slots].to(torch.int64)
        return self.kept_paths[index], self.kept_s_reach[index]


def window_with_verdicts(
    search: CandidateSearch, verdicts: ScreenVerdicts, motions: MotionVerdicts, max_candidates: int,
) -> torch.Tensor:
    """(A,) bool: each object's first ``max_candidates`` candidates still alive, with the screens'
    verdicts computed for every candidate in it.

    With verdicts known for the whole window, the window of the first candidates still alive after
    screening is the fixed point that screening round by round (each round moving the window past
    the candidates it exhausted) reaches, and it screens the same candidates. Verdicts are computed
    ahead, in blocks sized by the survival rate seen so far, so an object where few candidates
    survive takes a few blocks, not one round per window each recounting every candidate's window.
    The blocks also cover the usable candidates the next motion round's lookahead is expected to
    want past the window (``MotionVerdicts.screening_shortfall``, estimated once), which it would
    otherwise screen in a call of its own.
    """
    candidate_object, n_objects = verdicts.screened.object_index, verdicts.screened.n_objects
    usable_target = None  # (B,) usable candidates each object is expected to need screened in all
    while True:
        waiting = (search.status == CandidateStatus.UNDECIDED) & ~search.screened
        unknown = waiting & ~verdicts.ready
        alive = torch.where(waiting & verdicts.ready, verdicts.any_usable, search.status != CandidateStatus.EXHAUSTED)
        in_window = segment_exclusive_cumsum(alive.to(torch.int64), candidate_object, n_objects) < max_candidates
        missing = unknown & in_window
        if not missing.any():
            return in_window
        wanted = torch.zeros(n_objects, dtype=torch.int64, device=missing.device).index_add_(0, candidate_object, missing.to(torch.int64))
        usable = verdicts.usable_per_object()
        if usable_target is None:
            usable_target = usable + motions.screening_shortfall(search, verdicts)
        verdicts.compute_ahead(unknown, torch.maximum(wanted, usable_target - usable))
