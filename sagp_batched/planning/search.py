"""The candidate search: for each screened candidate, its first executable approach in prior order.

``plan_batch`` keeps each object's first ``max_candidates`` candidates that can still be feasible
(its window), applies the screens to the window, then the motion check to each undecided
candidate's next approach, round after round, until every object's window is decided. The result
equals trying candidates one by one in S_geom order, each approach in prior order, until
``max_candidates`` are feasible (what ``reference.plan_reference`` does). Verdicts are computed
ahead of the rounds in batches (``lookahead``) and applied only when a round reaches them.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from .lookahead import ScreenVerdicts


class CandidateStatus(enum.IntEnum):
    """Where a candidate's search stands."""

    UNDECIDED = 0  # an untried approach that passed the screens is left
    FEASIBLE = 1  # an approach passed the motion check
    EXHAUSTED = 2  # no approach is left


@dataclass(frozen=True)
class SearchTuning:
    """How far ahead the search computes verdicts: these move work between batches, never a result."""

    # Expected losses are taken this many times over, so that one block of screens, or one round
    # of motion checks, usually suffices.
    lookahead_margin: float = 1.25
    # A block of screens may add this many candidates beyond those needed even where half the
    # computed ones are fewer: where few candidates survive, growing by halves from a small block
    # costs many calls of fixed cost, while a candidate's screens cost little.
    min_block_growth: int = 1024
    # The share of candidates that run out of approaches before any is decided, and how many
    # decided candidates it weighs as: a guess the first observations soon outweigh.
    prior_exhausted_share: float = 0.1
    prior_weight: int = 4
    # Where nearly every candidate is lost, the expected feasible share used is at least this: the
    # lookahead stays within ten times the feasible candidates still needed, and later rounds
    # correct a shortfall.
    min_success_share: float = 0.1
    # A round of motion checks is filled up to this many grasps: a round's fixed cost buys them
    # at little more.
    small_round_checks: int = 32


def segment_exclusive_cumsum(values: torch.Tensor, object_index: torch.Tensor, n_objects: int) -> torch.Tensor:
    """Exclusive running sum of ``values`` restarting at each object (rows sorted by object)."""
    exclusive = torch.cumsum(values, 0) - values
    if n_objects == 1:  # a single plan's rows (hundreds of thousands at 500,000 pairs) need no restarts
        return exclusive
    first_row = torch.searchsorted(object_index, torch.arange(n_objects, device=object_index.device))
    base = torch.zeros(n_objects, dtype=values.dtype, device=values.device)
    has_rows = first_row < object_index.shape[0]
    base[has_rows] = exclusive[first_row[has_rows]]
    return exclusive - base[object_index]


@dataclass
class CandidateSearch:
    """Where the search for each screened candidate's first executable approach stands.

    Approaches are tried in prior order: a candidate is UNDECIDED while an untried approach that
    passed the screens is left (``cursor``), FEASIBLE once one passes the motion check, EXHAUSTED
    when none is left.
    """

    usable: torch.Tensor  # (A, K) bool: approach passed table, gripper volume and swept hand
    next_usable: torch.Tensor  # (A, K + 1) first usable approach at or after prior position k (K: none left)
    cursor: torch.Tensor  # (A,) approach to try next (K: none)
    screened: torch.Tensor  # (A,) bool: the screens' verdicts are applied
    status: torch.Tensor  # (A,) int64 ``CandidateStatus``
    clearance_m: torch.Tensor  # (A, K) swept hand's clearance where computed
    rejected: torch.Tensor  # (A, 3) int64 rejections per candidate: hand, grasp IK, motion

    @classmethod
    def start(cls, n_candidates: int, n_approaches: int, device: torch.device) -> CandidateSearch:
        # Candidates without a table-clear approach are found, and exhausted, when screened.
        return cls(
            usable=torch.zeros(n_candidates, n_approaches, dtype=torch.bool, device=device),
            next_usable=torch.full((n_candidates, n_approaches + 1), n_approaches, device=device),
            cursor=torch.full((n_candidates,), n_approaches, device=device),
            screened=torch.zeros(n_candidates, dtype=torch.bool, device=device),
            status=torch.full((n_candidates,), CandidateStatus.UNDECIDED, device=device),
            clearance_m=torch.full((n_candidates, n_approaches), float("inf"), device=device),
            rejected=torch.zeros(n_candidates, 3, dtype=torch.int64, device=device),
        )

    def apply_screens(self, rows: torch.Tensor, verdicts: ScreenVerdicts) -> None:
        """The screens' verdicts of candidates ``rows``: each moves to its first usable approach."""
        n_approaches = self.usable.shape[1]
        self.usable[rows] = verdicts.usable[rows]
        self.clearance_m[rows] = verdicts.clearance_m[rows]
        self.rejected[rows, 0] += verdicts.hand_blocked[rows].sum(dim=1)
        self.screened[rows] = True
        first_usable = torch.where(self.usable[rows], torch.arange(n_approaches, device=rows.device), n_approaches)
        first_usable = torch.cat((first_usable, torch.full((rows.numel(), 1), n_approaches, device=rows.device)), dim=1)
        self.next_usable[rows] = first_usable.flip(1).cummin(1).values.flip(1)
        self.cursor[rows] = self.next_usable[rows, 0]
        self.status[rows] = torch.where(self.cursor[rows] < n_approaches, CandidateStatus.UNDECIDED, CandidateStatus.EXHAUSTED)

    def apply_motions(self, rows: torch.Tensor, slots: torch.Tensor, feasible: torch.Tensor, rejected_by: torch.Tensor) -> None:
        """The motion checks' (R,) ``feasible`` and (R, 2) ``rejected_by`` of (``rows``, ``slots``) grasps."""
        self.rejected[rows, 1:] += rejected_by
        self.status[rows[feasible]] = CandidateStatus.FEASIBLE
        retry = rows[~feasible]
        self.cursor[retry] = self.next_usable[retry, slots[~feasible] + 1]
        self.status[retry] = torch.where(self.cursor[retry] < self.usable.shape[1], CandidateStatus.UNDECIDED, CandidateStatus.EXHAUSTED)
