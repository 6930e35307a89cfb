"""Collision checks by a representation of the scene built once per cloud and queried per pose, with
bounds that say when the exact pass must decide; and the exact checks as one fixed-shape fused pass.

Both checks of ``screens`` are passes over a cloud's points per grasp pose. Here the scene is
compressed once per cloud instead:

* the gripper volume (``gripper_occupancy``): the occupancy points binned into cubic cells, each
  cell kept as a ball (its points' mean, their farthest distance from it) weighted by its count
  (``cell_balls``). ``gripper_excess`` is 1-Lipschitz in the point, so a ball whose centre lies
  deeper inside the gripper than its radius holds only counted points, one farther outside holds
  none, and the count is bracketed (``cell_count_bounds``) by a pass over cells, not points.
* the swept hand (``hand_clearance``): a truncated Euclidean distance field of the hand check
  points sampled at grid nodes (``distance_field``), and the margin-inflated swept k-DOPs covered
  by balls (``hand_balls``), grasp frame, each with the hulls' k-DOP separation s at its centre.
  Per pose (``hand_clearance_bounds``), a ball that no point can reach (nearest-node lookup less
  the node's distance) clears everything it covers; a ball centre q bounds the clearance from
  above by s(q) + d(q), s being 1-Lipschitz.

All functions take one cloud's tensors and make theirs on the input's device. Lengths are metres;
"world" is the cloud's frame, "grasp frame" ``grasp_frames``' (origin at the grasp centre, y the
closing axis, z the approach).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import torch

from .compiled import compiled, padded_rows
from .gripper_occupancy import GripperGeometry
from .hand_clearance import BOUND_SLACK_M, RAW_ROUNDING_EPS, coordinate_scale
from .occupancy_verdict import VOLUME_SLACK_M, gripper_excess, pose_rows

# (pose, cell or ball) elements of one query block: eager temporaries of ~4 MB each.
QUERY_BLOCK_ELEMENTS = 1_048_576
# Points whose distances to their nearby grid nodes are taken at once while building the field.
FIELD_POINT_BLOCK = 256


class CellBalls(NamedTuple):
    """A cloud's points binned into cubic cells, each as a ball that holds all of its points."""

    centre: torch.Tensor  # (K, 3) float32 world: the mean of the cell's points
    radius: torch.Tensor  # (K,) float32 metres: the farthest of its points from that mean
    count: torch.Tensor  # (K,) float32 its points


class DistanceField(NamedTuple):
    """Distance from grid nodes to a cloud's nearest point, truncated at ``band_m``.

    Node (i, j, k) lies at ``origin + cell_m * (i, j, k)``; the grid spans the points' bounding box
    grown by ``band_m`` on every side, so a position outside it is at least ``band_m`` from every point."""

    distance: torch.Tensor  # (nx, ny, nz) float32 metres, min(exact distance, band_m)
    origin: torch.Tensor  # (3,) float32 world position of node (0, 0, 0)
    cell_m: float
    band_m: float


class HandBalls(NamedTuple):
    """Balls covering the margin-inflated swept hand {q : s(q) < margin}, grasp frame."""

    centre: torch.Tensor  # (K, 3) float32 grasp frame
    radius: torch.Tensor  # (K,) float32 metres
    separation: torch.Tensor  # (K,) float32 s at the centre: least k-DOP separation over the hulls


def _real_rows(points: torch.Tensor) -> torch.Tensor:
    """(n, 3) the rows of (N, 3) ``points`` without NaN (the padding)."""
    return points[~points.isnan().any(dim=1)]


def cell_balls(points: torch.Tensor, cell_m: float) -> CellBalls:
    """``CellBalls`` of (N, 3) world ``points`` (NaN rows ignored) in cubic cells of ``cell_m``."""
    points = _real_rows(points)
    cell = ((points - points.amin(dim=0)) / cell_m).floor().to(torch.int64)
    span = cell.amax(dim=0) + 1
    _, member, count = torch.unique((cell[:, 0] * span[1] + cell[:, 1]) * span[2] + cell[:, 2], return_inverse=True, return_counts=True)
    centre = torch.zeros(count.shape[0], 3, device=points.device).index_add_(0, member, points) / count[:, None]
    reach = (points - centre[member]).norm(dim=1)
    radius = torch.zeros(count.shape[0], device=points.device).scatter_reduce_(0, member, reach, "amax", include_self=False)
    return CellBalls(centre, radius, count.to(torch.float32))


