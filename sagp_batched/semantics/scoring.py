"""SAGP fused scoring of a candidate batch (the published method's stage 5).

Zone terms use the zones a candidate is rated by, which zoning put on the batch
(``GraspCandidates.rated_zones``: its primary zone, where protrusion wins over the third as the
published method says, and its two side zones): S_afford follows ``zone_affordance``'s danger-dominates rule, S_avoid is 1 when any of those
zones is avoided. S_task
needs both the prescribed approach (within ``rating.approach_tolerance_deg``; "any" always holds;
"side" means any approach within the tolerance of horizontal) and the predicted post-lift tilt (a
swing about the closing axis, centre of mass = cloud centroid) within the rating's ``max_tilt_deg``.
A neutral rating rates nothing, prescribes nothing: S_afford = S_avoid = 0 and S_task = 1 for every
candidate, so the ranking is by geometry and reach alone.
"""
from __future__ import annotations

import math

import torch

from sagp_batched_kernels import scoring as score_kernels

from ..config import Config, ScoreWeights
from ..grasps import GraspCandidates
from ..rating.zone_rating import PHI, ZoneRating


class ScoringInputError(ValueError):
    """Candidates, zones and rating handed to scoring do not fit together."""


def prescribed_approach_world(zone_rating: ZoneRating, config: Config) -> torch.Tensor | None:
    """(3,) unit direction the gripper must move in, world frame; None for "any" and "side" (no single vector)."""
    up = torch.tensor(config.zones.up_world)
    left = torch.tensor(config.zones.left_world)
    front = torch.tensor(config.zones.front_world)
    # The gripper comes from outside the named side, so it moves opposite to that side's outward direction.
    directions = {"top": -up, "front": -front, "back": front, "left": -left, "right": left}
    if zone_rating.approach == "vector":
        return torch.tensor(zone_rating.approach_vector_world, dtype=torch.float32)
    return directions.get(zone_rating.approach)


def approach_satisfied(approach: torch.Tensor, zone_rating: ZoneRating, config: Config) -> torch.Tensor:
    """(C,) bool: each approach (C, 3) lies within ``rating.approach_tolerance_deg`` of the prescription."""
    tolerance = math.radians(config.rating.approach_tolerance_deg)
    if zone_rating.approach == "any":
        return torch.ones(approach.shape[0], dtype=torch.bool)
    if zone_rating.approach == "side":
        up = torch.tensor(config.zones.up_world, dtype=approach.dtype)
        return (approach @ up).abs() <= math.sin(tolerance)
    direction = prescribed_approach_world(zone_rating, config).to(approach.dtype)
    return approach @ direction >= math.cos(tolerance)


def score_candidates(
    candidates: GraspCandidates,
    zone_rating: ZoneRating,
    weights: ScoreWeights,
    centre_of_mass_world: torch.Tensor | None,
    config: Config,
) -> GraspCandidates:
    """``candidates`` with ``s_afford``, ``s_avoid``, ``s_task`` and ``score`` filled, ranked by score (stable).

    ``candidates`` must carry their zones (``zones.assign_zones``); ``centre_of_mass_world`` (3,)
    is the predicted centre of mass (the cloud's centroid; None for an empty cloud), needed only
    by an orientation constraint; ``weights`` is ``config.weights`` for SAGP and
    ``GEOMETRY_ONLY_WEIGHTS`` for Geometry-Only.
    """
    if candidates.rated_zones is None:
        raise ScoringInputError("candidates carry no zones: zone them (zones.assign_zones) before scoring")
    memberships = candidates.rated_zones
    # A protrusion_<n> zone without a rating of its own takes the rating of "protrusion".
    levels = [zone_rating.level(z) for z in candidates.zone_names]
    zone_phi = torch.tensor([PHI.get(level or "", 0.0) for level in levels])
    zone_rated = torch.tensor([level is not None for level in levels], dtype=torch.bool)
    zone_avoid = torch.tensor([zone_rating.avoids(z) for z in candidates.zone_names], dtype=torch.bool)
    s_afford = score_kernels.zone_affordance(memberships, zone_phi, zone_rated)
    s_avoid = score_kernels.zone_avoidance(memberships, zone_avoid)

    task_ok = approach_satisfied(candidates.approach, zone_rating, config)
    if zone_rating.max_tilt_deg is not None:
        if centre_of_mass_world is None:
            raise ScoringInputError("an orientation constraint needs a centre of mass, but the cloud is empty")
        tilt = score_kernels.predicted_swing_tilt(
            candidates.position, candidates.closing_axis, centre_of_mass_world, torch.tensor(config.zones.up_world),
            config.rating.friction_hold_offset_m,
        )
        task_ok = task_ok & (tilt <= math.radians(zone_rating.max_tilt_deg))
    s_task = task_ok.to(torch.float32)
    score = score_kernels.fused_score(
        candidates.s_geom, candidates.s_reach, s_afford, s_avoid, s_task,
        (weights.geom, weights.reach, weights.afford, weights.avoid, weights.task),
    )
    scored = candidates.with_fields(s_afford=s_afford, s_avoid=s_avoid, s_task=s_task, score=score)
    return scored.ranked_by(score)
