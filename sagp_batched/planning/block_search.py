"""The candidate search in blocks of a few sizes: every verdict of a block's candidates at once.

The lookahead search (``lookahead``) reaches each object's first ``max_candidates`` executable
candidates in rounds sized by the survival seen so far: few wasted checks, but many small calls and
bookkeeping whose shapes follow the data. Here each object's candidates are taken in blocks whose
sizes are powers of two (``next_block_size``); a block gets the screens on every approach (the
same verdict kernels, ``ScreenVerdicts.compute``) and the motion check on the approaches the
screens leave usable, in two calls. The answer is the lookahead's: a candidate is feasible at its
first approach in prior order that passes every check, an object keeps its first
``max_candidates`` feasible candidates in S_geom order, and the counts are those of the candidates
up to its last kept one. A block checks more grasps (later usable approaches of candidates whose
first fails; the candidates of its block past the last kept one) in fewer calls of a few shapes.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import torch

from .lookahead import MotionVerdicts, ScreenVerdicts
from .motion_check import MotionCheck
from .search import CandidateSearch, CandidateStatus, segment_exclusive_cumsum

# A plan's first block per object: the soup can's 200 feasible candidates lie within its first 464
# ranked ones, the cracker box's within 819 (YCB clouds at 5,000 pairs), so one or two blocks reach
# most objects' last kept candidate.
FIRST_BLOCK_CANDIDATES = 512
# The smallest and largest later blocks: below the first, a block's calls cost more than its
# checks; above the last, an object whose candidates mostly fail (a mug's, 16 feasible in 3,772)
# is still screened in a few calls while a block's work stays within the screens' memory bounds.
MIN_BLOCK_CANDIDATES = 256
MAX_BLOCK_CANDIDATES = 4096
# Expected losses taken this many times over, so that one more block usually suffices.
BLOCK_MARGIN = 1.25


def next_block_size(searched: int, found: int, wanted: int) -> int:
    """Candidates in an object's next block, once ``searched`` of them gave ``found`` feasible ones of
    the ``wanted`` it keeps: the first block ``FIRST_BLOCK_CANDIDATES``; then those the yield so far
    says are still needed, ``BLOCK_MARGIN`` times over, rounded up to a power of two (so a plan's
    blocks come in a few sizes) within [``MIN_BLOCK_CANDIDATES``, ``MAX_BLOCK_CANDIDATES``]; an
    object with none found yet doubles what it searched."""
    if searched == 0:
        return FIRST_BLOCK_CANDIDATES
    needed = BLOCK_MARGIN * (wanted - found) * searched / found if found else 2 * searched
    return min(MAX_BLOCK_CANDIDATES, max(MIN_BLOCK_CANDIDATES, 1 << max(0, math.ceil(needed) - 1).bit_length()))


def search_in_blocks(
    screens: ScreenVerdicts, motions: MotionVerdicts, max_candidates: int, check: Callable[[torch.Tensor, torch.Tensor], MotionCheck],
) -> CandidateSearch:
    """Each object's first ``max_candidates`` feasible candidates, searched block by block: the
    screens' verdicts land in ``screens`` and the motion checks' in ``motions`` (``check`` checks
    (rows, slots) grasps), and the returned ``CandidateSearch`` holds what the lookahead search
    would hold at its end (status, approach, clearance and rejections of the candidates it reached)."""
    screened = screens.screened
    object_index, n_objects = screened.object_index, screened.n_objects
    device = object_index.device
    bounds = torch.searchsorted(object_index, torch.arange(n_objects + 1, device=device)).tolist()
    searched, found = [0] * n_objects, [0] * n_objects
    while True:
        objects = [index for index in range(n_objects) if found[index] < max_candidates and bounds[index] + searched[index] < bounds[index + 1]]
        if not objects:
            break
        spans = []
        for index in objects:
            first = bounds[index] + searched[index]
            end = min(first + next_block_size(searched[index], found[index], max_candidates), bounds[index + 1])
            spans.append((first, end))
            searched[index] += end - first
        rows = torch.cat([torch.arange(first, end, device=device) for first, end in spans])
        screens.compute(rows)
        _check_motions_of_block(rows, screens, motions, check)
        block_found = torch.bincount(object_index[rows], weights=(screens.usable[rows] & motions.feasible[rows]).any(dim=1).to(torch.float32),
                                     minlength=n_objects)
        for index, count in zip(objects, block_found[objects].tolist()):
            found[index] += int(count)
    return _search_state(screens, motions, max_candidates)


def _check_motions_of_block(
    rows: torch.Tensor, screens: ScreenVerdicts, motions: MotionVerdicts, check: Callable[[torch.Tensor, torch.Tensor], MotionCheck],
) -> None:
    """The motion checks the block's candidates ``rows`` need, in two calls: each one's first
    usable approach, then every later usable approach of those whose first one failed. Checking
    every usable approach at once took 1.6-2.2x the motion stage's time on the cracker box and the
    soup can (most first approaches pass); more calls would be one per approach position."""
    usable = screens.usable[rows]
    n_approaches = usable.shape[1]
    order = torch.arange(n_approaches, device=rows.device)
    first = torch.where(usable, order, n_approaches).amin(dim=1)
    with_usable = (first < n_approaches).nonzero().squeeze(1)
    if with_usable.numel() == 0:
        return
    motions.store(rows[with_usable], first[with_usable], check(rows[with_usable], first[with_usable]))
    first_failed = torch.zeros_like(usable)
    first_failed[with_usable] = ~motions.feasible[rows[with_usable], first[with_usable]][:, None]
    later_rows, later_slots = (usable & first_failed & (order > first[:, None])).nonzero(as_tuple=True)
    if later_rows.numel():
        motions.store(rows[later_rows], later_slots, check(rows[later_rows], later_slots))


def _search_state(screens: ScreenVerdicts, motions: MotionVerdicts, max_candidates: int) -> CandidateSearch:
    """The ``CandidateSearch`` the lookahead search ends with, from every block's verdicts: a
    candidate is reached when fewer than ``max_candidates`` of its object's feasible candidates
    rank before it; each reached candidate's approaches are tried in prior order up to its first
    feasible one (all usable ones where none is), and each tried one that fails counts as a
    rejection by the grasp IK or by the motion."""
    screened = screens.screened
    object_index, n_objects = screened.object_index, screened.n_objects
    n_candidates, n_approaches = screens.usable.shape
    order = torch.arange(n_approaches, device=object_index.device)
    feasible_pose = screens.usable & motions.feasible
    feasible = feasible_pose.any(dim=1)
    first_feasible = torch.where(feasible_pose, order, n_approaches).amin(dim=1)
    feasible_before = segment_exclusive_cumsum(feasible.to(torch.int64), object_index, n_objects)
    reached = screens.ready & (feasible_before < max_candidates)
    tried = screens.usable & (order <= first_feasible[:, None]) & reached[:, None]
    failed = tried & ~feasible_pose
    grasp_ik = failed & motions.grasp_ik_rejected
    rejected = torch.stack((torch.where(reached, screens.hand_blocked.sum(dim=1), 0), grasp_ik.sum(dim=1), (failed & ~grasp_ik).sum(dim=1)),
                           dim=1)
    status = torch.where(reached & feasible, CandidateStatus.FEASIBLE,
                         torch.where(reached, CandidateStatus.EXHAUSTED, CandidateStatus.UNDECIDED))
    return CandidateSearch(
        usable=screens.usable,
        next_usable=torch.full((n_candidates, n_approaches + 1), n_approaches, device=object_index.device),
        cursor=first_feasible,
        screened=reached,
        status=status,
        clearance_m=screens.clearance_m,
        rejected=rejected,
    )
