"""What the model sees: every primary zone drawn on the object crop and labelled with its name."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from PIL import Image

from sagp_batched.config import RatingConfig, ZonesConfig
from sagp_batched.semantics.vlm_direct import VLMDirectUnavailable, project_to_crop
from sagp_batched.semantics.zone_marks import PRIMARY_ZONE_RGB, draw_zone_marks
from sagp_batched.semantics.zones import decompose
from sagp_batched.types import CameraData, PerceivedCloud

FOCAL_PX = 240.0 / math.tan(math.radians(30.0))
CROP_BOX = (260, 170, 380, 290)  # 120 x 120 pixels around the image centre


def side_camera() -> CameraData:
    """A camera 0.5 m in front of (0.5, 0, 0.7) looking along world +y: image right = world +x, image down = world -z."""
    camera_to_world = np.eye(4)
    camera_to_world[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    camera_to_world[:3, 3] = [0.5, -0.5, 0.7]
    return CameraData("side", 640, 480, np.array([[FOCAL_PX, 0, 320.0], [0, FOCAL_PX, 240.0], [0, 0, 1]]),
                      camera_to_world, np.zeros(16), np.zeros(16), 0.01, 3.0)


def mug_like_points() -> torch.Tensor:
    """A 10 cm tall, 8 cm wide cylinder standing at (0.5, 0, 0.65) with a handle sticking out on world +x."""
    rng = np.random.default_rng(0)
    angle, height = rng.uniform(0, 2 * math.pi, 1500), rng.uniform(0.65, 0.75, 1500)
    body = np.stack([0.5 + 0.04 * np.cos(angle), 0.04 * np.sin(angle), height], axis=1)
    arc = rng.uniform(-math.pi / 2, math.pi / 2, 200)
    handle = np.stack([0.54 + 0.025 * np.cos(arc), rng.uniform(-0.004, 0.004, 200), 0.70 + 0.025 * np.sin(arc)], axis=1)
    return torch.tensor(np.concatenate([body, handle]), dtype=torch.float32)


def synthetic_cloud(crop_box=CROP_BOX) -> PerceivedCloud:
    points = mug_like_points()
    n = points.shape[0]
    return PerceivedCloud(
        points_world=points, normals_world=torch.nn.functional.normalize(torch.randn(n, 3), dim=1),
        view_index=torch.zeros(n, dtype=torch.int64), crop_rgb=np.full((120, 120, 3), 90, np.uint8),
        cameras=[side_camera()], object_id="025_mug", object_position_world=np.array([0.5, 0.0, 0.65]),
        object_quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), crop_box_px=crop_box,
    )


def scaled_crop(crop_rgb: np.ndarray, scale: float) -> np.ndarray:
    image = Image.fromarray(crop_rgb)
    return np.asarray(image.resize((round(image.width * scale), round(image.height * scale)), Image.Resampling.LANCZOS))


def primary_zones(zones) -> set[str]:
    return {zones.zone_names[i] for i in zones.point_zone.unique().tolist()}


def assert_every_primary_zone_is_labelled(marks, zones, crop_rgb):
    plain = scaled_crop(crop_rgb, marks.scale).astype(int)
    assert marks.image.shape == plain.shape and marks.image.dtype == np.uint8
    assert not np.array_equal(marks.image, plain), "the zones are drawn on the crop"
    assert set(marks.label_boxes_px) == primary_zones(zones)
    height, width = plain.shape[:2]
    for name, (u0, v0, u1, v1) in marks.label_boxes_px.items():
        assert 0 <= u0 < u1 <= width and 0 <= v0 < v1 <= height, f"label '{name}' lies inside the image"
        change = np.abs(marks.image[v0:v1, u0:u1].astype(int) - plain[v0:v1, u0:u1]).mean()
        assert change > 30.0, f"a label box was drawn for '{name}'"


def test_a_side_view_shows_the_thirds_top_to_bottom_and_the_handle_on_its_side():
    config = RatingConfig()
    cloud = synthetic_cloud()
    zones = decompose(cloud.points_world, ZonesConfig())
    assert {"top", "middle", "bottom", "protrusion_1"} <= primary_zones(zones)
    marks = draw_zone_marks(cloud, zones, config)
    assert marks.image.shape == (config.vd_image_min_side_px, config.vd_image_min_side_px, 3)
    assert marks.scale == pytest.approx(config.vd_image_min_side_px / 120)
    assert_every_primary_zone_is_labelled(marks, zones, cloud.crop_rgb)

    def centre(name):
        u0, v0, u1, v1 = marks.label_boxes_px[name]
        return (u0 + u1) / 2, (v0 + v1) / 2

    assert centre("top")[1] < centre("middle")[1] < centre("bottom")[1], "image down is world down"
    assert centre("protrusion_1")[0] > centre("middle")[0] + 0.04 * FOCAL_PX / 0.5 * marks.scale, "the handle is right of the body"
    # The dot of the lowest point lies where the camera projects it, in the bottom third's colour.
    lowest = int(torch.argmin(cloud.points_world[:, 2]))
    u, v = np.round(project_to_crop(cloud.points_world[lowest : lowest + 1], cloud)[0] * marks.scale).astype(int)
    assert tuple(marks.image[v, u]) == PRIMARY_ZONE_RGB["bottom"]


def test_a_cloud_without_its_crop_box_cannot_be_marked():
    cloud = synthetic_cloud(crop_box=None)
    with pytest.raises(VLMDirectUnavailable, match="crop_box_px"):
        draw_zone_marks(cloud, decompose(cloud.points_world, ZonesConfig()), RatingConfig())


def test_the_captured_ycb_mug_has_every_primary_zone_drawn_and_labelled(ycb_dir):
    from sagp_batched import Scene, capture, load_config, load_object_set

    config = load_config("paper")
    with Scene(config) as scene:
        scene.reset(load_object_set(ycb_dir).get("025_mug"), trial=200)
        cloud = capture(scene, config)
    zones = decompose(cloud.points_world, config.zones)
    assert "protrusion_1" in primary_zones(zones), "the handle is a zone of its own"
    marks = draw_zone_marks(cloud, zones, config.rating)
    height, width = cloud.crop_rgb.shape[:2]
    assert min(marks.image.shape[:2]) == max(config.rating.vd_image_min_side_px, min(height, width))
    assert marks.image.shape[:2] == (round(height * marks.scale), round(width * marks.scale))
    assert_every_primary_zone_is_labelled(marks, zones, cloud.crop_rgb)
