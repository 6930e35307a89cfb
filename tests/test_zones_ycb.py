"""Zones on captured clouds of the YCB mug and pitcher, measured against their annotated handles."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sagp_batched import Scene, capture, load_config, load_object_set
from sagp_batched.semantics.zones import decompose
from sagp_batched.world.functional_regions import region_membership

POSES = (200, 201, 202, 203)


def _captured(ycb_dir, object_id):
    config = load_config("paper")
    objects = load_object_set(ycb_dir)
    with Scene(config) as scene:
        for trial in POSES:
            scene.reset(objects.get(object_id), trial=trial)
            cloud = capture(scene, config)
            points_object = Rotation.from_quat(cloud.object_quat_xyzw).inv().apply(cloud.points_world.numpy() - cloud.object_position_world)
            yield decompose(cloud.points_world, config.zones), points_object


@pytest.fixture(scope="module")
def mug(ycb_dir):
    return list(_captured(ycb_dir, "025_mug"))


@pytest.fixture(scope="module")
def pitcher(ycb_dir):
    return list(_captured(ycb_dir, "019_pitcher_base"))


def test_the_mug_handle_is_a_protrusion_and_the_rim_is_not(mug):
    for zones, points_object in mug:
        regions = region_membership("025_mug", points_object)
        handle, rim = np.asarray(regions["in_functional_region"]), np.asarray(regions["in_avoid_region"])
        protrusion = (zones.protrusion_label >= 0).numpy()
        assert zones.protrusion_rule == "body"
        assert handle[protrusion].mean() >= 0.9, "precision against the annotated handle"
        # The handle's roots meet the wall within 1.3 body radii, so a third to a half of the
        # annotated handle's points stand out; the published rule found at most 44 of ~250.
        assert protrusion[handle].mean() >= 0.3
        assert not protrusion[rim].any()


def test_the_pitcher_handle_is_a_protrusion_zone_apart_from_any_other(pitcher):
    for zones, points_object in pitcher:
        handle = np.asarray(region_membership("019_pitcher_base", points_object)["in_functional_region"])
        labels = zones.protrusion_label.numpy()
        assert labels.max() >= 0
        # The zone holding most handle points is mostly handle, and no other zone is.
        shares = [handle[labels == k].mean() for k in range(labels.max() + 1)]
        best = int(np.argmax([(labels[handle] == k).sum() for k in range(labels.max() + 1)]))
        assert shares[best] >= 0.8
        assert all(share < 0.5 for k, share in enumerate(shares) if k != best)


@pytest.mark.parametrize("object_id", ["037_scissors", "051_large_clamp"])
def test_lying_scissors_and_clamp_are_split_along_their_length_with_the_handles_at_the_wide_end(ycb_dir, object_id):
    for zones, points_object in _captured(ycb_dir, object_id):
        regions = region_membership(object_id, points_object)
        handles, working_end = np.asarray(regions["in_functional_region"]), np.asarray(regions["in_avoid_region"])
        names = np.array(zones.zone_names)[zones.point_zone.numpy()]
        assert zones.split == "length"
        # Loops and handle bars are the wide end, blades and jaws the narrow end, in every pose.
        assert handles[names == "wide_end"].mean() >= 0.9 and (names[handles] == "wide_end").mean() >= 0.6
        assert working_end[names == "narrow_end"].mean() >= 0.9 and not (names[working_end] == "wide_end").any()


# The descriptions the rating prompt carried when the zone facts moved out of the prompt text (re-recorded
# once the embedded objects rest on their CoACD hulls, which moves the captures by a millimetre): a prompt
# that changes by one byte asks the model something else and misses every cached rating.
PUBLISHED_DESCRIPTIONS = {
    "019_pitcher_base": {
        "top": "top: 51% of points, top 8.0 cm of the object's 23.9 cm height",
        "middle": "middle: 29% of points, middle 8.0 cm of the object's 23.9 cm height",
        "bottom": "bottom: 21% of points, bottom 8.0 cm of the object's 23.9 cm height",
        "left": "left: 49% of points, the half on the robot's left",
        "right": "right: 51% of points, the half on the robot's right",
        "front": "front: 52% of points, the half on the side facing the robot",
        "back": "back: 48% of points, the half on the side away from the robot",
        "protrusion_1": "protrusion_1: 8% of points, a part that sticks out on the left side, 9.2 to 22.4 cm above the "
                        "object's lowest point (23.9 cm tall), reaching 4.3 cm beyond the body's side",
        "protrusion_2": "protrusion_2: 1% of points, a part that sticks out on the right side, 20.3 to 21.8 cm above the "
                        "object's lowest point (23.9 cm tall), reaching 2.8 cm beyond the body's side",
    },
    "037_scissors": {
        "middle": "middle: 25% of points, the middle third of the object's 20.2 cm length (it lies on the table), 5.1 cm across",
        "wide_end": "wide_end: 62% of points, the wider end, one third of the object's 20.2 cm length (it lies on the table), "
                    "8.6 cm across",
        "narrow_end": "narrow_end: 13% of points, the narrower end, one third of the object's 20.2 cm length (it lies on the "
                      "table), 1.5 cm across",
        "left": "left: 53% of points, the half on the robot's left",
        "right": "right: 47% of points, the half on the robot's right",
        "front": "front: 38% of points, the half on the side facing the robot",
        "back": "back: 62% of points, the half on the side away from the robot",
    },
}


# m: the published text rounds to 1 mm and 1 %, and is compared byte for byte because it is the rating
# cache's key; it stays the same on another processor only if no value it prints lies within that
# processor's float noise of a rounding edge. The cloud's float32 coordinates differ by a few ulp
# (~1e-7 m) between float paths; every point moved by up to 1e-6 m must still print the same text, while
# a real change in the capture or the zones moves a printed value by a millimetre or a percent.
DESCRIPTION_JITTER_M = 1e-6


@pytest.mark.recorded
@pytest.mark.parametrize("object_id", sorted(PUBLISHED_DESCRIPTIONS))
def test_the_prompt_describes_the_embedded_pitcher_and_scissors_zones_word_for_word_as_published(object_id):
    import torch

    from sagp_batched.world.objects import embedded_ycb_dir
    from sagp_batched.semantics.zone_descriptions import describe_zones

    config = load_config("paper")
    with Scene(config) as scene:
        scene.reset(load_object_set(embedded_ycb_dir()).get(object_id), trial=POSES[0])
        cloud = capture(scene, config)
    described = describe_zones(decompose(cloud.points_world, config.zones))
    # In order too: the prompt lists them as they come.
    assert list(described.items()) == list(PUBLISHED_DESCRIPTIONS[object_id].items())
    # Not on a rounding edge: the cloud moved within the float noise of another processor prints the same.
    generator = torch.Generator().manual_seed(0)
    for _ in range(2):
        jitter = DESCRIPTION_JITTER_M * (2.0 * torch.rand(cloud.points_world.shape, generator=generator) - 1.0)
        jittered = describe_zones(decompose(cloud.points_world + jitter, config.zones))
        moved = {name: text for name, text in jittered.items() if described.get(name) != text}
        assert list(jittered) == list(described) and not moved, (
            f"{object_id}: points moved by up to {DESCRIPTION_JITTER_M:.0e} m change the published text: {moved}")
