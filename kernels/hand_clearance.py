"""Clearance between point clouds and a gripper's collision hulls bounded by k-DOPs.

A k-DOP is a convex polytope given by its extent [low_d, high_d] along D fixed unit directions.
For a point p (in the polytope's frame) the separation

    s(p) = max_d max(p . u_d - high_d, low_d - p . u_d)

is positive outside the polytope and a lower bound on p's Euclidean distance to it (each term is
the distance to one supporting slab), and <= 0 inside. The gripper is several such polytopes in
the grasp frame (origin at the grasp centre, see ``grasp_frames``); a point's separation from
the gripper is its smallest separation from any of them.

The same maximum over only the first three directions is a lower bound of s(p) at a quarter of
the cost. It picks the points likely to strike a gripper first and rules out points that cannot
change the answer, so s(p) is evaluated on a few dozen of a scene's ~1,000 points. Over all the
points it is taken from world coordinates, u . p - u . centre, so that only the few points
evaluated exactly are moved to the grasp centre.
"""
from __future__ import annotations

from typing import NamedTuple

import torch

from .compiled import MIN_COMPILED_ROWS, compiled, padded_rows

# Runs of consecutive probe points (a coarse voxel subset, so roughly regions of the scene) whose
# least-bound probe has its exact separation evaluated first: a blocked grasp almost always has
# one of them under the margin. Four such probes, not eight or the 16 nearest overall (a per-row
# partition): the few more grasps those find blocked save less than their selection costs.
PROBE_RUNS = 4
# The lower bound's float32 rounding on points about the grasp centre (~1e-8 m at gripper sizes)
# is far inside this slack.
BOUND_SLACK_M = 1e-6
# The point pass bounds from world coordinates, a_d . p - (a_d . c + m_d), where rounding scales
# with the coordinates' magnitude L rather than the gripper's: each of the two computations (that
# and the exact separation's from fl(p - c)) is within 40 float32 unit roundoffs of L of the real
# slab excess (three-term products of unit axes and coordinates up to 2 L, and the subtractions
# after them), so 64 machine epsilons of L more slack (128 unit roundoffs, ~8e-6 m at 1 m) keep
# the bound under every exact separation it rules out.
RAW_ROUNDING_EPS = 64 * torch.finfo(torch.float32).eps
# MKL's batched GEMM rounds like the exhaustive product only from 12 columns up.
MIN_GEMM_COLUMNS = 16
# Rows whose exact separations are evaluated together, padded to the most candidate points of any
# of them: rows sorted by that count waste little padding in buckets of this many.
SEPARATION_BUCKET_ROWS = 256
# (candidate, polytope, axis, probe) elements of the probes' bound computed at once: blocks of
# ~2 MB temporaries, between smaller blocks' extra rounds and larger ones' cache misses.
PROBE_BLOCK_ELEMENTS = 524_288


class HandClearance(NamedTuple):
    blocked: torch.Tensor  # (C,) bool: some point's separation from the gripper is under the margin
    # (C,) float32 smallest separation of any point where not blocked (inf without points); where
    # blocked, the smallest among the points evaluated (which ones is a heuristic's choice), an
    # upper bound of it under the margin.
    clearance_m: torch.Tensor


def _least_excess(projection: torch.Tensor, middle: torch.Tensor, half: torch.Tensor, compile: bool = False) -> torch.Tensor:
    """(c, n) the largest slab excess |projection - middle| - half over directions, least over
    polytopes, NaN -> inf, for (d, c, n) projections and (S, d, c or 1, 1) slabs; ``compile``: by
    the compiled ``_fused_least_excess``, whose exact operations give the same values.

    Directions and polytopes lead: their reductions then run along whole (c, n) planes, not
    over a short middle dimension. In place on the one temporary: these are the
    sweep's largest tensors (MBs a block), and fresh allocations of that size cost as much as the
    arithmetic."""
    if compile and min(projection.shape[1:]) >= MIN_COMPILED_ROWS:
        return compiled(_fused_least_excess)(projection, middle, half)
    excess = (projection - middle).abs_().sub_(half).amax(dim=1).amin(dim=0)
    return torch.nan_to_num(excess, nan=float("inf"))


