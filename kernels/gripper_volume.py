"""Collision proxies for a parallel-jaw gripper: swept-volume occupancy and table penetration.

The gripper is described in the grasp frame (origin at the contact midpoint, y = closing axis,
z = approach, see ``grasp_frames``) by three axis-aligned boxes:

* two finger slabs, one outside each contact: |x| <= finger_width/2, z from the finger root to the
  fingertip, and |y| from just outside the contact (width/2 + contact_clearance) out to the open
  finger's back face (open_width/2 + finger_thickness). This is the volume each finger sweeps while
  closing from fully open to the contacts, so any point in it is something the finger would hit
  before touching the grasped surface: the "box swept between the fingers" of the SPEC.
* the palm: |x| <= palm_width/2, |y| <= palm_span/2, from the finger root back by palm_depth.

Points between the contacts (|y| < width/2) are the part being grasped and are not counted; the
``contact_clearance`` keeps the grasped surfaces' own points (which lie at |y| ~ width/2) out of
the count.

Apart from that closing sweep, the open gripper reaches the grasp by a straight descent of
``descent_m`` along +z, so it also sweeps the union of its boxes over that stroke: the open finger
columns (|y| from open_width/2 to the finger's back face) from the fingertip back to the finger
root minus ``descent_m``, and the palm's footprint from the finger root back to the palm's back
face minus ``descent_m``. The palm footprint holds the finger columns' footprint, so this union
is the palm column plus the two open-finger boxes below it. Anything in it is hit before the
fingers close.
"""
from __future__ import annotations

from typing import NamedTuple

import torch


class GripperOccupancy(NamedTuple):
    """Points inside each candidate gripper, split by part: (C, K) int64 each."""

    fingers: torch.Tensor  # inside the two swept finger slabs
    palm: torch.Tensor  # inside the palm box
    descent: torch.Tensor  # inside the open gripper's straight-descent sweep (overlaps the other two)

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
    # The wrist (Panda link 7 and flange) behind the palm: only the table check uses it, since it
    # never reaches the object before the palm does but hangs below low side grasps.
    wrist_half_width_m: float = 0.0
    wrist_length_m: float = 0.0


