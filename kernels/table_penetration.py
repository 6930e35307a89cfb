"""Whether a gripper dips below the table top: ``table_penetration`` takes any set of gripper
points in the grasp frame (see ``grasp_frames``) and checks them at the grasp and the pre-grasp pose.
"""
from __future__ import annotations

import torch

# Float32 rounding of the table check's bounds (a few 1e-8 m at these sizes) is far inside this.
TABLE_BOUND_SLACK_M = 1e-5
# Poses whose heights of hand points the table check takes from one GEMM: the heights (~1 MB for
# the 32-point cover) stay in cache for the minimum that follows, where one GEMM over every pose
# of a block of candidates would not; half or twice this serves as well.
TABLE_BLOCK_POSES = 8192
# Points that bound a pose's lowest hand point for the table check: 32 of the hand's 204 hull
# vertices cover every vertex within 2.5 cm, leaving ~10 % of a cloud's poses to check on all.
TABLE_COVER_POINTS = 32


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
    # amin, not min: min also finds the indices, which are not needed.
    if n_blocks <= 1:  # most calls: no split and concatenation
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
    return torch.tensor(chosen, device=points.device), float(distance.max()) if points.shape[0] else 0.0
