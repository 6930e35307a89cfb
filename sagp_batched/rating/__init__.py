"""Zone-rating backends: a local VLM, an OpenAI-compatible endpoint, and an offline prior."""
from .json_answer import extract_json_object
from .parse import parse_zone_rating
from .prompt import PROMPT_VERSION, build_zone_prompt
from .raters import CachedRater, PriorRater, Rater, VLMRater, get_rater
from .zone_rating import (
    PHI,
    RATING_LEVELS,
    RatingError,
    RatingProvenance,
    VLMRequestError,
    ZoneRating,
    neutral_rating,
)
from .vlm import OpenAIVLM, TransformersVLM, VLMClient, get_vlm_client

__all__ = [
    "PHI", "PROMPT_VERSION", "RATING_LEVELS", "CachedRater", "OpenAIVLM", "PriorRater", "Rater",
    "RatingError", "RatingProvenance", "TransformersVLM", "VLMClient", "VLMRater", "VLMRequestError", "ZoneRating",
    "build_zone_prompt", "extract_json_object", "get_rater", "get_vlm_client", "neutral_rating", "parse_zone_rating",
]
