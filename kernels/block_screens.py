"""The table, gripper-volume and swept-hand screens of a block of poses as fixed sequences of
element-wise operations: every pose of the block checked against every point, each (pose, point)
value from its own arithmetic, so the work has the block's shape whatever the data.

The data-dependent kernels (``table_penetration``, ``occupancy_verdict``, ``hand_clearance``)
spend their time deciding which poses and points need exact work; these spend it on the work
itself, in a shape a compiler fuses into one loop per check (``torch.compile``: each (pose, point)
value stays in registers) and a GPU runs in one launch. Eager on a CPU they run on slices of
``POSE_SLICE`` poses, whose (pose, point) temporaries stay in cache.

Frames: points, centres and frames in the world; a pose's grasp-frame coordinates are R^T (p - c)
(``grasp_frames``). Each value differs from the exhaustive references' GEMMs by rounding alone
(~1e-8 m at gripper sizes), so only a point within that of a box face, or a separation within it
of the margin, can be decided otherwise.
"""
from __future__ import annotations

import torch

from .gripper_occupancy import GripperGeometry

# Poses per eager slice: a slice's (pose, point) temporaries of ~1,000 points are ~1 MB.
POSE_SLICE = 256


def lowest_hand_height(centre_z: torch.Tensor, rotation: torch.Tensor, vertices: torch.Tensor, retreat_m: float) -> torch.Tensor:
    """(R, K) world height of the lowest of ``vertices`` at the grasp or at the pre-grasp (the grasp
    moved ``retreat_m`` back along the approach) of R candidates' K poses.

    Args:
        centre_z: (R,) grasp centres' world heights, metres.
        rotation: (R, K, 3, 3) grasp frames (grasp -> world).
        vertices: (V, 3) hand hull vertices, grasp frame, metres.
        retreat_m: pre-grasp distance back along the approach (grasp -z), metres.
    """
    heights = (rotation[..., 2, None, :] * vertices).sum(dim=-1).amin(dim=-1) + centre_z[:, None]  # (R, K)
    return torch.minimum(heights, heights - retreat_m * rotation[..., 2, 2])


def gripper_point_counts(
    columns: torch.Tensor, centre: torch.Tensor, frames: torch.Tensor, finger_y_min: torch.Tensor, geometry: GripperGeometry,
) -> torch.Tensor:
    """(P,) float32 points inside each pose's finger slabs or palm (``gripper_occupancy``'s boxes).

    Args:
        columns: (3, N) the scene's points as world x, y and z rows, metres; NaN columns are never inside.
        centre: (P, 3) grasp centres, world. frames: (P, 3, 3) grasp frames (grasp -> world).
        finger_y_min: (P,) |y| where each pose's finger slabs begin (half the width plus the contact clearance).
        geometry: the gripper's boxes.
    """
    x, y, z = _grasp_coordinates(columns, centre, frames)
    finger_y_max = geometry.finger_y_max
    finger_z_mid = (geometry.finger_z_min + geometry.fingertip_offset_m) / 2
    finger_z_half = (geometry.fingertip_offset_m - geometry.finger_z_min) / 2
    palm_z_mid, palm_z_half = (geometry.palm_z_min + geometry.finger_z_min) / 2, geometry.palm_depth_m / 2
    abs_x, abs_y = x.abs(), y.abs()
    finger_y_mid, finger_y_half = ((finger_y_min + finger_y_max) / 2)[:, None], ((finger_y_max - finger_y_min) / 2)[:, None]
    in_fingers = ((abs_y - finger_y_mid).abs() <= finger_y_half) & (abs_x <= geometry.finger_width_m / 2) & ((z - finger_z_mid).abs() <= finger_z_half)
    in_palm = (abs_y <= geometry.palm_span_m / 2) & (abs_x <= geometry.palm_width_m / 2) & ((z - palm_z_mid).abs() <= palm_z_half)
    return (in_fingers | in_palm).sum(dim=1, dtype=torch.float32)


def hand_probe(
    columns: torch.Tensor, centre: torch.Tensor, frames: torch.Tensor, directions: torch.Tensor, low: torch.Tensor, high: torch.Tensor,
    runs: int,
) -> torch.Tensor:
    """(P,) each pose's least k-DOP separation s(p) of the swept hand from its probes: an upper bound
    of its least separation from any scene point, so a pose whose probes come under the margin is
    blocked.

    s(p) is the largest slab excess over the D directions, least over the S polytopes (see
    ``hand_clearance``). A pose's probes are, in each of ``runs`` runs of consecutive points (a
    voxel subset's runs are regions of the scene), the point least by the bound over the first
    three directions: a blocking point is almost always the least-bound one of its region. The
    runs' argmins are reductions a compiler fuses with the bound, so no (pose, point) tensor is kept.

    Args:
        columns: (3, N) scene points as world x, y and z rows, N a multiple of ``runs`` (NaN
            columns: padding, never near).
        centre: (P, 3) grasp centres, world. frames: (P, 3, 3) grasp frames (grasp -> world).
        directions: (D, 3) unit k-DOP directions, grasp frame, the first three the bound's.
        low, high: (S, D) the polytopes' extents, metres. runs: probes per pose.
    """
    middle, half = (low + high) / 2, (high - low) / 2
    axes = directions @ frames.transpose(1, 2)  # (P, D, 3): u_d^T R^T
    projection = [_projected(columns, centre, axes[:, d]) for d in range(3)]
    bound = _least_excess(projection, middle[:, :3], half[:, :3]).nan_to_num(nan=float("inf"))  # (P, N)
    run_length = columns.shape[1] // runs
    probe = bound.view(-1, runs, run_length).argmin(dim=2) + torch.arange(0, columns.shape[1], run_length, device=columns.device)
    points = columns.T[probe] - centre[:, None, :]  # (P, runs, 3) about the centre, as ``_projected`` takes them
    exact = [(axes[:, d, None, 0] * points[..., 0] + axes[:, d, None, 1] * points[..., 1]) + axes[:, d, None, 2] * points[..., 2]
             for d in range(directions.shape[0])]
    separation = _least_excess(exact, middle, half).nan_to_num(nan=float("inf"))
    return separation.amin(dim=1)


def _grasp_coordinates(columns: torch.Tensor, centre: torch.Tensor, frames: torch.Tensor) -> list[torch.Tensor]:
    """(P, N) grasp-frame x, y and z of the points (``columns`` (3, N)) for P poses: a_d . (p - c)."""
    return [_projected(columns, centre, frames[:, :, axis]) for axis in range(3)]


def _projected(columns: torch.Tensor, centre: torch.Tensor, axis: torch.Tensor) -> torch.Tensor:
    """(P, N) a . (p - c) of the points (``columns`` (3, N)) for P axes a (P, 3) and centres c (P, 3),
    summed (x + y) + z as ``hand_nearest_points``' exact projections are."""
    return ((axis[:, 0, None] * (columns[0] - centre[:, 0, None]) + axis[:, 1, None] * (columns[1] - centre[:, 1, None]))
            + axis[:, 2, None] * (columns[2] - centre[:, 2, None]))


def _least_excess(projection: list[torch.Tensor], middle: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """The largest slab excess |projection_d - middle_d| - half_d over the directions of ``projection``
    (D tensors of one shape), least over the (S, D) polytopes' ``middle`` and ``half``."""
    least = None
    for polytope in range(middle.shape[0]):
        excess = None
        for d, values in enumerate(projection):
            term = (values - middle[polytope, d]).abs() - half[polytope, d]
            excess = term if excess is None else torch.maximum(excess, term)
        least = excess if least is None else torch.minimum(least, excess)
    return least
