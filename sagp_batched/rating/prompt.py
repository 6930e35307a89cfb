"""The structured zone-rating prompt and the JSON schema of its answer; the prompt's version is part of every cache key."""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..types import PROTRUSION, TASKS, ZONE_NAMES, is_zone_name
from .zone_rating import APPROACH_NAMES, GRASP_STYLES, RATING_LEVELS, RatingError

PROMPT_VERSION = "sagp-zones-v2"
# A model names an approach direction; a world vector ("vector") is not asked of it.
ANSWER_APPROACHES: tuple[str, ...] = tuple(a for a in APPROACH_NAMES if a != "vector")


def prompt_version(marked: bool) -> str:
    """The cache-key version of the prompt ``build_zone_prompt(..., marked=marked)`` writes."""
    return f"{PROMPT_VERSION}-marks" if marked else PROMPT_VERSION


def task_description(task: str) -> str:
    if task not in TASKS:
        raise RatingError(f"unknown task '{task}' (known: {', '.join(TASKS)})")
    return TASKS[task]


def checked_image(image: np.ndarray, name: str = "crop_rgb") -> np.ndarray:
    """``image`` as an (H, W, 3) uint8 array, or a ``RatingError`` naming what is wrong."""
    array = np.asarray(image)
    if array.ndim != 3 or array.shape[2] != 3 or array.shape[0] == 0 or array.shape[1] == 0 or array.dtype != np.uint8:
        raise RatingError(f"{name} must be a non-empty (H, W, 3) uint8 image, got shape {array.shape} dtype {array.dtype}")
    return array


ZONE_ANSWER_SCHEMA_NAME = "zone_rating"


def zone_answer_schema() -> dict[str, Any]:
    """The JSON schema of the answer ``build_zone_prompt`` asks for, built from the rating vocabulary.

    Zone names are not enumerated (``protrusion_<n>`` depends on the object); the parser checks them."""
    return {
        "type": "object",
        "properties": {
            "ratings": {"type": "object", "additionalProperties": {"type": "string", "enum": list(RATING_LEVELS)}},
            "preferred": {"type": "array", "items": {"type": "string"}},
            "avoid": {"type": "array", "items": {"type": "string"}},
            "approach": {"type": "string", "enum": list(ANSWER_APPROACHES)},
            "grasp_style": {"type": "string", "enum": list(GRASP_STYLES)},
            "max_tilt_deg": {"type": ["number", "null"]},
        },
        "required": ["ratings", "preferred", "avoid", "approach", "grasp_style", "max_tilt_deg"],
    }


def answer_zone_names(zone_descriptions: Mapping[str, str]) -> list[str]:
    """The zone names the prompt about ``zone_descriptions`` lets the model use: the described zones,
    and ``protrusion`` (all of them at once) where a ``protrusion_<n>`` is described."""
    names = list(zone_descriptions)
    if any(name.startswith(f"{PROTRUSION}_") for name in names):
        names.append(PROTRUSION)
    return names


def build_zone_prompt(object_name: str, task: str, zone_descriptions: Mapping[str, str], *, marked: bool = False) -> str:
    """The text sent beside the object crop: task, zones with their geometry, and the JSON to answer.

    ``marked``: the image carries the zones (``zone_marks.draw_zone_marks``), so the text points the
    model at the labelled dots; its version is then ``prompt_version(True)``."""
    unknown = [z for z in zone_descriptions if not is_zone_name(z)]
    if unknown:
        raise RatingError(f"zone descriptions name unknown zones {unknown} (known: {', '.join(ZONE_NAMES)}, {PROTRUSION}_<n>)")
    zone_lines = "\n".join(f"- {description}" for description in zone_descriptions.values())
    names = answer_zone_names(zone_descriptions)
    return (
        f"The image shows a {object_name} on a table, seen by a robot with a parallel-jaw gripper.\n"
        f"Task: {task_description(task)}.\n"
        "The object is divided into coarse zones (vertical thirds of its height, the halves on each side, "
        "and parts that stick out):\n"
        f"{zone_lines}\n"
        + (
            "The vertical thirds and the parts that stick out are drawn on the image as coloured dots, each "
            "labelled with its zone name in a box (the side halves are not drawn); use those marks to tell "
            "which part of the object each zone is.\n"
            if marked else ""
        )
        + f"Rate every zone for grasping in this task as one of {', '.join(RATING_LEVELS)}. "
        "Answer with one JSON object and nothing else:\n"
        '{"ratings": {"<zone>": "<level>", ...}, "preferred": ["<zone>", ...], "avoid": ["<zone>", ...], '
        f'"approach": "<one of {"|".join(ANSWER_APPROACHES)}>", '
        f'"grasp_style": "<one of {"|".join(GRASP_STYLES)}>", '
        '"max_tilt_deg": <largest tilt of the object the task allows, in degrees, or null>}\n'
        f"Zone names must come from: {', '.join(names)}"
        + (f" ('{PROTRUSION}' rates every {PROTRUSION}_<n> zone at once)." if PROTRUSION in names else ".")
    )
