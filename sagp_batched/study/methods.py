"""The compared methods as a registry: each name's ranking of a trial's candidates and what it needs.

Every method ranks the identical candidate set of a trial and returns it scored and ranked, best
first; execution runs the first ``execution.max_attempts``: Geometry-Only ranks by S_geom, SAGP by
the fused score, VLM-Direct puts the vision-language model's picks among the top geometric
candidates first.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..config import GEOMETRY_ONLY_WEIGHTS, Config, ScoreWeights
from ..rating.zone_rating import ZoneRating
from ..semantics.scoring import score_candidates
import torch

from ..grasps import GraspCandidates
from ..semantics.zones import ZoneDecomposition
from ..types import METHODS, PerceivedCloud


@dataclass(frozen=True)
class RankingInputs:
    """What a method may use to rank one trial's candidates."""

    candidates: GraspCandidates
    cloud: PerceivedCloud
    rating: ZoneRating
    zones: ZoneDecomposition
    object_name: str
    task: str
    config: Config
    # The model client to ask, built only by a method that needs one (the rater's own, if it has one).
    model_client: Callable[[], Any]


@dataclass(frozen=True)
class Method:
    name: str
    label: str  # as tables print it
    needs_model: bool  # asks a vision-language model itself (not only through the zone rating)
    # Ranks by the zone rating: a trial whose rater failed fails this method; one without it runs
    # on (its record's rating, for judging, is then the neutral one).
    uses_rating: bool
    # Its planning time (``times_s["rating"]`` and ``"total_plan"``) counts the zone rating's time: the
    # published timing charges it to every method that consults a vision-language model, so only
    # Geometry-Only, which plans without one, is timed without it.
    plan_time_counts_rating: bool
    rank: Callable[[RankingInputs], GraspCandidates]  # the candidates scored and ranked, best first


def _scored(inputs: RankingInputs, weights: ScoreWeights) -> GraspCandidates:
    return score_candidates(inputs.candidates, inputs.rating, weights, inputs.zones.centre_of_mass_world, inputs.config)


def _rank_geometry_only(inputs: RankingInputs) -> GraspCandidates:
    return _scored(inputs, GEOMETRY_ONLY_WEIGHTS)


def _rank_sagp(inputs: RankingInputs) -> GraspCandidates:
    return _scored(inputs, inputs.config.weights)


def _rank_vlm_direct(inputs: RankingInputs) -> GraspCandidates:
    from ..semantics.vlm_direct import vlm_direct_rank

    geometric = _scored(inputs, GEOMETRY_ONLY_WEIGHTS)
    shortlist = vlm_direct_rank(inputs.cloud, geometric, inputs.model_client(), inputs.config, inputs.task, inputs.object_name)
    # The model's order of the shortlist, then every other candidate in geometric order.
    shortlisted = set(shortlist.order)
    rest = [index for index in range(len(geometric)) if index not in shortlisted]
    return geometric.select(torch.tensor(shortlist.order + rest, dtype=torch.int64))


REGISTRY: dict[str, Method] = {
    method.name: method
    for method in (
        Method("go", "Geometry-Only", needs_model=False, uses_rating=False, plan_time_counts_rating=False,
               rank=_rank_geometry_only),
        Method("sagp", "SAGP", needs_model=False, uses_rating=True, plan_time_counts_rating=True, rank=_rank_sagp),
        # VLM-Direct's shortlist is drawn from the geometric ranking; the zone rating has no part in it.
        Method("vd", "VLM-Direct", needs_model=True, uses_rating=False, plan_time_counts_rating=True,
               rank=_rank_vlm_direct),
    )
}
assert tuple(REGISTRY) == METHODS, "every method name of the types layer has exactly one registered method"


def get_method(name: str) -> Method:
    if name not in REGISTRY:
        raise ValueError(f"unknown method '{name}' (known: {', '.join(REGISTRY)})")
    return REGISTRY[name]