def gripper_occupancy(
    points: torch.Tensor,
    object_index: torch.Tensor,
    centre: torch.Tensor,
    rotation: torch.Tensor,
    width_m: torch.Tensor,
    geometry: GripperGeometry,
    chunk_elements: int,
    descent_m: float = 0.0,
) -> GripperOccupancy:
    """Count the points inside each candidate gripper's swept finger slabs, its palm, and the
    volume the open gripper sweeps on its straight descent.

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
        descent_m: length of the straight descent onto the grasp along the approach, metres, >= 0
            (0: the open gripper at the grasp pose only).

    Returns:
        ``GripperOccupancy`` of (C, K) int64 counts: finger slabs, palm, their ``total``, and the
        descent sweep.
    """
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"points must be (B, N, 3), got {tuple(points.shape)}")
    if rotation.ndim != 4 or rotation.shape[-2:] != (3, 3) or rotation.shape[0] != centre.shape[0]:
        raise ValueError(f"rotation must be (C, K, 3, 3) matching centre (C, 3), got {tuple(rotation.shape)} and {tuple(centre.shape)}")
    if descent_m < 0.0:
        raise ValueError(f"descent_m must be >= 0, got {descent_m}")
    n_candidates, n_approaches = rotation.shape[:2]
    n_points = points.shape[1]
    finger_z_max = geometry.fingertip_offset_m
    finger_z_min = finger_z_max - geometry.finger_length_m
    palm_z_min = finger_z_min - geometry.palm_depth_m
    finger_y_max = geometry.open_width_m / 2 + geometry.finger_thickness_m
    finger_z_mid, finger_z_half = (finger_z_min + finger_z_max) / 2, (finger_z_max - finger_z_min) / 2
    palm_z_mid, palm_z_half = (palm_z_min + finger_z_min) / 2, (finger_z_min - palm_z_min) / 2
    column_z_mid, column_z_half = (palm_z_min - descent_m + finger_z_min) / 2, (finger_z_min - palm_z_min + descent_m) / 2
    finger_counts = torch.zeros(n_candidates, n_approaches, dtype=torch.int64)
    palm_counts = torch.zeros(n_candidates, n_approaches, dtype=torch.int64)
    open_y_mid, open_y_half = (geometry.open_width_m / 2 + finger_y_max) / 2, geometry.finger_thickness_m / 2
    descent_counts = torch.zeros(n_candidates, n_approaches, dtype=torch.int64)
    step = max(1, chunk_elements // max(1, n_approaches * n_points))
    for start in range(0, n_candidates, step):
        stop = min(start + step, n_candidates)
        relative = points[object_index[start:stop]] - centre[start:stop, None, :]  # (c, N, 3)
        # Grasp-frame coordinates R^T (p - centre) as one batched GEMM with the points along the
        # long output dimension: (c, K*3, 3) @ (c, 3, N) -> (c, K, 3, N).
        grasp_axes = rotation[start:stop].transpose(-1, -2).reshape(stop - start, n_approaches * 3, 3)
        local = (grasp_axes @ relative.transpose(1, 2)).view(stop - start, n_approaches, 3, n_points)
        abs_x = local[:, :, 0].abs()
        abs_y = local[:, :, 1].abs()
        z = local[:, :, 2]
        # Each interval test is one |value - middle| <= half-length comparison to halve the passes
        # over the (c, K, N) coordinates, the planner's most expensive tensors.
        finger_y_min = (width_m[start:stop] / 2 + geometry.contact_clearance_m)[:, None, None]
        in_finger_y = (abs_y - (finger_y_min + finger_y_max) / 2).abs() <= (finger_y_max - finger_y_min) / 2
        in_finger_xz = (abs_x <= geometry.finger_width_m / 2) & ((z - finger_z_mid).abs() <= finger_z_half)
        in_fingers = in_finger_y & in_finger_xz
        in_palm_xy = (abs_y <= geometry.palm_span_m / 2) & (abs_x <= geometry.palm_width_m / 2)
        in_palm = in_palm_xy & ((z - palm_z_mid).abs() <= palm_z_half)
        in_open_fingers = in_finger_xz & ((abs_y - open_y_mid).abs() <= open_y_half)
        in_descent = (in_palm_xy & ((z - column_z_mid).abs() <= column_z_half)) | in_open_fingers
        finger_counts[start:stop] = in_fingers.sum(dim=-1)
        palm_counts[start:stop] = in_palm.sum(dim=-1)
        descent_counts[start:stop] = in_descent.sum(dim=-1)
    return GripperOccupancy(finger_counts, palm_counts, descent_counts)


def gripper_corners_local(geometry: GripperGeometry) -> torch.Tensor:
    """Corners of the open gripper's finger and palm boxes in the grasp frame.

    Returns:
        (M, 3) float32 corner positions, metres: 8 per finger (at the fully open width), 8 for the
        palm and, when the geometry has a wrist, 8 for it (M = 24 or 32).
    """
    finger_z_max = geometry.fingertip_offset_m
    finger_z_min = finger_z_max - geometry.finger_length_m
    inner_y = geometry.open_width_m / 2
    outer_y = inner_y + geometry.finger_thickness_m
    boxes = [
        ((-geometry.finger_width_m / 2, geometry.finger_width_m / 2), (inner_y, outer_y), (finger_z_min, finger_z_max)),
        ((-geometry.finger_width_m / 2, geometry.finger_width_m / 2), (-outer_y, -inner_y), (finger_z_min, finger_z_max)),
        (
            (-geometry.palm_width_m / 2, geometry.palm_width_m / 2),
            (-geometry.palm_span_m / 2, geometry.palm_span_m / 2),
            (finger_z_min - geometry.palm_depth_m, finger_z_min),
        ),
    ]
    if geometry.wrist_length_m > 0.0:
        palm_back = finger_z_min - geometry.palm_depth_m
        half = geometry.wrist_half_width_m
        boxes.append(((-half, half), (-half, half), (palm_back - geometry.wrist_length_m, palm_back)))
    corners = [torch.cartesian_prod(torch.tensor(xs), torch.tensor(ys), torch.tensor(zs)) for xs, ys, zs in boxes]
    return torch.cat(corners).to(torch.float32)


def table_penetration(
    centre: torch.Tensor,
    rotation: torch.Tensor,
    corners_local: torch.Tensor,
    retreat_m: float,
    table_top_z_m: float,
) -> torch.Tensor:
    """Whether the open gripper dips below the table top at the grasp or at the pre-grasp pose.

    The pre-grasp pose is the grasp pose moved ``retreat_m`` back along the approach (grasp -z).

    Args:
        centre: (C, 3) grasp centres, world frame, metres.
        rotation: (C, K, 3, 3) grasp rotations (grasp frame -> world).
        corners_local: (M, 3) gripper box corners in the grasp frame (``gripper_corners_local``).
        retreat_m: pre-grasp distance back along the approach, metres.
        table_top_z_m: world height of the table top, metres.

    Returns:
        (C, K) bool, True where some corner is below the table top at either pose.
    """
    # Only world z matters: z_world = centre_z + R[2, :] . corner.
    row_z = rotation[..., 2, :]  # (C, K, 3)
    corner_z = centre[:, 2, None, None] + row_z @ corners_local.to(rotation).T  # (C, K, M)
    lowest_grasp = corner_z.min(dim=-1).values
    # Retreating along -approach changes every corner's height by -retreat * approach_z.
    lowest_pregrasp = lowest_grasp - retreat_m * rotation[..., 2, 2]
    return (lowest_grasp < table_top_z_m) | (lowest_pregrasp < table_top_z_m)
