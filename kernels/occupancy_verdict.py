"""The volume verdict: whether each pose's gripper holds at most a limit of points, decided as
``gripper_occupancy``'s exhaustive count would decide it, from bounds on the count that most poses
settle without that count (see ``gripper_occupancy_within``).
"""
from __future__ import annotations

import bisect
import math
from typing import NamedTuple

import torch

from .compiled import compiled, padded_rows
from .gripper_occupancy import GripperGeometry, gripper_occupancy
from .hand_clearance import scene_extents

# How far the volume verdict's coordinates may stray from the exhaustive GEMM's: twice the most
# that their rounding moves them (for grasp centres within ~4.8 m, L1, of the origin; see
# ``gripper_occupancy_within``).
VOLUME_SLACK_M = 2e-5
# (pose, point) pairs the volume verdict takes at once, in ~6 MB of buffers it reuses: larger
# blocks take fewer Python rounds, and the plans' chunk_elements caps them here.
VOLUME_BLOCK_ELEMENTS = 262_144


class _Layout(NamedTuple):
    """The volume verdict's counted poses, in groups that share one closing axis, ordered by group
    size (``_closing_groups``): G groups of R poses."""

    closing_rows: torch.Tensor  # (G, 1, 4) each group's closing axis and its y offset -axis . centre (``_frame_rows``)
    finger_y_mid: torch.Tensor  # (G, 1, 1) its finger slabs' middle along |y|
    finger_y_half: torch.Tensor  # (G, 1, 1) and half extent
    scene_starts: list[int]  # the groups that begin a scene's run (0 first)
    run_scenes: list[int]  # the scene of each of those runs
    xz_rows: torch.Tensor  # (2, R, 4) each pose's x and z axes and offsets (``_frame_rows``)
    classes: list[tuple[int, int, int, int]]  # per group size: (size, first group, end group, first pose)


