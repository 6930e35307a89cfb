"""The gripper as a collision proxy: the points inside a parallel-jaw gripper's swept volume.

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

``gripper_occupancy`` counts every point; ``occupancy_verdict.gripper_occupancy_within`` decides
those counts against a limit as this count would, at less cost.
"""
from __future__ import annotations

from typing import NamedTuple

import torch

from .grasp_frames import scene_points_about


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
        poses = torch.ones(n_candidates, n_approaches, dtype=torch.bool, device=centre.device)
    n_points = points.shape[1]
    finger_counts = torch.zeros(n_candidates * n_approaches, dtype=torch.int64, device=centre.device)
    palm_counts = torch.zeros(n_candidates * n_approaches, dtype=torch.int64, device=centre.device)
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
        finger_y_min = (width_m[rows] / 2 + geometry.contact_clearance_m).repeat_interleave(n_approaches)[chosen, None]
        pose_index = (rows[:, None] * n_approaches + torch.arange(n_approaches, device=rows.device)).view(-1)[chosen]
        finger_counts[pose_index], palm_counts[pose_index] = _box_counts(local, finger_y_min, geometry)
    shape = (n_candidates, n_approaches)
    return GripperOccupancy(finger_counts.view(shape), palm_counts.view(shape))


def _box_counts(local: torch.Tensor, finger_y_min: torch.Tensor, geometry: GripperGeometry) -> tuple[torch.Tensor, torch.Tensor]:
    """(R,) int64 counts of the points inside the finger slabs and inside the palm, of R poses'
    grasp-frame coordinates ``local`` (R, 3, N), the slabs starting at |y| = ``finger_y_min`` (R, 1)."""
    finger_z_max, finger_z_min, palm_z_min = geometry.fingertip_offset_m, geometry.finger_z_min, geometry.palm_z_min
    finger_y_max = geometry.finger_y_max
    finger_z_mid, finger_z_half = (finger_z_min + finger_z_max) / 2, (finger_z_max - finger_z_min) / 2
    palm_z_mid, palm_z_half = (palm_z_min + finger_z_min) / 2, (finger_z_min - palm_z_min) / 2
    abs_x = local[:, 0].abs()
    abs_y = local[:, 1].abs()
    z = local[:, 2]
    # Each interval test is one |value - middle| <= half-length comparison to halve the passes
    # over the (R, N) coordinates, the planner's most expensive tensors.
    in_finger_y = (abs_y - (finger_y_min + finger_y_max) / 2).abs() <= (finger_y_max - finger_y_min) / 2
    in_finger_xz = (abs_x <= geometry.finger_width_m / 2) & ((z - finger_z_mid).abs() <= finger_z_half)
    in_fingers = in_finger_y & in_finger_xz
    in_palm_xy = (abs_y <= geometry.palm_span_m / 2) & (abs_x <= geometry.palm_width_m / 2)
    in_palm = in_palm_xy & ((z - palm_z_mid).abs() <= palm_z_half)
    return in_fingers.sum(dim=-1), in_palm.sum(dim=-1)