def cell_count_bounds(
    cells: CellBalls, centre: torch.Tensor, frames: torch.Tensor, width_m: torch.Tensor, geometry: GripperGeometry, compile: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Upper and lower bounds, (R,) float32 each, of ``gripper_occupancy``'s total count for R poses
    of one cloud: (R, 3) grasp centres, (R, 3, 3) grasp -> world ``frames``, (R,) jaw ``width_m``.

    A cell counts surely where its ball lies inside the gripper by more than ``VOLUME_SLACK_M`` (the
    exhaustive count's rounding), possibly where within that of it; as for the exhaustive count's own
    bounds, a possible cell may sit on the finger slabs' and palm's common face and count twice.
    ``compile``: by the compiled ``_fused_cell_bounds`` rather than eagerly (the same graph)."""
    axes, offset, finger_y = pose_rows(frames, centre, width_m, geometry)
    columns, reach = cells.centre.T.contiguous(), cells.radius + VOLUME_SLACK_M
    fused = compiled(_fused_cell_bounds) if compile else _fused_cell_bounds
    maybe, surely = torch.empty(centre.shape[0], device=centre.device), torch.empty(centre.shape[0], device=centre.device)
    step = max(2, QUERY_BLOCK_ELEMENTS // max(1, columns.shape[1]))
    for start in range(0, centre.shape[0], step):
        block = slice(start, min(start + step, centre.shape[0]))
        rows = block.stop - block.start
        bounds = fused(columns, reach, cells.count, padded_rows(axes[block]), padded_rows(offset[block]), padded_rows(finger_y[block]), geometry)
        maybe[block], surely[block] = (bound[:rows] for bound in bounds)
    return maybe, surely


def _fused_cell_bounds(
    columns: torch.Tensor, reach: torch.Tensor, count: torch.Tensor, axes: torch.Tensor, offset: torch.Tensor, finger_y: torch.Tensor,
    geometry: GripperGeometry,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(R,) upper and lower count bounds of (3, K) ball ``columns`` of (K,) ``reach`` (radius plus
    slack) and ``count`` points, poses as ``gripper_excess`` takes them."""
    raise_m = geometry.finger_width_m / 2
    excess = gripper_excess(columns, axes, offset, finger_y, geometry)
    surely = ((excess < raise_m - reach) * count).sum(dim=1)
    return ((excess <= raise_m + reach) * count).sum(dim=1) * 2 - surely, surely


def distance_field(points: torch.Tensor, cell_m: float, band_m: float) -> DistanceField:
    """``DistanceField`` of (N, 3) world ``points`` (NaN rows ignored), nodes ``cell_m`` apart.

    A sparse brute force: each point updates only the nodes within ``band_m`` of it (a cube of
    nodes around it, (2 band / cell)^3 of them), so the build costs N times that cube, not N times
    the grid; the nodes no point reaches keep ``band_m``. Node values are exact up to float32
    rounding (~1e-8 m)."""
    points = _real_rows(points)
    device = points.device
    origin = points.amin(dim=0) - band_m
    shape = ((points.amax(dim=0) + band_m - origin) / cell_m).ceil().to(torch.int64) + 1
    reach = math.ceil(band_m / cell_m)
    steps = torch.arange(-reach, reach + 2, device=device)
    offsets = torch.cartesian_prod(steps, steps, steps)  # (O, 3) node offsets from a point's cell
    # A point lies in its cell, within sqrt(3)/2 cells of its middle: nodes farther than the band
    # plus that from the middle are beyond the band from the point (half the cube's nodes).
    offsets = offsets[(offsets - 0.5).norm(dim=1) <= band_m / cell_m + math.sqrt(3.0) / 2]
    distance = torch.full((int(shape.prod()),), band_m, device=device)
    for start in range(0, points.shape[0], FIELD_POINT_BLOCK):
        block = points[start : start + FIELD_POINT_BLOCK]
        node = ((block - origin) / cell_m).floor().to(torch.int64)[:, None, :] + offsets  # (b, O, 3)
        inside = ((node >= 0) & (node < shape)).all(dim=2)
        gap = (origin + node * cell_m - block[:, None, :]).norm(dim=2).clamp_max(band_m)
        flat = (node[..., 0] * shape[1] + node[..., 1]) * shape[2] + node[..., 2]
        distance.scatter_reduce_(0, flat[inside], gap[inside], "amin")
    return DistanceField(distance.view(*shape.tolist()), origin, cell_m, band_m)


def hulls_separation(grasp_points: torch.Tensor, directions: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """(K,) s(q) of (K, 3) grasp-frame points: the least over S k-DOPs ((S, D) extents ``low``,
    ``high`` along (D, 3) unit ``directions``) of the largest slab excess, <= 0 inside one."""
    projection = grasp_points @ directions.T  # (K, D)
    return torch.maximum(projection[:, None, :] - high, low - projection[:, None, :]).amax(dim=2).amin(dim=1)


def hand_balls(
    directions: torch.Tensor, low: torch.Tensor, high: torch.Tensor, margin_m: float, tolerance_m: float, max_side_m: float, min_side_m: float,
) -> HandBalls:
    """``HandBalls`` covering {q : s(q) < margin_m} of the hulls (``hulls_separation``'s arguments; the
    first three directions must be the grasp axes), by an octree of cubes each kept as its circumscribed ball.

    Cubes of ``max_side_m`` tile the hulls' inflated box; a cube is dropped where s(centre) - radius
    >= margin (s is 1-Lipschitz, so none of it is within the margin), kept where s(centre) + radius
    <= margin + ``tolerance_m`` or its side is down to ``min_side_m``, else halved. A ball so holds
    only positions of s < margin + max(tolerance_m, sqrt(3) min_side_m): a point in it that the
    exact check would clear by less than that leaves its pose undecided."""
    if not torch.equal(directions[:3], torch.eye(3, device=directions.device)):
        raise ValueError("the first three k-DOP directions must be the grasp axes")
    lowest, highest = low[:, :3].amin(dim=0) - margin_m, high[:, :3].amax(dim=0) + margin_m
    counts = ((highest - lowest) / max_side_m).ceil().to(torch.int64)
    cube = torch.cartesian_prod(*(torch.arange(int(n), device=low.device) for n in counts)).view(-1, 3)
    centres, side = lowest + (cube + 0.5) * max_side_m, max_side_m
    corner = torch.cartesian_prod(*[torch.tensor([-1.0, 1.0], device=low.device)] * 3)  # (8, 3) children's directions
    kept = []
    while centres.shape[0]:
        radius = side * math.sqrt(3.0) / 2
        separation = hulls_separation(centres, directions, low, high)
        near = separation - radius < margin_m
        centres, separation = centres[near], separation[near]
        leaf = (separation + radius <= margin_m + tolerance_m) | (side <= min_side_m * (1 + 1e-6))
        kept.append((centres[leaf], torch.full_like(separation[leaf], radius), separation[leaf]))
        centres, side = (centres[~leaf][:, None, :] + corner * side / 4).reshape(-1, 3), side / 2
    centre, radius, separation = (torch.cat(parts) for parts in zip(*kept))
    # The ball radius rounded up past float32's rounding of the cube's corners.
    return HandBalls(centre, radius + 1e-7, separation)


def hand_clearance_bounds(
    field: DistanceField, balls: HandBalls, centre: torch.Tensor, frames: torch.Tensor, margin_m: float, slack_m: float, compile: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Lower and upper bounds, (R,) float32 each, of ``hand_clearance``'s least separation of R poses
    of one cloud ((R, 3) grasp centres, (R, 3, 3) grasp -> world ``frames``) from the field's points.

    Lower: ``margin_m`` where no ball can hold a point (clear), else the least s(centre) - radius of
    the balls that may; upper: the least s(q) + d(q) over ball centres q, inf where no node within
    the band is near. A position's distance d is bracketed by its nearest node's value -/+ their gap
    (1-Lipschitz), at most sqrt(3)/2 ``field.cell_m``; ``slack_m`` (metres) widens both bounds by the
    exact pass's rounding. So a pose with upper < margin is blocked, one with lower >= margin clear,
    and the others are within the field's and the balls' resolution of the margin: undecided."""
    fused = compiled(_fused_ball_bounds) if compile else _fused_ball_bounds
    last_node = torch.tensor(field.distance.shape, device=centre.device, dtype=torch.float32) - 1
    grid = (field.distance.reshape(-1), field.origin, last_node, field.cell_m, field.band_m)
    ball = (balls.centre.T.contiguous(), balls.radius + slack_m, balls.separation)
    lower, upper = torch.empty(centre.shape[0], device=centre.device), torch.empty(centre.shape[0], device=centre.device)
    step = max(2, QUERY_BLOCK_ELEMENTS // max(1, balls.radius.shape[0]))
    for start in range(0, centre.shape[0], step):
        block = slice(start, min(start + step, centre.shape[0]))
        bounds = fused(grid, ball, padded_rows(frames[block]), padded_rows(centre[block]), margin_m)
        lower[block], upper[block] = (bound[: block.stop - block.start] for bound in bounds)
    return lower, upper + slack_m


def _fused_ball_bounds(grid: tuple, ball: tuple, frames: torch.Tensor, centre: torch.Tensor, margin_m: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(r,) ``hand_clearance_bounds``' bounds before the slack, element-wise over (pose, ball):
    ``grid`` (flat distances, origin, (3,) last node index as float, cell, band) and ``ball``
    ((3, K) grasp-frame centres, (K,) radii plus slack, (K,) s at the centres)."""
    distance, origin, last_node, cell_m, band_m = grid
    ball_columns, reach, separation = ball
    world = [frames[:, a, 0, None] * ball_columns[0] + frames[:, a, 1, None] * ball_columns[1] + frames[:, a, 2, None] * ball_columns[2]
             + centre[:, a, None] for a in range(3)]
    scaled = [(world[a] - origin[a]) / cell_m for a in range(3)]
    node = [scaled[a].round().clamp(min=0.0).minimum(last_node[a]) for a in range(3)]
    gap = ((scaled[0] - node[0]) ** 2 + (scaled[1] - node[1]) ** 2 + (scaled[2] - node[2]) ** 2).sqrt() * cell_m
    flat = ((node[0] * (last_node[1] + 1) + node[1]) * (last_node[2] + 1) + node[2]).to(torch.int64)
    value = distance[flat]
    outside = (scaled[0] < -0.5) | (scaled[1] < -0.5) | (scaled[2] < -0.5) | (scaled[0] > last_node[0] + 0.5) \
        | (scaled[1] > last_node[1] + 0.5) | (scaled[2] > last_node[2] + 0.5)
    nearest_low = torch.where(outside, band_m, value - gap)
    may_hold = nearest_low <= reach
    lower = torch.where(may_hold, separation - reach, float("inf")).amin(dim=1).clamp_max(margin_m)
    upper = torch.where(value < band_m, separation + value + gap, float("inf")).amin(dim=1)
    return lower, upper


def least_separation(
    points: torch.Tensor, centre: torch.Tensor, frames: torch.Tensor, directions: torch.Tensor, low: torch.Tensor, high: torch.Tensor,
    compile: bool = False,
) -> torch.Tensor:
    """(R,) float32 the least k-DOP separation s(p) of one cloud's (N, 3) world ``points`` (NaN rows
    ignored) from R poses' hulls ((R, 3) centres, (R, 3, 3) grasp -> world ``frames``; ``directions``,
    ``low``, ``high`` as for ``hulls_separation``), inf without points: ``hand_clearance``'s
    exhaustive clearance as one fixed-shape element-wise pass over (pose, point), taken from world
    coordinates a . p - a . c; within ``BOUND_SLACK_M`` + ``RAW_ROUNDING_EPS`` times the coordinates'
    scale of the exact values (``hand_clearance``'s bound). ``compile``: ``_fused_least_separation``
    compiled, else eager."""
    columns = _real_rows(points).T.contiguous()
    axes = directions @ frames.transpose(-1, -2)  # (R, D, 3)
    offset = (axes @ centre[:, :, None]).squeeze(2)  # (R, D)
    middle, half = ((low + high) / 2).contiguous(), ((high - low) / 2).contiguous()
    fused = compiled(_fused_least_separation) if compile else _fused_least_separation
    least = torch.empty(centre.shape[0], device=centre.device)
    step = max(2, QUERY_BLOCK_ELEMENTS // max(1, columns.shape[1]))
    for start in range(0, centre.shape[0], step):
        block = slice(start, min(start + step, centre.shape[0]))
        least[block] = fused(columns, padded_rows(axes[block]), padded_rows(offset[block]), middle, half)[: block.stop - block.start]
    return least


def _fused_least_separation(columns: torch.Tensor, axes: torch.Tensor, offset: torch.Tensor, middle: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """(r,) ``least_separation`` of (3, N) point ``columns`` for (r, D, 3) world ``axes`` with (r, D)
    ``offset``, (S, D) slab ``middle`` and ``half``."""
    projection = [axes[:, d, 0, None] * columns[0] + axes[:, d, 1, None] * columns[1] + axes[:, d, 2, None] * columns[2] - offset[:, d, None]
                  for d in range(axes.shape[1])]
    least = None
    for hull in range(middle.shape[0]):
        excess = None
        for d, along in enumerate(projection):
            term = (along - middle[hull, d]).abs() - half[hull, d]
            excess = term if excess is None else torch.maximum(excess, term)
        least = excess if least is None else torch.minimum(least, excess)
    return least.amin(dim=1)


def exact_pass_slack(points: torch.Tensor, centre: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> float:
    """Metres by which ``least_separation`` and ``hand_clearance_bounds``' world positions may round
    unlike ``hand_clearance``'s exact separations: its bound for coordinates of this scale."""
    return BOUND_SLACK_M + RAW_ROUNDING_EPS * coordinate_scale(points, centre, low, high)
