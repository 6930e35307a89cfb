"""Collision proxies for a parallel-jaw gripper: swept-volume occupancy and table penetration.

The gripper is described in the grasp frame (origin at the contact midpoint, y = closing axis,
z = approach, see ``grasp_frames``) by three axis-aligned boxes:

* two finger slabs, one outside each contact: |x| <= finger_width/2, z from the finger root to the
  fingertip, and |y| from just outside the contact (width/2 + contact_clearance) out to the open
  finger's back face (open_width/2 + finger_thickness). This is the volume each finger sweeps while
  closing from fully open to the contacts, so any point in it is something the finger would hit
  before touching the grasped surface: the published method's "box swept between the fingers".
* the palm: |x| <= palm_width/2, |y| <= palm_span/2, from the finger root back by palm_depth.

Points between the contacts (|y| < width/2) are the part being grasped and are not counted; the
``contact_clearance`` keeps the grasped surfaces' own points (which lie at |y| ~ width/2) out of
the count.

The table check (``table_penetration``) takes any set of gripper points in the grasp frame.
"""
from __future__ import annotations

import bisect
import math
from typing import NamedTuple

import torch

from .grasp_frames import scene_points_about

# Float32 rounding of the table check's bounds (a few 1e-8 m at these sizes) is far inside this.
TABLE_BOUND_SLACK_M = 1e-5
# How far the volume verdict's coordinates may stray from the exhaustive GEMM's: twice the most
# that their rounding moves them (for grasp centres within ~4.8 m, L1, of the origin; see
# ``gripper_occupancy_within``).
VOLUME_SLACK_M = 2e-5
# (pose, point) pairs the volume verdict takes at once, in ~6 MB of buffers it reuses: measured
# at 5,000 and at 500,000 pairs, blocks of 32k to 256k pairs took ever less time (fewer Python
# rounds), the plans' chunk_elements capping them here.
VOLUME_BLOCK_ELEMENTS = 262_144
# Poses whose heights of hand points the table check takes from one GEMM: the heights (~1 MB for
# the 32-point cover) stay in cache for the minimum that follows (at 500,000 pairs one GEMM over
# every pose of a block of candidates made the check ~4x slower); 4,096 to 16,384 measured alike.
TABLE_BLOCK_POSES = 8192
# Points that bound a pose's lowest hand point for the table check: 32 of the hand's 204 hull
# vertices cover every vertex within 2.5 cm, leaving ~10 % of a cloud's poses to check on all.
TABLE_COVER_POINTS = 32


class GripperOccupancy(NamedTuple):
    """Points inside each candidate gripper, split by part: (C, K) int64 each."""

    fingers: torch.Tensor  # inside the two swept finger slabs
    palm: torch.Tensor  # inside the palm box

    @property
    def total(self) -> torch.Tensor:
        """Points inside the finger slabs or the palm (the boxes are disjoint along z)."""
        return self.fingers + self.palm


class GripperGeometry(NamedTuple):
    """Gripper dimensions in metres, grasp frame (see module docstring)."""

    open_width_m: float
    finger_width_m: float
    finger_thickness_m: float
    finger_length_m: float
    fingertip_offset_m: float  # how far the fingertips reach beyond the grasp point along +z
    palm_width_m: float
    palm_span_m: float
    palm_depth_m: float
    contact_clearance_m: float

    @property
    def finger_y_max(self) -> float:
        """Outer |y| of the finger slabs: the open finger's back face."""
        return self.open_width_m / 2 + self.finger_thickness_m

    @property
    def finger_z_min(self) -> float:
        """The finger root along z, where the fingers meet the palm."""
        return self.fingertip_offset_m - self.finger_length_m

    @property
    def palm_z_min(self) -> float:
        """The palm's back face along z."""
        return self.finger_z_min - self.palm_depth_m


