"""Coarse zones (SPEC stage 3) on constructed clouds: the geometry the published figure shows."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from runners.zones import plot_zones
from sagp_batched.config import ZonesConfig
from sagp_batched.semantics.zone_descriptions import describe_zones
from sagp_batched.semantics.zones import (
    UNZONED,
    ZONE_INDEX,
    GEOMETRIC_ZONES,
    ZoneInputError,
    decompose,
)
from sagp_batched_kernels import zone_geometry as zone_kernels

TABLE_Z = 0.625
rng = np.random.default_rng(7)


def cylinder(radius, height, n, base=(0.5, 0.0, TABLE_Z)):
    theta = rng.uniform(0, 2 * math.pi, n)
    z = rng.uniform(0, height, n)
    return np.stack([radius * np.cos(theta), radius * np.sin(theta), z], 1) + np.asarray(base)


def mug_cloud():
    """A mug-like cylinder (r 4 cm, h 8 cm) with a C-shaped handle sticking out 4.8 cm on its +x side."""
    body = cylinder(0.04, 0.08, 4500, base=(0.0, 0.0, 0.0))
    n = 700
    arc = rng.uniform(-math.pi / 2, math.pi / 2, n)
    tube = rng.uniform(0, 2 * math.pi, n)
    ring = 0.032 + 0.006 * np.cos(tube)
    handle = np.stack([0.05 + ring * np.cos(arc), 0.006 * np.sin(tube), 0.04 + ring * np.sin(arc)], 1)
    return torch.tensor(np.concatenate([body, handle]) + [0.5, 0.0, TABLE_Z], dtype=torch.float32), body.shape[0]


def box_cloud(size, n=5000):
    faces = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            face = rng.uniform(-0.5, 0.5, (n // 6, 3)) * size
            face[:, axis] = sign * size[axis] / 2
            faces.append(face)
    return np.concatenate(faces)


def test_mug_handle_is_a_protrusion_and_rim_is_top():
    points, n_body = mug_cloud()
    zones = decompose(points)
    assert zones.degenerate is None and zones.protrusion_rule == "body"
    handle_outer = (points[:, 0] > 0.5 + 0.084).nonzero().squeeze(1)
    protrusion = zones.protrusion_label >= 0
    # The handle is past 1.3 x the body's radius from its vertical axis and forms one cluster, its own zone.
    assert protrusion[handle_outer].all()
    assert zones.zone_names[-1] == "protrusion_1" and (zones.point_zone[handle_outer] == len(zones.zone_names) - 1).all()
    assert int(protrusion.sum()) >= ZonesConfig().min_protrusion_points
    assert int(zones.protrusion_label.max()) == 0
    assert not protrusion[:n_body].any(), "no body point is a protrusion"
    rim = (points[:n_body, 2] > TABLE_Z + 0.075).nonzero().squeeze(1)
    assert (zones.point_zone[rim] == ZONE_INDEX["top"]).all()
    base = (points[:n_body, 2] < TABLE_Z + 0.005).nonzero().squeeze(1)
    assert (zones.point_zone[base] == ZONE_INDEX["bottom"]).all()
    assert torch.allclose(zones.axes_world[:, 0].abs(), torch.tensor([0.0, 0.0, 1.0]), atol=0.1)


def test_every_point_is_in_one_third_one_lateral_and_one_depth_side():
    points, _ = mug_cloud()
    zones = decompose(points)
    members = zones.memberships
    for group in (("top", "middle", "bottom"), ("left", "right"), ("front", "back")):
        assert (members[:, [ZONE_INDEX[z] for z in group]].sum(dim=1) == 1).all()
    # Sides follow the robot's view: +y is its left, -x (towards the robot) the object's front.
    left_points = points[:, 1] > 0.01
    assert members[left_points, ZONE_INDEX["left"]].all()
    front_points = points[:, 0] < 0.5 - 0.01
    assert members[front_points, ZONE_INDEX["front"]].all()


def test_candidate_zone_is_its_midpoints_nearest_point_and_protrusion_wins():
    points, _ = mug_cloud()
    zones = decompose(points)
    on_handle = torch.tensor([[0.5 + 0.088, 0.0, TABLE_Z + 0.04]])
    on_rim = torch.tensor([[0.5, 0.04, TABLE_Z + 0.079]])
    near_base = torch.tensor([[0.5 - 0.04, 0.0, TABLE_Z + 0.002]])
    zone, _ = zones.candidate_zones(torch.cat([on_handle, on_rim, near_base]))
    assert [zones.zone_names[i] for i in zone.tolist()] == ["protrusion_1", "top", "bottom"]
    members = zones.memberships[zones.nearest_points(on_handle)][0]
    assert members[zones.zone_names.index("protrusion_1")] and members[ZONE_INDEX["middle"]], "the handle point keeps its third"


def test_tilted_box_still_finds_its_long_vertical_axis():
    rotation = Rotation.from_euler("xy", [25.0, -15.0], degrees=True)
    points = rotation.apply(box_cloud(np.array([0.05, 0.07, 0.16]))) + [0.5, 0.0, 0.72]
    zones = decompose(torch.tensor(points, dtype=torch.float32))
    long_axis = torch.tensor(rotation.apply([0.0, 0.0, 1.0]), dtype=torch.float32)
    assert float(zones.axes_world[:, 0] @ long_axis) > 0.99
    assert zones.degenerate is None
    counts = zones.zone_point_counts()
    assert all(counts[z] > 0.2 * zones.n_points for z in ("top", "middle", "bottom"))


def test_sphere_has_no_protrusion():
    direction = rng.normal(size=(4000, 3))
    points = 0.05 * direction / np.linalg.norm(direction, axis=1, keepdims=True) + [0.5, 0.0, 0.7]
    zones = decompose(torch.tensor(points, dtype=torch.float32))
    assert zones.zone_names == GEOMETRIC_ZONES
    assert not any(name.startswith("protrusion") for name in describe_zones(zones))


@pytest.mark.parametrize(
    "points, outcome",
    [
        (torch.zeros(0, 3), "empty"),
        (torch.tensor([[0.5, 0.0, 0.7], [0.51, 0.0, 0.7]]), "too_few_points"),
        (torch.stack([torch.linspace(0.4, 0.6, 200), torch.zeros(200), torch.full((200,), 0.7)], 1), "collinear"),
        (torch.tensor(np.c_[rng.uniform(0.4, 0.6, (500, 2)), np.full(500, 0.7)], dtype=torch.float32), "flat"),
        (torch.full((50, 3), 0.6), "collinear"),
    ],
    ids=["empty", "two-points", "line", "plane", "one-point-repeated"],
)
def test_degenerate_clouds_get_a_typed_outcome_and_no_nan_zones(points, outcome):
    zones = decompose(points)
    assert zones.degenerate == outcome and zones.degenerate_reason
    assert torch.isfinite(zones.axes_world).all() and torch.isfinite(zones.centroid_world).all()
    assert ((zones.point_zone >= 0) & (zones.point_zone < len(zones.zone_names))).all()
    assert (zones.memberships.sum(dim=1) >= 3).all()
    queries = torch.tensor([[0.5, 0.0, 0.7], [0.45, 0.02, 0.71]])
    zone, _ = zones.candidate_zones(queries)
    if outcome == "empty":
        assert (zone == UNZONED).all()
        assert describe_zones(zones) == {}
    else:
        assert ((zone >= 0) & (zone < len(zones.zone_names))).all()
        assert all(outcome in text for text in describe_zones(zones).values())


def test_a_single_view_half_shell_still_gets_every_zone():
    theta = rng.uniform(-math.pi / 2, math.pi / 2, 3000)  # the half of a can one side camera sees
    z = rng.uniform(0, 0.1, 3000)
    points = np.stack([-0.033 * np.cos(theta) + 0.5, 0.033 * np.sin(theta), z + TABLE_Z], 1)
    zones = decompose(torch.tensor(points, dtype=torch.float32))
    assert zones.degenerate is None
    counts = zones.zone_point_counts()
    assert all(counts[z] > 0.2 * zones.n_points for z in ("top", "middle", "bottom", "left", "right"))
    # The SPEC rule as written: a half shell's centroid sits inside the shell, so its far corners
    # can pass 1.5 x the median distance; they must be corners (top or bottom third), never the middle.
    in_protrusion = zones.protrusion_label >= 0
    assert not (zones.memberships[in_protrusion, ZONE_INDEX["middle"]]).any()


def test_malformed_clouds_are_rejected_by_name():
    with pytest.raises(ZoneInputError, match="points_world"):
        decompose(torch.zeros(10, 2))
    with pytest.raises(ZoneInputError, match="non-finite"):
        decompose(torch.tensor([[0.0, 0.0, float("nan")]] * 20))
    with pytest.raises(ZoneInputError, match="orthonormal"):
        decompose(torch.rand(20, 3), ZonesConfig(left_world=(1.0, 0.0, 0.0)))


def test_kernels_batch_padded_clouds_like_single_ones():
    mug, _ = mug_cloud()
    sphere = torch.randn(300, 3) * 0.03
    padded = torch.zeros(2, mug.shape[0], 3)
    padded[0] = mug
    padded[1, :300] = sphere
    padded[1, 300:] = 5.0  # padding far away must not matter
    valid = torch.zeros(2, mug.shape[0], dtype=torch.bool)
    valid[0] = True
    valid[1, :300] = True
    config = ZonesConfig()
    up, left, front = torch.tensor([config.up_world, config.left_world, config.front_world])
    centroid, axes, _ = zone_kernels.principal_frame(padded, valid, up, left, front, config.isotropy_tolerance)
    single_centroid, single_axes, _ = zone_kernels.principal_frame(
        sphere.unsqueeze(0), torch.ones(1, 300, dtype=torch.bool), up, left, front, config.isotropy_tolerance
    )
    assert torch.allclose(centroid[1], single_centroid[0], atol=1e-6)
    assert torch.allclose(axes[1], single_axes[0], atol=1e-4)
    third, lateral, _ = zone_kernels.zone_coordinates(padded, valid, centroid, axes, config.min_split_extent_m)
    assert (third[1, 300:] == zone_kernels.MIDDLE).all() and not lateral[1, 300:].any()
    far, _, median = zone_kernels.far_points(padded, valid, centroid, config.protrusion_distance_factor)
    assert not far[1, 300:].any() and median[1] < 0.1


def test_describe_zones_says_how_far_the_handle_sticks_out():
    points, _ = mug_cloud()
    zones = decompose(points)
    text = describe_zones(zones)
    assert set(text) == {name for name, count in zones.zone_point_counts().items() if count}
    assert "wide_end" not in text and zones.split == "vertical"
    assert "sticks out" in text["protrusion_1"] and "% of points" in text["top"]
    # The handle reaches 8.8 cm from the axis of a 4 cm body: 4.8 cm beyond its side.
    beyond_cm = float(text["protrusion_1"].split("reaching ")[1].split(" cm")[0])
    assert 4.0 < beyond_cm < 5.2
    assert "robot's" not in text["protrusion_1"] and "above the object's lowest point" in text["protrusion_1"]


def test_zone_picture_draws_every_primary_zone_in_its_colour(tmp_path):
    from picture_checks import TAB_RGB, pixels_of_colour

    points, _ = mug_cloud()
    path = plot_zones(decompose(points), tmp_path / "mug_zones.png", "mug")
    # top, middle, bottom and the handle (protrusion_1) each cover a visible patch of the picture.
    for colour in ("blue", "green", "orange", "red"):
        assert pixels_of_colour(path, TAB_RGB[colour]) > 500, colour
    # A cloud without a protrusion draws no protrusion colour.
    plain = plot_zones(decompose(torch.tensor(cylinder(0.04, 0.08, 3000, base=(0.5, 0.0, TABLE_Z)), dtype=torch.float32)), tmp_path / "can.png")
    assert pixels_of_colour(plain, TAB_RGB["red"]) < 50


def test_the_published_centroid_rule_stays_selectable_and_misses_most_of_a_handle():
    points, n_body = mug_cloud()
    body = decompose(points)
    centroid = decompose(points, ZonesConfig(protrusion_rule="centroid"))
    assert centroid.protrusion_rule == "centroid"
    handle = torch.arange(n_body, points.shape[0])
    assert int((centroid.protrusion_label[handle] >= 0).sum()) < int((body.protrusion_label[handle] >= 0).sum())


def test_a_pitcher_handle_and_its_spout_are_zones_of_their_own():
    """A tall body with a large handle on one side and a smaller spout on the other: two protrusion
    zones, the larger first, which a rating can tell apart."""
    body = cylinder(0.06, 0.2, 6000, base=(0.0, 0.0, 0.0))
    arc = rng.uniform(-math.pi / 2, math.pi / 2, 900)
    tube = rng.uniform(0, 2 * math.pi, 900)
    ring = 0.05 + 0.008 * np.cos(tube)
    handle = np.stack([0.07 + ring * np.cos(arc), 0.008 * np.sin(tube), 0.11 + ring * np.sin(arc)], 1)
    spout = np.stack([-rng.uniform(0.06, 0.095, 300), rng.uniform(-0.012, 0.012, 300), rng.uniform(0.17, 0.2, 300)], 1)
    points = torch.tensor(np.concatenate([body, handle, spout]) + [0.5, 0.0, TABLE_Z], dtype=torch.float32)
    zones = decompose(points)
    assert "protrusion_2" in zones.zone_names
    handle_rows = torch.arange(6000, 6900)
    spout_rows = torch.arange(6900, 7200)
    handle_zone = torch.mode(zones.point_zone[handle_rows][zones.protrusion_label[handle_rows] >= 0]).values
    spout_zone = torch.mode(zones.point_zone[spout_rows][zones.protrusion_label[spout_rows] >= 0]).values
    assert zones.zone_names[int(handle_zone)] == "protrusion_1"
    assert zones.zone_names[int(spout_zone)].startswith("protrusion_") and spout_zone != handle_zone


def test_a_cloud_lying_flat_with_a_square_footprint_keeps_vertical_thirds_and_the_centroid_rule():
    points = box_cloud(np.array([0.1, 0.09, 0.03])) + [0.5, 0.0, TABLE_Z + 0.015]
    zones = decompose(torch.tensor(points, dtype=torch.float32))
    assert zones.protrusion_rule == "centroid" and zones.split == "vertical"


def scissors_cloud():
    """Flat scissors-like object lying on the table along a diagonal: a 9 x 8 cm loop end and
    a 10 x 1.5 cm blade, 1.5 cm thick. Returns world points and the loop-end mask."""
    loops = box_cloud(np.array([0.09, 0.08, 0.015]), 3000) + [0.045, 0.0, 0.0]
    blade = box_cloud(np.array([0.10, 0.015, 0.015]), 3000) + [-0.05, 0.0, 0.0]
    local = np.concatenate([loops, blade])
    yaw = Rotation.from_euler("z", 35, degrees=True)
    return yaw.apply(local) + [0.5, 0.05, TABLE_Z + 0.0075], np.arange(len(local)) < len(loops)


def test_an_elongated_object_lying_flat_is_split_along_its_length_and_its_ends_named_by_width():
    points, loop_end = scissors_cloud()
    zones = decompose(torch.tensor(points, dtype=torch.float32))
    assert zones.split == "length" and zones.protrusion_rule == "none" and (zones.protrusion_label < 0).all()
    names = np.array(zones.zone_names)[zones.point_zone.numpy()]
    far_loops = loop_end & (Rotation.from_euler("z", -35, degrees=True).apply(points - [0.5, 0.05, 0])[:, 0] > 0.04)
    assert (names[far_loops] == "wide_end").all()
    assert (names[~loop_end] != "wide_end").all() and (names == "narrow_end").sum() > 1000
    assert {"top", "bottom"}.isdisjoint(set(names))
    text = describe_zones(zones)
    assert "wider end" in text["wide_end"] and "narrower end" in text["narrow_end"] and "lies on the table" in text["middle"]
    # The length axis runs along the object's 35 degree diagonal, toward the wide end.
    assert float(zones.length_axis_world @ torch.tensor([math.cos(math.radians(35)), math.sin(math.radians(35)), 0.0])) > 0.99


def test_the_published_vertical_thirds_stay_selectable_for_lying_objects():
    points, _ = scissors_cloud()
    zones = decompose(torch.tensor(points, dtype=torch.float32), ZonesConfig(length_split=False))
    assert zones.split == "vertical" and zones.protrusion_rule == "centroid"
    assert "wide_end" not in np.array(zones.zone_names)[zones.point_zone.numpy()]
