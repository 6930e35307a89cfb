"""VLM-Direct baseline: the model ranks numbered candidates drawn on the object image, with no zones.

The first ``rating.vd_num_candidates`` candidates of the batch ranked by Geometry-Only (S_geom) are projected through the camera that
produced the crop, drawn as numbered markers (1..K), and the model is asked for a ranked shortlist.
Its answer is untrusted: non-integer, out-of-range and repeated ids are dropped with a logged
reason. The returned order is the model's shortlist followed by the rest of the top-K in geometric
order (so execution always has candidates to try); with no valid id at all the order is purely
geometric and marked ``fallback``.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageFont

from ..config import Config, RatingConfig
from ..grasps import GraspCandidates
from ..rating.json_answer import MAX_NUMBER_CHARS, excerpt, extract_json_object, extract_json_value
from ..rating.prompt import checked_image, task_description
from ..rating.zone_rating import RatingError, VLMRequestError
from ..rating.vlm import VLMClient, get_vlm_client
from ..types import PerceivedCloud

log = logging.getLogger(__name__)


class VLMDirectUnavailable(RuntimeError):
    """VLM-Direct cannot run: the rating backend has no model (``prior``) or the cloud lacks its crop box."""


@dataclass
class VLMDirectResult:
    order: list[int]  # indices into the candidates given, best first
    n_from_model: int  # how many leading entries of ``order`` the model chose
    fallback: bool  # True when the model gave no valid id and ``order`` is geometric
    backend: str
    model: str
    latency_s: float
    raw_text: str
    dropped: list[str] = field(default_factory=list)  # reasons for every id the parser rejected
    marker_image: np.ndarray | None = None  # (H, W, 3) uint8 image the model saw


def get_vd_client(config: RatingConfig) -> VLMClient:
    """The model client VLM-Direct asks; ``VLMDirectUnavailable`` for the ``prior`` backend."""
    if config.backend == "prior":
        raise VLMDirectUnavailable("VLM-Direct needs a vision-language model; rating backend 'prior' is a table, not a model")
    try:
        return get_vlm_client(config)
    except RatingError as exc:
        raise VLMDirectUnavailable(str(exc)) from exc


def project_to_crop(points_world: torch.Tensor, cloud: PerceivedCloud) -> np.ndarray:
    """(K, 2) pixel (u, v) of each world point (K, 3) in ``cloud.crop_rgb``'s coordinates."""
    if cloud.crop_box_px is None:
        raise VLMDirectUnavailable("the cloud does not record crop_box_px, so candidates cannot be drawn on its crop")
    if not 0 <= cloud.crop_camera_index < len(cloud.cameras):
        raise VLMDirectUnavailable(f"crop_camera_index {cloud.crop_camera_index} names none of {len(cloud.cameras)} cameras")
    camera = cloud.cameras[cloud.crop_camera_index]
    world_to_camera = np.linalg.inv(camera.camera_to_world)
    points = points_world.double().numpy()
    in_camera = points @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    depth = np.clip(in_camera[:, 2], 1e-6, None)
    intrinsics = camera.intrinsics
    u = intrinsics[0, 0] * in_camera[:, 0] / depth + intrinsics[0, 2]
    v = intrinsics[1, 1] * in_camera[:, 1] / depth + intrinsics[1, 2]
    u0, v0, _, _ = cloud.crop_box_px
    return np.stack([u - u0, v - v0], axis=1)


def scaled_crop(crop_rgb: np.ndarray, config: RatingConfig) -> tuple[Image.Image, float]:
    """The crop scaled up to ``vd_image_min_side_px`` on its short side (never down), and the scale
    (image pixels per crop pixel), so marks drawn on it stay legible to a model."""
    image = Image.fromarray(checked_image(crop_rgb))
    scale = max(1.0, config.vd_image_min_side_px / min(image.size))
    return image.resize((round(image.width * scale), round(image.height * scale)), Image.Resampling.LANCZOS), scale


def draw_candidate_markers(crop_rgb: np.ndarray, pixels: np.ndarray, config: RatingConfig) -> np.ndarray:
    """The crop, scaled up to ``vd_image_min_side_px`` on its short side, with markers 1..K at ``pixels`` (K, 2).

    Markers that fall outside the crop (points seen only by the other cameras) are clamped to its border
    so the model is shown every id it may answer.
    """
    image, scale = scaled_crop(crop_rgb, config)
    draw = ImageDraw.Draw(image)
    radius = config.vd_marker_radius_px
    font = ImageFont.load_default(size=int(radius * 1.4))
    centres = np.clip(pixels * scale, [radius, radius], [image.width - radius - 1, image.height - radius - 1])
    for number, (u, v) in enumerate(centres, start=1):
        draw.ellipse((u - radius, v - radius, u + radius, v + radius), fill=(255, 255, 255), outline=(220, 0, 0), width=2)
        draw.text((u, v), str(number), fill=(0, 0, 0), font=font, anchor="mm")
    return np.asarray(image)


