"""SAGP fused-score terms over a batch of C grasp candidates (the published method's stage 5).

Zones are indexed 0..Z-1 in the caller's vocabulary. Positions and directions are world frame,
metres and unit vectors.
"""
from __future__ import annotations

import torch


def zone_affordance(memberships: torch.Tensor, zone_phi: torch.Tensor, zone_rated: torch.Tensor) -> torch.Tensor:
    """S_afford of each candidate from the ratings of every zone its contact point belongs to.

    A point lies in several zones (a vertical third, two sides, maybe a protrusion). Danger dominates:
    if any rated zone of the point has negative phi the most negative one counts (a dangerous rim
    stays dangerous on the good side); otherwise the best rated zone counts. No rated zone: 0.

    Args:
        memberships: (C, Z) bool, zones of each candidate's contact midpoint.
        zone_phi: (Z,) phi of each zone's rating (good 1, acceptable 0.5, bad -0.5, dangerous -1).
        zone_rated: (Z,) bool, whether the zone has a rating at all.

    Returns:
        (C,) S_afford in [-1, 1].
    """
    counted = memberships & zone_rated.unsqueeze(0)
    phi = zone_phi.unsqueeze(0).expand_as(memberships).to(torch.float32)
    worst = torch.where(counted, phi, torch.full_like(phi, float("inf"))).amin(dim=1)
    best = torch.where(counted, phi, torch.full_like(phi, float("-inf"))).amax(dim=1)
    any_rated = counted.any(dim=1)
    return torch.where(~any_rated, torch.zeros_like(best), torch.where(worst < 0, worst, best))


def zone_avoidance(memberships: torch.Tensor, zone_avoid: torch.Tensor) -> torch.Tensor:
    """(C,) S_avoid: 1 where the candidate's contact point lies in any avoid zone, else 0.

    Args:
        memberships: (C, Z) bool; zone_avoid: (Z,) bool.
    """
    return (memberships & zone_avoid.unsqueeze(0)).any(dim=1).to(torch.float32)


def predicted_swing_tilt(
    grasp_position: torch.Tensor,
    closing_axis: torch.Tensor,
    centre_of_mass: torch.Tensor,
    up: torch.Tensor,
    friction_hold_offset_m: float,
) -> torch.Tensor:
    """Predicted tilt of the object after a straight lift, radians.

    A parallel-jaw grasp leaves the object free to rotate about the closing axis only. Gravity on the
    centre of mass acts with lever arm ``|closing_axis . ((com - grasp) x down)|`` about that axis;
    finger friction holds lever arms up to ``friction_hold_offset_m`` (no tilt), beyond it the object
    swings until its centre of mass hangs straight below the axis: the tilt is that swing angle.

    Args:
        grasp_position: (C, 3) contact midpoints, world frame, metres.
        closing_axis: (C, 3) unit closing axes, world frame.
        centre_of_mass: (3,) object centre of mass (e.g. the cloud centroid), world frame, metres.
        up: (3,) unit world up.
        friction_hold_offset_m: largest lever arm friction holds, metres.

    Returns:
        (C,) predicted tilt in [0, pi] radians.
    """
    down = -up.to(grasp_position.dtype).expand_as(grasp_position)
    offset = centre_of_mass.unsqueeze(0) - grasp_position
    lever = (closing_axis * torch.linalg.cross(offset, down)).sum(dim=1).abs()
    offset_normal = offset - (offset * closing_axis).sum(dim=1, keepdim=True) * closing_axis
    down_normal = down - (down * closing_axis).sum(dim=1, keepdim=True) * closing_axis
    swing = torch.atan2(
        torch.linalg.vector_norm(torch.linalg.cross(offset_normal, down_normal), dim=1),
        (offset_normal * down_normal).sum(dim=1),
    )
    return torch.where(lever > friction_hold_offset_m, swing, torch.zeros_like(swing))


def fused_score(
    s_geom: torch.Tensor,
    s_reach: torch.Tensor,
    s_afford: torch.Tensor,
    s_avoid: torch.Tensor,
    s_task: torch.Tensor,
    weights: tuple[float, float, float, float, float],
) -> torch.Tensor:
    """(C,) S = w_geom S_geom + w_reach S_reach + w_afford S_afford - w_avoid S_avoid + w_task S_task.

    Args:
        s_geom: (C,) geometric term.
        s_reach: (C,) reachability term.
        s_afford: (C,) affordance term.
        s_avoid: (C,) avoid term, subtracted.
        s_task: (C,) task term.
        weights: (w_geom, w_reach, w_afford, w_avoid, w_task), w_avoid entering with a minus sign.
    """
    w_geom, w_reach, w_afford, w_avoid, w_task = weights
    return w_geom * s_geom + w_reach * s_reach + w_afford * s_afford - w_avoid * s_avoid + w_task * s_task
