"""What the model sees: the object crop with its zones drawn on it (set-of-mark prompting).

A description such as "protrusion_2: a part that sticks out on the left" does not tell a model which
pixels it means; drawing every zone's points as coloured dots with the zone's name beside them does.
The primary zones are drawn (thirds, protrusions: what ``ZoneDecomposition.point_zone``
holds); the side halves overlap them and are left to the text.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from PIL import ImageDraw, ImageFont

from ..config import RatingConfig
from ..types import PerceivedCloud
from .vlm_direct import project_to_crop, scaled_crop
from .zones import GEOMETRIC_ZONES, ZoneDecomposition

# Zone colours (matplotlib's tab palette): ``runners.zones`` plots the cloud with these too.
PRIMARY_ZONE_RGB = {"top": (31, 119, 180), "middle": (44, 160, 44), "bottom": (255, 127, 14),
                    "wide_end": (31, 119, 180), "narrow_end": (255, 127, 14)}
PROTRUSION_RGB = ((214, 39, 40), (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34))
LABEL_PADDING_PX = 2


@dataclass
class ZoneMarks:
    image: np.ndarray  # (H, W, 3) uint8: the crop scaled up by ``scale``, zones drawn on it
    scale: float  # image pixels per crop pixel
    # Zone name -> (u0, v0, u1, v1) pixel box of its label in ``image`` (u right, v down, u1/v1 exclusive).
    label_boxes_px: dict[str, tuple[int, int, int, int]]


def zone_rgb(zone_names: tuple[str, ...], index: int) -> tuple[int, int, int]:
    """The colour of zone ``zone_names[index]``: its third's, or its protrusion's in turn."""
    name = zone_names[index]
    if name in PRIMARY_ZONE_RGB:
        return PRIMARY_ZONE_RGB[name]
    return PROTRUSION_RGB[(index - len(GEOMETRIC_ZONES)) % len(PROTRUSION_RGB)]


def _place_label(
    anchor_px: np.ndarray, size_px: tuple[int, int], image_size_px: tuple[int, int], placed: list[tuple[int, int, int, int]]
) -> tuple[int, int, int, int]:
    """A box of ``size_px`` (w, h) centred on ``anchor_px`` (u, v), moved inside the image and, where it
    can be, up or down off the boxes already ``placed`` (zones whose centroids nearly coincide)."""
    width, height = size_px
    image_width, image_height = image_size_px

    def box_at(step: int) -> tuple[int, int, int, int]:
        u0 = int(np.clip(round(anchor_px[0] - width / 2), 0, max(image_width - width, 0)))
        v0 = int(np.clip(round(anchor_px[1] - height / 2 + step * (height + 1)), 0, max(image_height - height, 0)))
        return u0, v0, u0 + width, v0 + height

    def overlaps(box: tuple[int, int, int, int]) -> bool:
        return any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in placed)

    return next((box for step in (0, 1, -1, 2, -2, 3, -3) if not overlaps(box := box_at(step))), box_at(0))


def draw_zone_marks(cloud: PerceivedCloud, zones: ZoneDecomposition, config: RatingConfig) -> ZoneMarks:
    """The image a zone rater is shown: ``cloud.crop_rgb`` scaled up to ``config.vd_image_min_side_px`` on
    its short side, every cloud point drawn as a dot in its primary zone's colour, and each primary zone's
    name in a boxed label at the projected centroid of its points.

    ``zones`` must be the decomposition of ``cloud.points_world`` (one primary zone per point). Points
    are projected through ``cloud.cameras[cloud.crop_camera_index]`` (``vlm_direct.project_to_crop``),
    which raises ``VLMDirectUnavailable`` for a cloud without ``crop_box_px``. Dots are drawn for the
    points that camera captured itself (``view_index``), so the back of the object does not show through;
    a zone it did not capture at all is drawn from every view. Dots are small so the object stays visible.
    The label boxes are returned in ``ZoneMarks.label_boxes_px``.
    """
    if zones.n_points != cloud.n_points:
        raise ValueError(f"zones hold {zones.n_points} points but the cloud {cloud.n_points}: not its decomposition")
    image, scale = scaled_crop(cloud.crop_rgb, config)
    if zones.n_points == 0:
        return ZoneMarks(np.array(image), scale, {})
    pixels = project_to_crop(zones.points_world, cloud) * scale  # (N, 2) u, v in ``image``
    point_zone = zones.point_zone.numpy()
    draw = ImageDraw.Draw(image)
    radius = config.zone_mark_dot_radius_px
    present = [int(index) for index in np.unique(point_zone)]  # ascending: protrusions drawn last, on top
    colours = {index: zone_rgb(zones.zone_names, index) for index in present}
    # Dots where the crop's own camera saw the zone (its surface as the image shows it); a zone that
    # camera did not see (a handle behind the body) is drawn from every view, seen through the object.
    seen_here = (cloud.view_index == cloud.crop_camera_index).numpy()
    for index in present:
        in_zone = point_zone == index
        drawn = in_zone & seen_here if (in_zone & seen_here).any() else in_zone
        for u, v in pixels[drawn]:
            draw.ellipse((u - radius, v - radius, u + radius, v + radius), fill=colours[index])
    font = ImageFont.load_default(size=config.zone_label_font_px)
    label_boxes: dict[str, tuple[int, int, int, int]] = {}
    for index in present:
        name = zones.zone_names[index]
        left, top, right, bottom = draw.textbbox((0, 0), name, font=font, anchor="lt")
        size = (right - left + 2 * LABEL_PADDING_PX, bottom - top + 2 * LABEL_PADDING_PX)
        box = _place_label(pixels[point_zone == index].mean(axis=0), size, image.size, list(label_boxes.values()))
        draw.rectangle((box[0], box[1], box[2] - 1, box[3] - 1), fill=(255, 255, 255), outline=colours[index], width=1)
        draw.text((box[0] + LABEL_PADDING_PX - left, box[1] + LABEL_PADDING_PX - top), name, fill=(0, 0, 0), font=font)
        label_boxes[name] = box
    return ZoneMarks(np.array(image), scale, label_boxes)


def rating_image(cloud: PerceivedCloud, zones: ZoneDecomposition, config: RatingConfig) -> np.ndarray:
    """(H, W, 3) uint8 image a zone rater is given: the marked crop if ``config.zone_marks``, else the plain crop."""
    return draw_zone_marks(cloud, zones, config).image if config.zone_marks else cloud.crop_rgb