def gripper_occupancy_within(
    points: torch.Tensor,
    object_index: torch.Tensor,
    centre: torch.Tensor,
    rotation: torch.Tensor,
    width_m: torch.Tensor,
    geometry: GripperGeometry,
    limit: torch.Tensor,
    chunk_elements: int,
    poses: torch.Tensor,
    compile: bool = False,
) -> torch.Tensor:
    """Whether each pose's gripper holds at most ``limit`` points: ``gripper_occupancy``'s verdict
    at a fraction of its cost, identical for every pose.

    Why it is cheaper: each counted pose's grasp-frame coordinates come from its own frame's
    rows applied to the scene's raw points, a . p - a . c, as one thin GEMM (each axis with its
    offset against the points and a row of ones), without the exhaustive check's (candidate,
    point, 3) offsets p - c, its GEMM over every approach and its gather of the counted poses; and a candidate's poses that share one closing
    axis (all of them, for ``grasp_rotations``' frames) share its y coordinates and their finger
    slab and palm excesses, computed once for them. The coordinates differ from the exhaustive
    GEMM's by rounding (<< ``VOLUME_SLACK_M`` for grasp centres within a few metres of the
    origin), so a pose's count is bounded: points inside a box by more than the slack count,
    points outside every box by more than it do not, and only points within it of a face (rare,
    but common on a grid aligned with the gripper) are uncertain. Poses whose bounds straddle
    ``limit``, and those whose centre is too far out for the rounding bound, are counted by
    ``gripper_occupancy`` itself.

    ``points``, ``object_index``, ``centre``, ``rotation``, ``width_m`` and ``geometry`` are as for
    ``gripper_occupancy``.

    Args:
        chunk_elements: bounds the (pose, point) pairs held at once (one candidate's poses at least).
        limit: (C,) float32 largest point count each candidate's poses may hold.
        poses: (C, K) bool, the poses to decide; the others are reported False.
        compile: take the bounds from ``_fused_count_bounds`` compiled (``compiled``) instead of
            the eager blocks: other roundings, within the same slack, so the same verdicts.

    Returns:
        (C, K) bool: ``poses & (gripper_occupancy(...).total.to(float32) <= limit[:, None])``.
    """
    n_candidates, n_approaches = rotation.shape[:2]
    if compile:
        pose_row, pose_slot = poses.nonzero(as_tuple=True)
        maybe, surely = _compiled_pose_bounds(points, object_index[pose_row], centre[pose_row], rotation[pose_row, pose_slot],
                                              width_m[pose_row], geometry)
    else:
        layout, pose_row, pose_slot = _closing_layout(poses, object_index, centre, rotation, width_m, geometry)
        pose_budget = max(1, min(chunk_elements, VOLUME_BLOCK_ELEMENTS) // max(1, points.shape[1]))
        maybe, surely = _pose_bounds(layout, points.permute(2, 0, 1).contiguous(), scene_extents(points).tolist(), geometry, pose_budget)
    pose_limit, pose_ok = limit[pose_row], centre[pose_row].abs().sum(dim=1) <= _centre_reach_l1(geometry)
    within = torch.zeros(n_candidates, n_approaches, dtype=torch.bool, device=centre.device)
    undecided = torch.zeros(n_candidates, n_approaches, dtype=torch.bool, device=centre.device)
    within[pose_row, pose_slot] = pose_ok & (maybe <= pose_limit)
    undecided[pose_row, pose_slot] = ~pose_ok | ((maybe > pose_limit) & (surely <= pose_limit))
    return _counted_where_undecided(within, undecided, points, object_index, centre, rotation, width_m, geometry, limit, chunk_elements)


def _closing_layout(
    poses: torch.Tensor, object_index: torch.Tensor, centre: torch.Tensor, rotation: torch.Tensor, width_m: torch.Tensor, geometry: GripperGeometry
) -> tuple[_Layout, torch.Tensor, torch.Tensor]:
    """The (C, K) bool ``poses`` to decide, laid out for ``_pose_bounds`` in groups that share one
    closing axis; and each laid-out pose's candidate and approach, (R,) int64 each, in that order."""
    n_approaches = rotation.shape[1]
    finger_y_max = geometry.finger_y_max
    pose_row, pose_slot = poses.nonzero(as_tuple=True)
    # The poses in groups that share one closing axis, then each pose's grasp-axis rows.
    frames = rotation.reshape(-1, 3, 3).index_select(0, pose_row * n_approaches + pose_slot)
    order, group_first, classes = _closing_groups(pose_row, frames[:, :, 1])
    pose_row, pose_slot = pose_row[order], pose_slot[order]
    rows = _frame_rows(frames[order], centre[pose_row], geometry)
    # A group's y coordinates come from its first pose's closing row and y offset: for each of
    # its poses they are a . p - a . c with that pose's own axis a (bit-identical) and centre c,
    # though a . c may round unlike that pose's own product: ``_centre_reach_l1``'s bound holds.
    finger_y_min = width_m[pose_row[group_first], None, None] / 2 + geometry.contact_clearance_m
    scene = object_index[pose_row[group_first]]
    scene_starts = torch.cat((torch.zeros(min(1, scene.numel()), dtype=torch.int64, device=scene.device), (scene[1:] != scene[:-1]).nonzero().squeeze(1) + 1))
    layout = _Layout(
        rows[group_first, 1:2], (finger_y_min + finger_y_max) / 2, (finger_y_max - finger_y_min) / 2, scene_starts.tolist(),
        scene[scene_starts].tolist(), rows[:, 0::2].transpose(0, 1), classes,
    )
    return layout, pose_row, pose_slot


def _frame_rows(frames: torch.Tensor, centre: torch.Tensor, geometry: GripperGeometry) -> torch.Tensor:
    """(R, 3, 4) each pose's grasp axes as rows, each with its offset -axis . centre, z measured from
    the finger slabs' middle: a row against a point's (x, y, z, 1) is its grasp-frame coordinate.
    ``frames`` (R, 3, 3) grasp -> world rotations, ``centre`` (R, 3)."""
    axes = frames.transpose(1, 2)
    offset = -(axes @ centre[:, :, None])
    offset[:, 2] -= (geometry.finger_z_min + geometry.fingertip_offset_m) / 2
    return torch.cat((axes, offset), dim=2)


def _centre_reach_l1(geometry: GripperGeometry) -> float:
    """How far (L1, metres) from the world origin a grasp centre may lie for the volume verdict's
    coordinates to stay within half of ``VOLUME_SLACK_M`` of the exhaustive GEMM's."""
    # A point within the slack of a box has grasp-frame |local|_1 below reach_l1, so its world
    # offset from the centre has |p - c|_1 <= sqrt(3) |p - c|_2 <= sqrt(3) reach_l1 = near_l1.
    reach_l1 = max(geometry.palm_width_m / 2 + geometry.palm_span_m / 2, geometry.finger_width_m / 2 + geometry.finger_y_max) + max(
        abs(geometry.palm_z_min), abs(geometry.fingertip_offset_m)
    ) + 3 * VOLUME_SLACK_M
    near_l1 = math.sqrt(3.0) * reach_l1
    # A coordinate is a . p - a . c here and a . (p - c) in the exhaustive GEMM: four-term sums
    # that, with the finger slabs' middle folded into z, round by at most 8 u (|p|_1 + |c|_1 +
    # near_l1) each (u = 2^-24). Near a box |p|_1 <= |c|_1 + near_l1, so they differ by at most
    # 32 u (|c|_1 + near_l1): half the slack for centres within this L1 reach. Farther points
    # round by more, but lie outside every box by far more.
    return VOLUME_SLACK_M / (2.0 * 32.0 * 2.0**-24) - near_l1


def _closing_groups(pose_row: torch.Tensor, closing_axis: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, list[tuple[int, int, int, int]]]:
    """Group the poses (R, in candidate order) into runs of one candidate's poses whose closing
    axes (R, 3) are bit-identical, so that they share their y coordinates; and order the groups by
    size, so that blocks of one size broadcast a group's y terms over its poses.

    Returns:
        order (R,) the poses' new order, groups contiguous; group_first (G,) each group's first
        pose in that order; and per group size, (size, first group, end group, first pose).
    """
    n_poses = pose_row.numel()
    begins = torch.ones(n_poses, dtype=torch.bool, device=pose_row.device)
    begins[1:] = (pose_row[1:] != pose_row[:-1]) | (closing_axis[1:] != closing_axis[:-1]).any(dim=1)
    first = begins.nonzero().squeeze(1)
    size = torch.diff(first, append=torch.tensor([n_poses], device=first.device))
    by_size = torch.argsort(size, stable=True)
    size = size[by_size]
    group_first = size.cumsum(0) - size
    order = (first[by_size] - group_first).repeat_interleave(size) + torch.arange(n_poses, device=first.device)
    sizes, counts = torch.unique_consecutive(size, return_counts=True)
    group_ends = counts.cumsum(0).tolist()
    group_starts = [0, *group_ends][:-1]
    pose_starts = group_first[group_starts].tolist()
    return order, group_first, list(zip(sizes.tolist(), group_starts, group_ends, pose_starts))


def _pose_bounds(
    layout: _Layout, scene_columns: torch.Tensor, extents: list[int], geometry: GripperGeometry, pose_budget: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Upper and lower bounds (R,) float32 of each pose's gripper point count (``_count_bounds``),
    in blocks of whole groups of one size and one scene of at most ``pose_budget`` poses;
    ``scene_columns`` (3, B, N) holds the scene points' world x, y and z rows, each scene's real
    ones the first ``extents`` (B,) of them."""
    n_poses, n_points = layout.xz_rows.shape[1], scene_columns.shape[-1]
    maybe, surely = torch.empty(n_poses, device=scene_columns.device), torch.empty(n_poses, device=scene_columns.device)
    # Every block reuses these (coordinates, scratch, and y terms of up to as many groups): fresh
    # temporaries of this size cost page faults on each block. A block holds one group at least.
    block_rows = min(max([pose_budget] + [size for size, *_ in layout.classes]), n_poses)
    buffers = torch.empty(3, 2 * block_rows * n_points, device=scene_columns.device)
    # Each scene's points as ``_coordinates`` takes them, up to its last real point (a batch pads to
    # its largest scene; padding is inside no box, so it adds nothing to a count).
    columns = [torch.cat((scene_columns[:, scene, :extent], scene_columns.new_ones(1, extent))) for scene, extent in enumerate(extents)]
    for size, group_start, group_end, pose_start in layout.classes:
        # This size's poses as (group, pose of the group), and the groups per block.
        poses, shape = slice(pose_start, pose_start + (group_end - group_start) * size), (group_end - group_start, size)
        bounds = (maybe[poses].view(shape), surely[poses].view(shape))
        # Blocks never mix scenes: a scene's points broadcast over its groups, with no (groups, points) gather.
        for scene, run_first, run_last in _scene_runs(layout, group_start, group_end):
            _run_bounds(layout, (layout.xz_rows[:, poses].unflatten(1, shape), bounds), columns[scene], group_start, (run_first, run_last),
                        size, geometry, pose_budget, buffers)
    return maybe, surely


def _scene_runs(layout: _Layout, group_start: int, group_end: int) -> list[tuple[int, int, int]]:
    """(scene, first group, end group) of each run of one scene's groups within [group_start, group_end)."""
    first_run = bisect.bisect_right(layout.scene_starts, group_start) - 1
    end_run = bisect.bisect_left(layout.scene_starts, group_end)
    starts = [group_start, *layout.scene_starts[first_run + 1 : end_run], group_end]
    return list(zip(layout.run_scenes[first_run:end_run], starts[:-1], starts[1:]))


def _run_bounds(
    layout: _Layout, size_class: tuple, columns: torch.Tensor, group_start: int, run: tuple[int, int], size: int,
    geometry: GripperGeometry, pose_budget: int, buffers: torch.Tensor,
) -> None:
    """``_pose_bounds``' bounds of the groups [run) of one scene, whose points' rows are ``columns``
    (4, n: world x, y, z and ones), of one size class: its (2, groups, size, 4) axes and offsets
    and its (groups, size) bounds to write (``size_class``), its first group ``group_start``."""
    rows_of_size, bounds = size_class
    n_points, step = columns.shape[-1], max(1, pose_budget // size)
    # The y terms of whole blocks' groups, up to ``pose_budget`` groups, at once: fewer, larger
    # calls than one per block of poses.
    span = step * max(1, pose_budget // step)
    for terms_first in range(run[0], run[1], span):
        terms_last = min(terms_first + span, run[1])
        closing = buffers[2, : 2 * (terms_last - terms_first) * n_points].view(2, terms_last - terms_first, 1, n_points)
        terms = _closing_terms(layout, terms_first, terms_last, columns, geometry, closing)
        for first in range(terms_first, terms_last, step):
            last = min(first + step, terms_last)
            block, rows = slice(first - group_start, last - group_start), slice(first - terms_first, last - terms_first)
            buffer_shape, elements = (2, last - first, size, n_points), 2 * (last - first) * size * n_points
            block_coordinates = _coordinates(rows_of_size[:, block], columns, buffers[0, :elements].view(buffer_shape))
            _count_bounds(
                block_coordinates, terms[:, rows], geometry, buffers[1, :elements].view(buffer_shape), (bounds[0][block], bounds[1][block])
            )


def _coordinates(rows: torch.Tensor, columns: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """``out`` (..., N) set to the coordinates of points along world axes plus offsets, ``rows`` (..., 4)
    each an axis and its offset; ``columns`` (4, N) holds the points' world x, y and z rows and a row of ones."""
    # One (rows, 4) @ (4, N) GEMM into ``out``: 2.6-3.6x quicker than a multiply and three
    # multiply-adds over the same (rows, N) (measured at 16-2,048 rows of 300-1,024 points). Its
    # four-term sums may round in another order than the exhaustive GEMM's, within the slack.
    return torch.mm(rows.reshape(-1, rows.shape[-1]), columns, out=out.view(-1, out.shape[-1])).view(out.shape)


def _closing_terms(layout: _Layout, first: int, last: int, columns: torch.Tensor, geometry: GripperGeometry, out: torch.Tensor) -> torch.Tensor:
    """``out`` (2, g, 1, n) set to the finger slabs' and the palm's excess along |y| (raised as in
    ``_count_bounds``) of the scene points' y coordinates along the closing axes of groups
    [first, last), all of one scene whose points' rows are ``columns`` (4, n, ``_coordinates``')."""
    raise_m = geometry.finger_width_m / 2
    finger, palm = out
    _coordinates(layout.closing_rows[first:last], columns, palm).abs_()
    torch.sub(palm, layout.finger_y_mid[first:last], out=finger).abs_().sub_(layout.finger_y_half[first:last] - raise_m)
    palm.sub_(geometry.palm_span_m / 2 - raise_m)
    return out


def _count_bounds(
    coordinates: torch.Tensor, closing: torch.Tensor, geometry: GripperGeometry, scratch: torch.Tensor, out: tuple[torch.Tensor, torch.Tensor]
) -> None:
    """``out`` set to upper and lower bounds (g, s) float32 of the gripper point counts of g groups
    of s poses, from the points' grasp-frame x and z (``coordinates`` (2, g, s, N), z measured from the finger
    slabs' middle) and each group's excesses along |y| (``closing`` (2, g, 1, N), from
    ``_closing_terms``); ``coordinates`` and ``scratch`` (2, g, s, N) are overwritten."""
    # Excess over each box (> 0 outside, <= 0 inside), then over the gripper, all raised by the
    # finger slabs' half width so that their |x| test needs no subtraction. For points near the
    # thresholds every value on the way lies under ~0.3 m, so each of the few roundings there errs
    # by at most 2^-24 * 0.3 m ~ 2e-8 m, raised or not: far inside the half of the slack (1e-5 m)
    # that the coordinates' own rounding leaves spare.
    raise_m = geometry.finger_width_m / 2
    abs_x, z = coordinates
    finger_y, palm_y = closing
    palm, palm_z = scratch
    abs_x.abs_()
    torch.maximum(torch.sub(abs_x, geometry.palm_width_m / 2 - raise_m, out=palm), palm_y, out=palm)
    finger = torch.maximum(abs_x, finger_y, out=abs_x)
    torch.add(z, (geometry.finger_length_m + geometry.palm_depth_m) / 2, out=palm_z).abs_().sub_(geometry.palm_depth_m / 2 - raise_m)
    torch.maximum(palm, palm_z, out=palm)
    torch.maximum(finger, z.abs_().sub_(geometry.finger_length_m / 2 - raise_m), out=finger)
    excess = torch.minimum(finger, palm, out=finger)
    # A point inside by more than the slack is inside one box alone (they meet only at one
    # face); a point within the slack of a face may be inside, or inside both boxes at their
    # common face, so it may count once more: bounds inside +- uncertain, where inside counts
    # excess <= slack and uncertain |excess| <= slack, i.e. inside less those below -slack.
    # Comparisons land in float32 0/1 so they sum straight into the float32 bounds, not through bool.
    maybe, surely = out
    torch.sum(torch.le(excess, raise_m + VOLUME_SLACK_M, out=palm_z), dim=-1, out=maybe)
    torch.sum(excess.lt_(raise_m - VOLUME_SLACK_M), dim=-1, out=surely)
    maybe.mul_(2).sub_(surely)


def _compiled_pose_bounds(
    points: torch.Tensor, scene: torch.Tensor, centre: torch.Tensor, frames: torch.Tensor, width_m: torch.Tensor, geometry: GripperGeometry
) -> tuple[torch.Tensor, torch.Tensor]:
    """``_pose_bounds``' (R,) bounds of R poses (scenes (R,) ``scene``, sorted; (R, 3) ``centre``,
    (R, 3, 3) ``frames``, (R,) ``width_m``) of (B, N, 3) ``points``, by the compiled
    ``_fused_count_bounds``, one call per scene over its points up to its last real one."""
    axes, offset, finger_y = pose_rows(frames, centre, width_m, geometry)
    maybe, surely = centre.new_empty(scene.shape[0]), centre.new_empty(scene.shape[0])
    run_scene, run_length = torch.unique_consecutive(scene, return_counts=True)
    extents = scene_extents(points)
    start, count_bounds = 0, compiled(_fused_count_bounds)
    for scene_index, length in zip(run_scene.tolist(), run_length.tolist()):
        block = slice(start, start + length)
        columns = points[scene_index, : max(2, int(extents[scene_index]))].T.contiguous()
        bounds = count_bounds(columns, padded_rows(axes[block]), padded_rows(offset[block]), padded_rows(finger_y[block]), geometry)
        maybe[block], surely[block] = (bound[:length] for bound in bounds)
        start += length
    return maybe, surely


def _fused_count_bounds(
    columns: torch.Tensor, axes: torch.Tensor, offset: torch.Tensor, finger_y: torch.Tensor, geometry: GripperGeometry
) -> tuple[torch.Tensor, torch.Tensor]:
    """``_count_bounds``' (R,) float32 bounds for R poses, each element of its chain taken as
    ``_coordinates``, ``_closing_terms`` and ``_count_bounds`` take it, fused (for ``compiled``):
    (3, N) ``columns`` the points' world x, y and z rows, (R, 3, 3) ``axes`` each pose's grasp axes
    as rows, (R, 3) ``offset`` their offsets (z measured from the finger slabs' middle), (R, 2)
    ``finger_y`` the finger slabs' middle and half extent along |y|."""
    raise_m = geometry.finger_width_m / 2
    excess = gripper_excess(columns, axes, offset, finger_y, geometry)
    surely = (excess < raise_m - VOLUME_SLACK_M).sum(dim=1, dtype=torch.float32)
    return (excess <= raise_m + VOLUME_SLACK_M).sum(dim=1, dtype=torch.float32) * 2 - surely, surely


def pose_rows(frames: torch.Tensor, centre: torch.Tensor, width_m: torch.Tensor, geometry: GripperGeometry) -> tuple[torch.Tensor, ...]:
    """``gripper_excess``' pose inputs of R poses ((R, 3, 3) grasp -> world ``frames``, (R, 3)
    ``centre``, (R,) jaw ``width_m``): (R, 3, 3) grasp axes as rows, (R, 3) their offsets (``_frame_rows``)
    and (R, 2) the finger slabs' middle and half extent along |y|, contiguous."""
    rows = _frame_rows(frames, centre, geometry)
    finger_y_min = width_m / 2 + geometry.contact_clearance_m
    finger_y = torch.stack(((finger_y_min + geometry.finger_y_max) / 2, (geometry.finger_y_max - finger_y_min) / 2), dim=1)
    return rows[..., :3].contiguous(), rows[..., 3].contiguous(), finger_y


def gripper_excess(columns: torch.Tensor, axes: torch.Tensor, offset: torch.Tensor, finger_y: torch.Tensor, geometry: GripperGeometry) -> torch.Tensor:
    """(R, N) each point's excess over the gripper's boxes (> 0 outside, <= 0 inside), raised by the
    finger slabs' half width, element by element as ``_count_bounds`` takes it: (3, N) ``columns``
    the points' world x, y and z rows, (R, 3, 3) ``axes``, (R, 3) ``offset`` and (R, 2) ``finger_y``
    from ``pose_rows``. Metres; 1-Lipschitz in the point (maxima and minima of distances to planes),
    which is what lets a ball of points be bounded by its centre's excess."""
    raise_m = geometry.finger_width_m / 2
    x, y, z = (((axes[:, a, 0, None] * columns[0] + axes[:, a, 1, None] * columns[1]) + axes[:, a, 2, None] * columns[2]) + offset[:, a, None]
               for a in range(3))
    abs_x, abs_y = x.abs(), y.abs()
    finger_y_excess = (abs_y - finger_y[:, 0, None]).abs() - (finger_y[:, 1, None] - raise_m)
    finger = torch.maximum(torch.maximum(abs_x, finger_y_excess), z.abs() - (geometry.finger_length_m / 2 - raise_m))
    palm_z = (z + (geometry.finger_length_m + geometry.palm_depth_m) / 2).abs() - (geometry.palm_depth_m / 2 - raise_m)
    palm = torch.maximum(torch.maximum(abs_x - (geometry.palm_width_m / 2 - raise_m), abs_y - (geometry.palm_span_m / 2 - raise_m)), palm_z)
    return torch.minimum(finger, palm)


def _counted_where_undecided(
    within: torch.Tensor, undecided: torch.Tensor, points: torch.Tensor, object_index: torch.Tensor, centre: torch.Tensor,
    rotation: torch.Tensor, width_m: torch.Tensor, geometry: GripperGeometry, limit: torch.Tensor, chunk_elements: int,
) -> torch.Tensor:
    """``within`` (C, K) with the ``undecided`` poses decided by ``gripper_occupancy``'s exhaustive count."""
    exhaustive = undecided.any(dim=1).nonzero().squeeze(1)
    if exhaustive.numel():
        mine = undecided[exhaustive]
        occupancy = gripper_occupancy(
            points, object_index[exhaustive], centre[exhaustive], rotation[exhaustive], width_m[exhaustive], geometry, chunk_elements, mine
        )
        within[exhaustive] = torch.where(mine, occupancy.total.to(torch.float32) <= limit[exhaustive, None], within[exhaustive])
    return within