def build_vd_prompt(object_name: str, task: str, n_candidates: int) -> str:
    return (
        f"The image shows a {object_name} on a table. The numbered markers 1 to {n_candidates} are the centres of "
        "candidate grasps for a robot's parallel-jaw gripper.\n"
        f"Task: {task_description(task)}.\n"
        "Rank the candidates you would try for this task, best first (at most "
        f"{n_candidates}). Answer with one JSON object and nothing else: "
        '{"ranking": [<marker number>, ...]}'
    )


# Reasons kept for dropped ids; the rest are counted (an answer can list thousands).
MAX_DROPPED_LISTED = 20


def _shortlist_id(entry: object) -> float | None:
    """``entry`` as a number: a JSON number, or a short string that spells one; else None."""
    if isinstance(entry, bool) or not isinstance(entry, (int, str, float)):
        return None
    if isinstance(entry, str) and len(entry) > MAX_NUMBER_CHARS:
        return None
    try:
        return float(entry)
    except ValueError:
        return None


def parse_shortlist(text: object, n_candidates: int) -> tuple[list[int], list[str]]:
    """Zero-based candidate positions from the model's answer (any value; read as untrusted as the
    zone rater reads its answers), and why rejected entries were dropped (the first
    ``MAX_DROPPED_LISTED``, then their count)."""
    data, issues = extract_json_object(text)
    if data is None:
        # A bare list is taken as the ranking only when it is the whole answer.
        if not (isinstance(text, str) and text.strip().strip("`").startswith("[")):
            return [], issues
        listed, _ = extract_json_value(text, "[")
        if not isinstance(listed, list):
            return [], issues
        data = {"ranking": listed}
    ranking = data.get("ranking")
    if not isinstance(ranking, list):
        return [], issues + ["answer has no 'ranking' list"]
    chosen: list[int] = []
    dropped: list[str] = []
    unlisted = 0
    for entry in ranking:
        number = _shortlist_id(entry)
        if number is None:
            reason = "is not a number"
        elif not number.is_integer():
            reason = "is not a whole number"
        elif not 1 <= number <= n_candidates:
            reason = f"is outside 1..{n_candidates}"
        elif int(number) - 1 in chosen:
            reason = "repeats"
        else:
            chosen.append(int(number) - 1)
            continue
        if len(dropped) < MAX_DROPPED_LISTED:
            dropped.append(f"id {excerpt(entry)} {reason}")
        else:
            unlisted += 1
    return chosen, dropped + ([f"{unlisted} more ids dropped"] if unlisted else [])


def vlm_direct_rank(
    cloud: PerceivedCloud, candidates: GraspCandidates, client: VLMClient, config: Config, task: str, object_name: str
) -> VLMDirectResult:
    """The model's ranking of the first K of ``candidates`` (ranked by Geometry-Only), as indices into them."""
    task_description(task)
    geometric = list(range(min(config.rating.vd_num_candidates, len(candidates))))
    if not geometric:
        return VLMDirectResult([], 0, True, client.backend, client.model, 0.0, "", ["no candidates to rank"])
    image = draw_candidate_markers(cloud.crop_rgb, project_to_crop(candidates.position[: len(geometric)], cloud), config.rating)
    start = time.perf_counter()
    try:
        text = client.generate(image, build_vd_prompt(object_name, task, len(geometric)))
    except VLMRequestError as exc:
        latency = time.perf_counter() - start
        log.warning("VLM-Direct got no answer from %s: %s; geometric order", client.model, exc)
        return VLMDirectResult(geometric, 0, True, client.backend, client.model, latency, "", [f"no answer: {exc}"], image)
    latency = time.perf_counter() - start
    chosen, dropped = parse_shortlist(text, len(geometric))
    for reason in dropped:
        log.info("VLM-Direct answer from %s: %s", client.model, reason)
    if not chosen:
        log.warning("VLM-Direct answer from %s held no valid id; geometric order", client.model)
    order = [geometric[i] for i in chosen] + [g for i, g in enumerate(geometric) if i not in chosen]
    return VLMDirectResult(order, len(chosen), not chosen, client.backend, client.model, latency, text, dropped, image)