def _fused_least_excess(projection: torch.Tensor, middle: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """``_least_excess``, one polytope at a time, fused (for ``compiled``): differences, absolute
    values, maxima and minima are exact, so every value is the eager one."""
    least = None
    for polytope in range(middle.shape[0]):
        excess = ((projection - middle[polytope]).abs() - half[polytope]).amax(dim=0)
        least = excess if least is None else torch.minimum(least, excess)
    return torch.nan_to_num(least, nan=float("inf"))


def separation(relative: torch.Tensor, axes: torch.Tensor, middle: torch.Tensor, half: torch.Tensor, compile: bool) -> torch.Tensor:
    """(c, n) separation s(p) of points ``relative`` (c, n, 3) from the polytopes, NaN rows -> inf."""
    n_points = relative.shape[1]
    if n_points < MIN_GEMM_COLUMNS:
        relative = torch.cat((relative, relative.new_full((relative.shape[0], MIN_GEMM_COLUMNS - n_points, 3), float("nan"))), dim=1)
    # Projections on the k-DOP directions in one GEMM: (u_d^T R^T) (p - centre).
    projection = (axes @ relative.transpose(1, 2))[:, :, :n_points].transpose(0, 1).contiguous()  # (D, c, n)
    return _least_excess(projection, middle, half, compile)


def _bound_from_world(
    points: torch.Tensor, axes: torch.Tensor, centre: torch.Tensor, middle: torch.Tensor, half: torch.Tensor, compile: bool = False,
) -> torch.Tensor:
    """(r, N) s(p) over the first three directions, a lower bound of s(p) up to rounding, of the
    rows' scene's (N, 3) ``points`` for rows with (r, 3, 3) ``axes`` and (r, 3) ``centre``;
    ``middle`` and ``half``: (S, D, 1, 1) slabs. NaN rows -> inf.

    a_d . (p - c) - m_d is taken as a_d . p - (a_d . c + m_d): the points stay in the world frame,
    and the projections are one GEMM against them: no (r, N, 3) gather, and no batch of
    (d, 3) x (3, N) products."""
    projection = (axes.transpose(0, 1).reshape(-1, 3) @ points.T).view(axes.shape[1], axes.shape[0], -1)  # (3, r, N)
    offset = (axes @ centre[:, :, None]).view(-1, 3).T[:, :, None] + middle[:, :3]  # (S, 3, r, 1)
    return _least_excess(projection, offset, half[:, :3], compile)


def _least_per_run(bound: torch.Tensor, runs: int) -> torch.Tensor:
    """(c, runs) column of each row's least ``bound`` value (c, runs * length) within each run of
    ``length`` consecutive columns, the first where tied."""
    length = bound.shape[1] // runs
    return bound.view(bound.shape[0], runs, length).argmin(dim=2) + torch.arange(0, bound.shape[1], length, device=bound.device)


def _compacted(points: torch.Tensor, scene: torch.Tensor, centre: torch.Tensor, chosen: torch.Tensor, per_row: torch.Tensor) -> torch.Tensor:
    """(r, max per_row, 3) each row's ``chosen`` (r, N) points of its scene ``points[scene]`` less its
    ``centre``, in index order, then NaN padding; ``per_row``: (r,) ``chosen.sum(dim=1)``.

    Only the chosen points are moved to the grasp centre: the same float32 subtraction as
    ``scene_points_about``'s, so the same bits. Scattered to their places from ``nonzero``'s
    row-major list rather than ordered by a stable sort of the mask, which would sort every
    (row, point) flag."""
    row, point = chosen.nonzero(as_tuple=True)
    slot = torch.arange(row.numel(), device=row.device) - (per_row.cumsum(0) - per_row)[row]
    compact = points.new_full((chosen.shape[0], int(per_row.max()), 3), float("nan"))
    compact[row, slot] = points[scene[row], point] - centre[row]
    return compact


def coordinate_scale(*tensors: torch.Tensor) -> float:
    """The largest coordinate magnitude in ``tensors``, NaN padding ignored."""
    return max((float(t.nan_to_num().abs().amax()) for t in tensors if t.numel()), default=0.0)


def scene_extents(points: torch.Tensor) -> torch.Tensor:
    """(B,) int64 rows of each of (B, N, 3) ``points``' scenes up to its last row without NaN: the
    rows after it are padding, whose separation is inf, so a scene's points end there."""
    if points.shape[1] == 0:
        return torch.zeros(points.shape[0], dtype=torch.int64, device=points.device)
    valid = ~points.isnan().any(dim=-1)
    return (valid * torch.arange(1, points.shape[1] + 1, device=points.device)).amax(dim=1)


def row_blocks(scene: torch.Tensor, width: torch.Tensor, budget: int) -> list[tuple[int, int, int, int]]:
    """Consecutive ranges (start, end, width, scene) of rows of scenes (R,) ``scene``, each of one
    scene's rows, as many as ``budget`` elements allow at that scene's (B,) ``width`` (one row at least).

    A block never mixes scenes: its rows then take one GEMM against their scene's points and its
    probes are cut at their own scene's extent, so a batch's rows are computed in the blocks, and
    with the operations, a plan of their scene alone would use. Walks the runs of equal scenes (a
    scene-sorted batch's few) in Python integers, not the rows."""
    if scene.numel() == 0:
        return []
    run_scene, run_length = torch.unique_consecutive(scene, return_counts=True)
    blocks, start = [], 0
    for run, run_width, count in zip(run_scene.tolist(), width[run_scene].tolist(), run_length.tolist()):
        rows = max(1, budget // max(1, run_width))
        blocks.extend((first, min(first + rows, start + count), run_width, run) for first in range(start, start + count, rows))
        start += count
    return blocks


def _probe_width(extent: int) -> tuple[int, int]:
    """The probe runs of a block whose scenes hold up to ``extent`` probe points, and their length."""
    n_runs = min(PROBE_RUNS, extent)
    return n_runs, (-(-extent // n_runs) if n_runs else 0)


def hand_clearance(
    points: torch.Tensor,
    probe_points: torch.Tensor,
    object_index: torch.Tensor,
    centre: torch.Tensor,
    rotation: torch.Tensor,
    directions: torch.Tensor,
    low: torch.Tensor,
    high: torch.Tensor,
    margin_m: float,
    chunk_elements: int,
    compile: bool = False,
) -> HandClearance:
    """Whether each candidate gripper comes within ``margin_m`` of a point of its scene, and its clearance.

    Args:
        points: (B, N, 3) points of B scenes, world frame, metres; NaN rows are padding.
        probe_points: (B, P, 3) a subset of each scene's points (e.g. one per coarse voxel, NaN
            padded); the least by the lower bound in each of ``PROBE_RUNS`` runs of them are evaluated
            first, to find most blocked grasps without the whole scene.
        object_index: (C,) int64 scene of each candidate, in [0, B).
        centre: (C, 3) grasp-frame origins, world frame.
        rotation: (C, 3, 3) grasp frames (grasp -> world rotation).
        directions: (D, 3) unit k-DOP directions, grasp frame, D >= 3; the first three also
            give the lower bound that culls points (the axes, for box-like hulls).
        low: (S, D) lower extents of S polytopes along ``directions``, metres.
        high: (S, D) upper extents, metres (low <= high).
        margin_m: a point with separation under this blocks the gripper.
        chunk_elements: bound on the (candidate, polytope, direction, point) elements held at once.
        compile: take the lower bound that picks the points evaluated exactly from
            ``_fused_bound_below`` compiled (``compiled``): other roundings within the same slack,
            the same points' exact separations, so the same result.

    Returns:
        ``HandClearance`` of (C,) tensors; every separation it reports is the exhaustive
        computation's for that point, bit for bit, so ``blocked`` is exactly "some point of
        ``points`` is under the margin".

    Each block of candidates takes its scenes' points up to their last real one
    (``scene_extents``), not the padding up to the largest scene's: a batch of scenes of 250 to
    2,000 points would otherwise sweep each candidate over the largest. A block's probes are the
    runs of its scenes' probes so cut, so a scene's candidates probe alike alone and in a batch.
    """
    if points.ndim != 3 or points.shape[-1] != 3 or probe_points.ndim != 3 or probe_points.shape[-1] != 3:
        raise ValueError(f"points and probe_points must be (B, N, 3), got {tuple(points.shape)} and {tuple(probe_points.shape)}")
    if rotation.shape != (centre.shape[0], 3, 3):
        raise ValueError(f"rotation must be (C, 3, 3) matching centre (C, 3), got {tuple(rotation.shape)} and {tuple(centre.shape)}")
    if low.shape != high.shape or low.shape[1] != directions.shape[0] or directions.shape[0] < 3:
        raise ValueError(f"low and high must be (S, D) with D = {directions.shape[0]} >= 3, got {tuple(low.shape)} and {tuple(high.shape)}")
    middle = ((low + high) / 2)[:, :, None, None]  # (S, D, 1, 1)
    half = ((high - low) / 2)[:, :, None, None]
    axes = directions @ rotation.transpose(-1, -2)  # (C, D, 3): u_d^T R^T
    clearance = _probe_clearance(probe_points, object_index, centre, axes, middle, half, chunk_elements, compile)
    slack_m = BOUND_SLACK_M + RAW_ROUNDING_EPS * coordinate_scale(points, centre, low, high)
    clearance = _lowered_by_points(points, object_index, centre, axes, middle, half, clearance, margin_m, slack_m, chunk_elements, compile)
    return HandClearance(clearance < margin_m, clearance)


def _probe_clearance(
    probe_points: torch.Tensor, object_index: torch.Tensor, centre: torch.Tensor, axes: torch.Tensor, middle: torch.Tensor,
    half: torch.Tensor, chunk_elements: int, compile: bool,
) -> torch.Tensor:
    """(C,) each candidate's least exact separation of its probes, the least by the lower bound in
    each run of its block's (B, P, 3) ``probe_points``; inf where its scene has none. ``axes``:
    (C, D, 3) the candidates' k-DOP directions in the world frame; ``middle`` and ``half``:
    (S, D, 1, 1) slabs."""
    clearance = torch.full((centre.shape[0],), float("inf"), device=centre.device)
    probe_extent = scene_extents(probe_points)
    # Probe blocks are sized by the probes' own bound tensor, at their runs' padded width.
    n_runs = probe_extent.clamp_max(PROBE_RUNS)
    padded_extent = n_runs * torch.where(n_runs > 0, -(-probe_extent // n_runs.clamp_min(1)), 0)
    probe_budget = min(chunk_elements, PROBE_BLOCK_ELEMENTS) // max(1, middle.shape[0] * 3)
    for start, end, _, scene in row_blocks(object_index, padded_extent, probe_budget):
        block = slice(start, end)
        n_runs, run_length = _probe_width(int(probe_extent[scene]))
        if not n_runs:
            continue
        # NaN padding to whole runs: its bound is inf, and a run of padding alone gives an inf separation.
        block_probes = torch.nn.functional.pad(
            probe_points[scene, : min(n_runs * run_length, probe_points.shape[1])], (0, 0, 0, max(0, n_runs * run_length - probe_points.shape[1])),
            value=float("nan"),
        )
        # From world coordinates like the point pass: the bound only picks which probes are
        # evaluated, and each evaluated probe's separation is exact whichever are picked.
        picked = _least_per_run(_bound_from_world(block_probes, axes[block, :3], centre[block], middle, half, compile), n_runs)
        probe = block_probes[picked] - centre[block, None, :]  # (c, runs, 3)
        clearance[block] = separation(probe, axes[block], middle, half, compile).amin(dim=1)
    return clearance


def _lowered_by_points(
    points: torch.Tensor, object_index: torch.Tensor, centre: torch.Tensor, axes: torch.Tensor, middle: torch.Tensor,
    half: torch.Tensor, clearance: torch.Tensor, margin_m: float, slack_m: float, chunk_elements: int, compile: bool,
) -> torch.Tensor:
    """(C,) ``clearance`` lowered, where it is at least ``margin_m``, to the least exact separation
    of any of the scene's (B, N, 3) ``points``, evaluated only where the lower bound less
    ``slack_m`` falls under it (``compile``: ``_fused_bound_below``'s); in place. ``axes``,
    ``middle``, ``half``: as for ``_probe_clearance``."""
    # Only where the probes left the gripper clear, in blocks of those candidates; there only
    # points whose bound is under the probes' clearance can block it or lower that clearance.
    # The compiled bound holds no (polytope, direction) elements, only the (row, point) verdicts.
    open_rows = (clearance >= margin_m).nonzero().squeeze(1)
    extent = scene_extents(points)
    for start, end, width, scene_index in row_blocks(object_index[open_rows], extent, chunk_elements // (1 if compile else max(1, middle.numel()))):
        rows = open_rows[start:end]
        scene, row_axes = object_index[rows], axes[rows]
        block_points, scene_points = points[:, :width], points[scene_index, :width]
        if compile:
            candidates = _compiled_bound_below(scene_points, row_axes[:, :3], centre[rows], middle, half, clearance[rows] + slack_m)
        else:
            candidates = _bound_from_world(scene_points, row_axes[:, :3], centre[rows], middle, half) - slack_m < clearance[rows, None]
        per_row = candidates.sum(dim=1)
        # Rows are evaluated in buckets of similar candidate counts: each bucket is padded to its
        # largest count, and a block's counts range from none to ten times their median.
        by_count = per_row.argsort()
        for bucket in by_count[per_row[by_count] > 0].split(SEPARATION_BUCKET_ROWS):
            compact = _compacted(block_points, scene[bucket], centre[rows[bucket]], candidates[bucket], per_row[bucket])
            found = separation(compact, row_axes[bucket], middle, half, compile).amin(dim=1)
            clearance[rows[bucket]] = torch.minimum(clearance[rows[bucket]], found)
    return clearance


def _compiled_bound_below(
    points: torch.Tensor, axes: torch.Tensor, centre: torch.Tensor, middle: torch.Tensor, half: torch.Tensor, limit: torch.Tensor,
) -> torch.Tensor:
    """(r, N) bool: ``_bound_from_world``'s bound of the rows' scene's (N, 3) ``points`` under each
    row's (r,) ``limit``, by the compiled ``_fused_bound_below``. ``axes`` (r, 3, 3), ``centre``
    (r, 3), ``middle`` and ``half`` (S, D, 1, 1) as there."""
    offset = (axes @ centre[:, :, None]).squeeze(2)  # (r, 3): a_d . c
    slab_middle, slab_half = middle[:, :3, 0, 0].contiguous(), half[:, :3, 0, 0].contiguous()
    below = compiled(_fused_bound_below)(
        points.T.contiguous(), padded_rows(axes), padded_rows(offset), slab_middle, slab_half, padded_rows(limit),
    )
    return below[: axes.shape[0]]


def _fused_bound_below(
    columns: torch.Tensor, axes: torch.Tensor, offset: torch.Tensor, middle: torch.Tensor, half: torch.Tensor, limit: torch.Tensor
) -> torch.Tensor:
    """(r, N) bool: s(p) over the first three directions (``_bound_from_world``'s, element by element)
    under (r,) ``limit``, fused (for ``compiled``): (3, N) ``columns`` the points' world x, y and z rows,
    (r, 3, 3) ``axes``, (r, 3) ``offset`` (a_d . c), (S, 3) slab ``middle`` and ``half``. NaN points are never under it."""
    projection = [(axes[:, a, 0, None] * columns[0] + axes[:, a, 1, None] * columns[1]) + axes[:, a, 2, None] * columns[2] for a in range(3)]
    bound = None
    for polytope in range(middle.shape[0]):
        excess = None
        for a in range(3):
            term = (projection[a] - (offset[:, a, None] + middle[polytope, a])).abs() - half[polytope, a]
            excess = term if excess is None else torch.maximum(excess, term)
        bound = excess if bound is None else torch.minimum(bound, excess)
    return bound < limit[:, None]
