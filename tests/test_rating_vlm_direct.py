"""VLM-Direct baseline: numbered candidates drawn on the crop, the model's shortlist parsed as untrusted input."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sagp_batched.config import Config, RatingConfig
from sagp_batched.grasps import GraspCandidates
from sagp_batched.rating import VLMRequestError
from sagp_batched.semantics.vlm_direct import (
    VLMDirectUnavailable,
    draw_candidate_markers,
    get_vd_client,
    parse_shortlist,
    project_to_crop,
    vlm_direct_rank,
)
from sagp_batched.types import CameraData, PerceivedCloud

CROP_BOX = (270, 190, 370, 290)  # 100 x 100 pixels around the image centre


def overhead_camera() -> CameraData:
    """A camera 0.5 m above (0.5, 0, 0.7) looking straight down: x right = world +x, y down = world -y."""
    focal = 240.0 / math.tan(math.radians(30.0))
    camera_to_world = np.eye(4)
    camera_to_world[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    camera_to_world[:3, 3] = [0.5, 0.0, 1.2]
    return CameraData("overhead", 640, 480, np.array([[focal, 0, 320.0], [0, focal, 240.0], [0, 0, 1]]),
                      camera_to_world, np.zeros(16), np.zeros(16), 0.01, 3.0)


def cloud(crop_box=CROP_BOX) -> PerceivedCloud:
    points = torch.tensor([[0.5, 0.0, 0.7]]) + torch.randn(200, 3) * 0.01
    return PerceivedCloud(
        points_world=points, normals_world=torch.nn.functional.normalize(torch.randn(200, 3), dim=1),
        view_index=torch.zeros(200, dtype=torch.int64), crop_rgb=np.full((100, 100, 3), 90, np.uint8),
        cameras=[overhead_camera()], object_id="025_mug", object_position_world=np.array([0.5, 0.0, 0.65]),
        object_quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), crop_box_px=crop_box,
    )


def candidates(n: int) -> GraspCandidates:
    midpoints = torch.tensor([[0.5, 0.0, 0.7]]) + torch.tensor([[0.002 * i - 0.02, 0.0, 0.0] for i in range(n)])
    s_geom = torch.linspace(0.5, 0.99, n).flip(0)[torch.randperm(n, generator=torch.Generator().manual_seed(0))]
    zeros = torch.zeros(n)
    return GraspCandidates(
        contacts=torch.stack([midpoints, midpoints], dim=1), closing_axis=torch.tensor([[0.0, 1.0, 0.0]]).repeat(n, 1),
        width_m=zeros, s_geom=s_geom, approach=torch.tensor([[0.0, 0.0, -1.0]]).repeat(n, 1),
        rotation=torch.eye(3).repeat(n, 1, 1), s_reach=zeros + 1, ik_solution=torch.zeros(n, 7),
        zone=torch.full((n,), -1, dtype=torch.int64), s_afford=zeros, s_avoid=zeros, s_task=zeros, score=s_geom.clone(),
    )


class ScriptedClient:
    backend, model = "openai", "scripted"

    def __init__(self, answer: str | Exception):
        self.answer, self.seen = answer, []

    def generate(self, image, prompt):
        self.seen.append((image, prompt))
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


def test_candidates_project_through_the_crop_camera():
    pixels = project_to_crop(torch.tensor([[0.5, 0.0, 0.7], [0.55, 0.0, 0.7]]), cloud())
    focal = 240.0 / math.tan(math.radians(30.0))
    assert pixels[0] == pytest.approx([50.0, 50.0])
    assert pixels[1] == pytest.approx([50.0 + focal * 0.05 / 0.5, 50.0])


def test_marker_image_shows_every_candidate_scaled_up():
    config = RatingConfig()
    crop = np.full((100, 100, 3), 90, np.uint8)
    image = draw_candidate_markers(crop, np.array([[50.0, 50.0], [10.0, 80.0], [500.0, -40.0]]), config)
    assert image.shape == (config.vd_image_min_side_px, config.vd_image_min_side_px, 3)
    scale = config.vd_image_min_side_px / 100
    centre = image[int(50 * scale) - 3 : int(50 * scale) + 4, int(50 * scale) - 3 : int(50 * scale) + 4]
    assert (centre != 90).any(), "a marker is drawn at the projected candidate"
    border = image[: 2 * config.vd_marker_radius_px + 2, -2 * config.vd_marker_radius_px - 2 :]
    assert (border != 90).any(), "an off-crop candidate is clamped onto the border, not lost"


def test_shortlist_parsing_drops_unknown_duplicate_and_out_of_range_ids():
    chosen, dropped = parse_shortlist('```json\n{"ranking": [3, "5", 3, 0, 21, 2.5, "seven", null, 1]}\n```', 20)
    assert chosen == [2, 4, 0]
    reasons = " | ".join(dropped)
    for fragment in ("repeats", "outside 1..20", "not a whole number", "'seven' is not a number", "None is not a number"):
        assert fragment in reasons
    assert parse_shortlist("[4, 2]", 5)[0] == [3, 1]
    assert parse_shortlist("I would pick the handle.", 5)[0] == []
    assert parse_shortlist('{"best": 3}', 5) == ([], ["answer has no 'ranking' list"])


def test_model_shortlist_comes_first_then_the_rest_in_geometric_order():
    batch, config = candidates(30), Config()
    client = ScriptedClient('{"ranking": [4, 1, 99, 4]}')
    result = vlm_direct_rank(cloud(), batch.ranked_by(batch.s_geom), client, config, "t2", "mug")
    assert result.order[:2] == [3, 0], "ids count from 1 in the geometric ranking"
    assert result.order[2:] == [g for g in range(20) if g not in (3, 0)]
    assert result.n_from_model == 2 and not result.fallback and len(result.dropped) == 2
    image, prompt = client.seen[0]
    assert image.shape[0] >= config.rating.vd_image_min_side_px and "1 to 20" in prompt and "functional grasp" in prompt


@pytest.mark.parametrize("answer", ["no idea", '{"ranking": [0, 40]}', VLMRequestError("timed out")], ids=["garbage", "all-invalid", "no-answer"])
def test_no_valid_answer_falls_back_to_geometric_order_marked_as_such(answer):
    batch = candidates(8)
    result = vlm_direct_rank(cloud(), batch.ranked_by(batch.s_geom), ScriptedClient(answer), Config(), "t1", "mug")
    assert result.fallback and result.n_from_model == 0
    assert result.order == list(range(8))


def test_vlm_direct_is_unavailable_without_a_model_or_a_crop_box():
    with pytest.raises(VLMDirectUnavailable, match="prior"):
        get_vd_client(RatingConfig(backend="prior"))
    with pytest.raises(VLMDirectUnavailable, match="crop_box_px"):
        vlm_direct_rank(cloud(crop_box=None), candidates(5), ScriptedClient("[1]"), Config(), "t1", "mug")