def gripper_occupancy(
    points: torch.Tensor,
    object_index: torch.Tensor,
    centre: torch.Tensor,
    rotation: torch.Tensor,
    width_m: torch.Tensor,
    geometry: GripperGeometry,
    chunk_elements: int,
    poses: torch.Tensor | None = None,
) -> GripperOccupancy:
    """Count the points inside each candidate gripper's swept finger slabs and its palm.

    Args:
        points: (B, N, 3) points of B scenes (object plus obstacle points), world frame, metres.
            Scenes with fewer points are padded with NaN rows, which are never inside.
        object_index: (C,) int64 scene of each candidate, in [0, B).
        centre: (C, 3) grasp centres (contact midpoints), world frame.
        rotation: (C, K, 3, 3) grasp rotations (grasp frame -> world) for K approaches per candidate.
        width_m: (C,) contact distances.
        geometry: gripper dimensions.
        chunk_elements: bound on the number of (candidate, approach, point) triples held in
            memory at once; work is split over candidates to respect it.
        poses: optional (C, K) bool, the (candidate, approach) poses to count (default all);
            the others are reported as 0.

    Returns:
        ``GripperOccupancy`` of (C, K) int64 counts: finger slabs, palm and their ``total``.
    """
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"points must be (B, N, 3), got {tuple(points.shape)}")
    if rotation.ndim != 4 or rotation.shape[-2:] != (3, 3) or rotation.shape[0] != centre.shape[0]:
        raise ValueError(f"rotation must be (C, K, 3, 3) matching centre (C, 3), got {tuple(rotation.shape)} and {tuple(centre.shape)}")
    n_candidates, n_approaches = rotation.shape[:2]
    if poses is None:
        poses = torch.ones(n_candidates, n_approaches, dtype=torch.bool)
    n_points = points.shape[1]
    finger_z_max, finger_z_min, palm_z_min = geometry.fingertip_offset_m, geometry.finger_z_min, geometry.palm_z_min
    finger_y_max = geometry.finger_y_max
    finger_z_mid, finger_z_half = (finger_z_min + finger_z_max) / 2, (finger_z_max - finger_z_min) / 2
    palm_z_mid, palm_z_half = (palm_z_min + finger_z_min) / 2, (finger_z_min - palm_z_min) / 2
    finger_counts = torch.zeros(n_candidates * n_approaches, dtype=torch.int64)
    palm_counts = torch.zeros(n_candidates * n_approaches, dtype=torch.int64)
    step = max(1, chunk_elements // max(1, n_approaches * n_points))
    counted = poses.any(dim=1).nonzero().squeeze(1)
    for start in range(0, counted.numel(), step):
        rows = counted[start : start + step]
        chosen = poses[rows].reshape(-1).nonzero().squeeze(1)  # flat (candidate, approach) in the chunk
        relative = scene_points_about(points, object_index[rows], centre[rows])  # (c, N, 3)
        # Grasp-frame coordinates R^T (p - centre) as one batched GEMM with the points along the
        # long output dimension: (c, K*3, 3) @ (c, 3, N) -> (c, K, 3, N). Every approach takes
        # part even where only some are counted: the GEMM's rounding depends on its shape.
        grasp_axes = rotation[rows].transpose(-1, -2).reshape(rows.numel(), n_approaches * 3, 3)
        local = (grasp_axes @ relative.transpose(1, 2)).view(-1, 3, n_points)[chosen]  # (R, 3, N)
        abs_x = local[:, 0].abs()
        abs_y = local[:, 1].abs()
        z = local[:, 2]
        # Each interval test is one |value - middle| <= half-length comparison to halve the passes
        # over the (R, N) coordinates, the planner's most expensive tensors.
        finger_y_min = (width_m[rows] / 2 + geometry.contact_clearance_m).repeat_interleave(n_approaches)[chosen, None]
        in_finger_y = (abs_y - (finger_y_min + finger_y_max) / 2).abs() <= (finger_y_max - finger_y_min) / 2
        in_finger_xz = (abs_x <= geometry.finger_width_m / 2) & ((z - finger_z_mid).abs() <= finger_z_half)
        in_fingers = in_finger_y & in_finger_xz
        in_palm_xy = (abs_y <= geometry.palm_span_m / 2) & (abs_x <= geometry.palm_width_m / 2)
        in_palm = in_palm_xy & ((z - palm_z_mid).abs() <= palm_z_half)
        pose_index = (rows[:, None] * n_approaches + torch.arange(n_approaches)).view(-1)[chosen]
        finger_counts[pose_index] = in_fingers.sum(dim=-1)
        palm_counts[pose_index] = in_palm.sum(dim=-1)
    shape = (n_candidates, n_approaches)
    return GripperOccupancy(finger_counts.view(shape), palm_counts.view(shape))


class _Layout(NamedTuple):
    """The volume verdict's counted poses, in groups that share one closing axis, ordered by group
    size (``_closing_groups``): G groups of R poses."""

    closing_axis: torch.Tensor  # (G, 1, 3) each group's closing axis, as a row
    closing_offset: torch.Tensor  # (G, 1, 1) its y offset -axis . centre
    finger_y_mid: torch.Tensor  # (G, 1, 1) its finger slabs' middle along |y|
    finger_y_half: torch.Tensor  # (G, 1, 1) and half extent
    scene: torch.Tensor  # (G,) its scene
    scene_starts: list[int]  # the groups that begin another scene's run
    xz_axes: torch.Tensor  # (2, R, 3) each pose's x and z axes, as rows
    xz_offset: torch.Tensor  # (2, R, 1) and offsets, z measured from the finger slabs' middle
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
) -> torch.Tensor:
    """Whether each pose's gripper holds at most ``limit`` points: ``gripper_occupancy``'s verdict
    at a fraction of its cost, identical for every pose.

    Why it is cheaper: each counted pose's grasp-frame coordinates come from its own frame's
    rows applied to the scene's raw points, a . p - a . c, as three broadcast multiply-adds per
    axis, without the exhaustive check's (candidate, point, 3) offsets p - c, its GEMM over every
    approach and its gather of the counted poses; and a candidate's poses that share one closing
    axis (all of them, for ``grasp_rotations``' frames) share its y coordinates and their finger
    slab and palm excesses, computed once for them. The coordinates differ from the exhaustive
    GEMM's by rounding (<< ``VOLUME_SLACK_M`` for grasp centres within a few metres of the
    origin), so a pose's count is bounded: points inside a box by more than the slack count,
    points outside every box by more than it do not, and only points within it of a face (rare,
    but common on a grid aligned with the gripper) are uncertain. Poses whose bounds straddle
    ``limit``, and those whose centre is too far out for the rounding bound, are counted by
    ``gripper_occupancy`` itself.

    Args:
        points, object_index, centre, rotation, width_m, geometry, chunk_elements: as for
            ``gripper_occupancy``; ``chunk_elements`` bounds the (pose, point) pairs held at once
            (one candidate's poses at least).
        limit: (C,) float32 largest point count each candidate's poses may hold.
        poses: (C, K) bool, the poses to decide; the others are reported False.

    Returns:
        (C, K) bool: ``poses & (gripper_occupancy(...).total.to(float32) <= limit[:, None])``.
    """
    n_candidates, n_approaches = rotation.shape[:2]
    finger_z_max, finger_z_min, finger_y_max = geometry.fingertip_offset_m, geometry.finger_z_min, geometry.finger_y_max
    pose_row, pose_slot = poses.nonzero(as_tuple=True)
    # The poses in groups that share one closing axis, then each pose's grasp axes as rows
    # (R, 3, 3) and offsets -axis . centre (R, 3, 1), z measured from the finger slabs' middle.
    frames = rotation.reshape(-1, 3, 3).index_select(0, pose_row * n_approaches + pose_slot)
    order, group_first, classes = _closing_groups(pose_row, frames[:, :, 1])
    pose_row, pose_slot, axes = pose_row[order], pose_slot[order], frames[order].transpose(1, 2)
    offset = -(axes @ centre[pose_row, :, None])
    offset[:, 2] -= (finger_z_min + finger_z_max) / 2
    # A group's y coordinates come from its first pose's closing row and y offset: for each of
    # its poses they are a . p - a . c with that pose's own axis a (bit-identical) and centre c,
    # though a . c may round unlike that pose's own product: ``_centre_reach_l1``'s bound holds.
    closing_axis, closing_offset = axes[group_first, 1:2], offset[group_first, 1:2]
    finger_y_min = width_m[pose_row[group_first], None, None] / 2 + geometry.contact_clearance_m
    scene = object_index[pose_row[group_first]]
    layout = _Layout(
        closing_axis, closing_offset, (finger_y_min + finger_y_max) / 2, (finger_y_max - finger_y_min) / 2, scene,
        ((scene[1:] != scene[:-1]).nonzero().squeeze(1) + 1).tolist(), axes[:, 0::2].transpose(0, 1), offset[:, 0::2].transpose(0, 1), classes,
    )
    pose_budget = max(1, min(chunk_elements, VOLUME_BLOCK_ELEMENTS) // max(1, points.shape[1]))
    maybe, surely = _pose_bounds(layout, points.permute(2, 0, 1).contiguous(), geometry, pose_budget)
    pose_limit, pose_ok = limit[pose_row], centre[pose_row].abs().sum(dim=1) <= _centre_reach_l1(geometry)
    within = torch.zeros(n_candidates, n_approaches, dtype=torch.bool)
    undecided = torch.zeros(n_candidates, n_approaches, dtype=torch.bool)
    within[pose_row, pose_slot] = pose_ok & (maybe <= pose_limit)
    undecided[pose_row, pose_slot] = ~pose_ok | ((maybe > pose_limit) & (surely <= pose_limit))
    return _counted_where_undecided(within, undecided, points, object_index, centre, rotation, width_m, geometry, limit, chunk_elements)


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
    begins = torch.ones(n_poses, dtype=torch.bool)
    begins[1:] = (pose_row[1:] != pose_row[:-1]) | (closing_axis[1:] != closing_axis[:-1]).any(dim=1)
    first = begins.nonzero().squeeze(1)
    size = torch.diff(first, append=torch.tensor([n_poses]))
    by_size = torch.argsort(size, stable=True)
    size = size[by_size]
    group_first = size.cumsum(0) - size
    order = (first[by_size] - group_first).repeat_interleave(size) + torch.arange(n_poses)
    sizes, counts = torch.unique_consecutive(size, return_counts=True)
    group_ends = counts.cumsum(0).tolist()
    group_starts = [0, *group_ends][:-1]
    pose_starts = group_first[group_starts].tolist()
    return order, group_first, list(zip(sizes.tolist(), group_starts, group_ends, pose_starts))


def _pose_bounds(layout: _Layout, scene_columns: torch.Tensor, geometry: GripperGeometry, pose_budget: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Upper and lower bounds (R,) float32 of each pose's gripper point count (``_count_bounds``),
    in blocks of whole groups of one size of at most ``pose_budget`` poses; ``scene_columns``
    (3, B, N) holds the scene points' world x, y and z rows."""
    n_poses, n_points = layout.xz_axes.shape[1], scene_columns.shape[-1]
    maybe, surely = torch.empty(n_poses), torch.empty(n_poses)
    # Every block reuses these (coordinates, scratch, and y terms of up to as many groups): fresh
    # temporaries of this size cost page faults on each block. A block holds one group at least.
    block_rows = min(max([pose_budget] + [size for size, *_ in layout.classes]), n_poses)
    coordinates, scratch, closing = torch.empty(3, 2, block_rows, n_points)
    for size, group_start, group_end, pose_start in layout.classes:
        # This size's poses as (group, pose of the group), and the groups per block.
        poses, shape = slice(pose_start, pose_start + (group_end - group_start) * size), (group_end - group_start, size)
        axes, offset = layout.xz_axes[:, poses].unflatten(1, shape), layout.xz_offset[:, poses].unflatten(1, shape)
        bounds, step = (maybe[poses].view(shape), surely[poses].view(shape)), max(1, pose_budget // size)
        # The y terms of whole blocks' groups, up to ``pose_budget`` groups, at once: taken per
        # block of poses (51 to 85 groups), the 500,000-pair mug's verdict took ~4 % longer.
        span = step * max(1, pose_budget // step)
        for terms_first in range(group_start, group_end, span):
            terms_last = min(terms_first + span, group_end)
            terms = _closing_terms(layout, terms_first, terms_last, scene_columns, geometry, closing[:, : terms_last - terms_first, None])
            for first in range(terms_first, terms_last, step):
                last = min(first + step, terms_last)
                block, rows = slice(first - group_start, last - group_start), slice(first - terms_first, last - terms_first)
                buffer_shape = (2, last - first, size, n_points)
                block_coordinates = _coordinates(
                    axes[:, block], offset[:, block], _scene_rows(layout, scene_columns, first, last),
                    coordinates[:, : (last - first) * size].view(buffer_shape),
                )
                _count_bounds(
                    block_coordinates, terms[:, rows], geometry, scratch[:, : (last - first) * size].view(buffer_shape),
                    (bounds[0][block], bounds[1][block]),
                )
    return maybe, surely


def _scene_rows(layout: _Layout, scene_columns: torch.Tensor, first: int, last: int) -> torch.Tensor:
    """The world x, y and z rows (3, g or 1, 1, N) of the scene points of groups [first, last),
    from ``scene_columns`` (3, B, N)."""
    if bisect.bisect_right(layout.scene_starts, first) == bisect.bisect_left(layout.scene_starts, last):
        # One scene (the common case): its points broadcast over the groups.
        return scene_columns[:, int(layout.scene[first]), None, None]
    return scene_columns[:, layout.scene[first:last], None]


def _coordinates(axes: torch.Tensor, offset: torch.Tensor, columns: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """``out`` set to the coordinates of points along world ``axes`` (..., 3), plus ``offset``
    (..., 1); ``columns`` (3, ..., N) holds the points' world x, y and z rows, broadcasting."""
    # An out-of-place addcmul broadcasting three ways is several times slower than these; a
    # (rows, 4) @ (4, N) GEMM with the offsets as a fourth column took 2.5x as long (K = 4).
    torch.mul(axes[..., 0:1], columns[0], out=out)
    return out.addcmul_(axes[..., 1:2], columns[1]).addcmul_(axes[..., 2:3], columns[2]).add_(offset)


def _closing_terms(layout: _Layout, first: int, last: int, scene_columns: torch.Tensor, geometry: GripperGeometry, out: torch.Tensor) -> torch.Tensor:
    """``out`` (2, g, 1, N) set to the finger slabs' and the palm's excess along |y| (raised as in
    ``_count_bounds``) of the scene points' y coordinates along the closing axes of groups
    [first, last), from ``scene_columns`` (3, B, N)."""
    raise_m = geometry.finger_width_m / 2
    finger, palm = out
    columns = _scene_rows(layout, scene_columns, first, last)
    _coordinates(layout.closing_axis[first:last], layout.closing_offset[first:last], columns, palm).abs_()
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
    # Comparing into float32 0/1 and summing is several times faster than through bool.
    maybe, surely = out
    torch.sum(torch.le(excess, raise_m + VOLUME_SLACK_M, out=palm_z), dim=-1, out=maybe)
    torch.sum(excess.lt_(raise_m - VOLUME_SLACK_M), dim=-1, out=surely)
    maybe.mul_(2).sub_(surely)


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


def table_penetration(
    centre: torch.Tensor,
    rotation: torch.Tensor,
    gripper_points_local: torch.Tensor,
    retreat_m: float,
    table_top_z_m: float,
    cover: tuple[torch.Tensor, float] | None = None,
) -> torch.Tensor:
    """Whether the open gripper dips below the table top at the grasp or at the pre-grasp pose.

    The pre-grasp pose is the grasp pose moved ``retreat_m`` back along the approach (grasp -z).

    Args:
        centre: (C, 3) grasp centres, world frame, metres.
        rotation: (C, K, 3, 3) grasp rotations (grasp frame -> world).
        gripper_points_local: (M, 3) points bounding the open gripper (e.g. its collision hulls'
            vertices) in the grasp frame, metres.
        retreat_m: pre-grasp distance back along the approach, metres.
        table_top_z_m: world height of the table top, metres.
        cover: ``table_cover(gripper_points_local)``, if the caller keeps it for fixed points
            (default: computed here).

    Returns:
        (C, K) bool, True where some gripper point is below the table top at either pose.
    """
    # Only world z matters: z_world = centre_z + R[2, :] . point.
    row_z = rotation[..., 2, :]  # (C, K, 3)
    points = gripper_points_local.to(rotation)
    drop = retreat_m * rotation[..., 2, 2]  # (C, K) the pre-grasp's lowest point is this much lower
    # Most poses are decided by a few points: the lowest of a subset that covers every point
    # within ``reach`` bounds the lowest point from above (it is a real point) and, less
    # ``reach``, from below (z is 1-Lipschitz in the point, the rows of R being unit). Only poses
    # whose bounds straddle the table top are evaluated on every point, with the same GEMM as the
    # exhaustive check, so every verdict is bit-for-bit the exhaustive one; the slack absorbs the
    # bounds' float32 rounding.
    subset, reach = table_cover(points) if cover is None else cover
    upper = centre[:, 2, None] + _lowest_along(row_z, points[subset])
    lower = upper - reach
    through = (upper < table_top_z_m - TABLE_BOUND_SLACK_M) | (upper - drop < table_top_z_m - TABLE_BOUND_SLACK_M)
    clear = (lower >= table_top_z_m + TABLE_BOUND_SLACK_M) & (lower - drop >= table_top_z_m + TABLE_BOUND_SLACK_M)
    poses, slots = (~(through | clear)).nonzero(as_tuple=True)
    if not poses.numel():
        return through
    # MKL picks another summation order for GEMMs of fewer than 4 rows; padding the batch to 8
    # rows keeps the exhaustive check's rounding.
    padded = torch.cat((poses, poses.new_zeros(max(0, 8 - poses.numel()))))
    padded_slots = torch.cat((slots, slots.new_zeros(max(0, 8 - slots.numel()))))
    # Rounding is monotonic, so adding the centre's height to the lowest of the GEMM's heights
    # gives the lowest of the heights with it added, bit for bit, at one addition per pose.
    lowest_grasp = centre[poses, 2] + _lowest_along(row_z[padded, padded_slots], points)[: poses.numel()]
    # Retreating along -approach changes every point's height by -retreat * approach_z.
    lowest_pregrasp = lowest_grasp - drop[poses, slots]
    through[poses, slots] = (lowest_grasp < table_top_z_m) | (lowest_pregrasp < table_top_z_m)
    return through


def _lowest_along(directions: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """(...) the least of (M, 3) ``points``' heights along each of (..., 3) ``directions``: the
    minima of ``directions @ points.T``, in near-equal GEMMs of at most ``TABLE_BLOCK_POSES``
    directions and at least half as many unless there are fewer in all: never the fewer than 4
    rows that MKL rounds otherwise, so each height rounds as in one GEMM over every direction."""
    n_blocks = -(-directions[..., 0].numel() // TABLE_BLOCK_POSES)
    # amin, not min: min also finds the indices, which made it several times slower.
    if n_blocks <= 1:  # most calls: no split and concatenation, ~10 us each
        return (directions @ points.T).amin(dim=-1)
    blocks = directions.reshape(-1, 3).tensor_split(n_blocks)
    return torch.cat([(block @ points.T).amin(dim=1) for block in blocks]).view(directions.shape[:-1])


def table_cover(points: torch.Tensor) -> tuple[torch.Tensor, float]:
    """The ``TABLE_COVER_POINTS`` farthest-point subset of (M, 3) ``points`` that ``table_penetration``
    bounds poses by: (S,) indices and the largest distance (metres) from any point to its nearest
    subset point."""
    chosen = [0]
    distance = (points - points[0]).norm(dim=1)
    for _ in range(min(TABLE_COVER_POINTS, points.shape[0]) - 1):
        chosen.append(int(distance.argmax()))
        distance = torch.minimum(distance, (points - points[chosen[-1]]).norm(dim=1))
    return torch.tensor(chosen), float(distance.max()) if points.shape[0] else 0.0
