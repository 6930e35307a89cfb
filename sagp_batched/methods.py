"""The compared methods as a registry: each name's ranking of a trial's candidates and what it needs.

Every method ranks the identical candidate set of a trial and returns the candidates scored, with
the attempts to make, best first: Geometry-Only keeps S_geom order, SAGP ranks by the fused score,
VLM-Direct lets a vision-language model pick among the top geometric candidates.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .config import GEOMETRY_ONLY_WEIGHTS, Config, ScoreWeights
from .rating.types import ZoneRating
from .scoring import score_candidates
from .types import METHODS, GraspCandidates, PerceivedCloud
from .zones import ZoneDecomposition


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
    rank: Callable[[RankingInputs], tuple[GraspCandidates, list[int]]]


def _scored(inputs: RankingInputs, weights: ScoreWeights) -> GraspCandidates:
    return score_candidates(inputs.candidates, inputs.rating, weights, inputs.zones, inputs.config)


def _first_attempts(scored: GraspCandidates, config: Config) -> list[int]:
    return list(range(min(config.execution.max_attempts, len(scored))))


def _rank_geometry_only(inputs: RankingInputs) -> tuple[GraspCandidates, list[int]]:
    scored = _scored(inputs, GEOMETRY_ONLY_WEIGHTS)
    return scored, _first_attempts(scored, inputs.config)


def _rank_sagp(inputs: RankingInputs) -> tuple[GraspCandidates, list[int]]:
    scored = _scored(inputs, inputs.config.weights)
    return scored, _first_attempts(scored, inputs.config)


def _rank_vlm_direct(inputs: RankingInputs) -> tuple[GraspCandidates, list[int]]:
    from .vlm_direct import vlm_direct_rank

    scored = _scored(inputs, GEOMETRY_ONLY_WEIGHTS)
    shortlist = vlm_direct_rank(inputs.cloud, scored, inputs.model_client(), inputs.config, inputs.task, inputs.object_name)
    return scored, [int(i) for i in shortlist.order[: inputs.config.execution.max_attempts]]


REGISTRY: dict[str, Method] = {
    method.name: method
    for method in (
        Method("go", "Geometry-Only", needs_model=False, rank=_rank_geometry_only),
        Method("sagp", "SAGP", needs_model=False, rank=_rank_sagp),
        Method("vd", "VLM-Direct", needs_model=True, rank=_rank_vlm_direct),
    )
}
assert tuple(REGISTRY) == METHODS, "every method name of the types layer has exactly one registered method"


def get_method(name: str) -> Method:
    if name not in REGISTRY:
        raise ValueError(f"unknown method '{name}' (known: {', '.join(REGISTRY)})")
    return REGISTRY[name]
