"""Width and antipodal filtering of contact pairs, and the geometric quality S_geom.

Sign convention. Normals are OUTWARD (pointing away from the object). With the closing axis
``a = (p_j - p_i) / |p_j - p_i|`` from contact i to contact j, a well-posed pinch has each
contact's outward normal pointing away from the other contact: ``n_i ~ -a`` and ``n_j ~ +a``.
The published angles angle(n_i, a) and angle(n_j, -a) are therefore measured with the inward normals
``-n_i`` and ``-n_j``, i.e. the contact cosines are

    cos_i = -n_i . a        cos_j = n_j . a

and a pair is antipodal when both cosines exceed cos(max angle). S_geom = cos_i * cos_j.
"""
from __future__ import annotations

import math

import torch


def antipodal_pairs(
    points: torch.Tensor,
    normals: torch.Tensor,
    pair_indices: torch.Tensor,
    min_width_m: float,
    max_width_m: float,
    max_contact_angle_deg: float,
) -> dict[str, torch.Tensor]:
    """Evaluate P contact pairs at once.

    Args:
        points: (N, 3) contact positions, metres, any frame shared with ``normals``.
        normals: (N, 3) unit outward surface normals in the same frame.
        pair_indices: (P, 2) int64 indices ``(i, j)`` into ``points``.
        min_width_m: smallest accepted contact distance |p_j - p_i|, metres (inclusive).
        max_width_m: largest accepted contact distance, metres (inclusive).
        max_contact_angle_deg: largest accepted angle between each inward normal and the closing
            axis, degrees.

    Returns:
        dict of tensors over the P pairs:
            ``closing_axis`` (P, 3) unit vector from contact i to contact j (zero for coincident points),
            ``width_m`` (P,) contact distance,
            ``cos_i``, ``cos_j`` (P,) contact cosines as defined in the module docstring,
            ``s_geom`` (P,) ``cos_i * cos_j`` (0 where the pair is rejected),
            ``width_ok`` (P,) bool, ``antipodal`` (P,) bool (width and both angles pass).
    """
    if points.ndim != 2 or points.shape[-1] != 3 or normals.shape != points.shape:
        raise ValueError(f"points and normals must both be (N, 3), got {tuple(points.shape)} and {tuple(normals.shape)}")
    if pair_indices.ndim != 2 or pair_indices.shape[-1] != 2:
        raise ValueError(f"pair_indices must be (P, 2), got {tuple(pair_indices.shape)}")
    p_i = points[pair_indices[:, 0]]
    p_j = points[pair_indices[:, 1]]
    offset = p_j - p_i
    width = offset.norm(dim=-1)
    closing_axis = offset / width.clamp_min(torch.finfo(points.dtype).tiny).unsqueeze(-1)
    cos_i = -(normals[pair_indices[:, 0]] * closing_axis).sum(-1)
    cos_j = (normals[pair_indices[:, 1]] * closing_axis).sum(-1)
    width_ok = (width >= min_width_m) & (width <= max_width_m)
    min_cos = math.cos(math.radians(max_contact_angle_deg))
    antipodal = width_ok & (cos_i > min_cos) & (cos_j > min_cos)
    s_geom = torch.where(antipodal, cos_i * cos_j, torch.zeros_like(width))
    return {
        "closing_axis": closing_axis,
        "width_m": width,
        "cos_i": cos_i,
        "cos_j": cos_j,
        "s_geom": s_geom,
        "width_ok": width_ok,
        "antipodal": antipodal,
    }
