"""Both labelling protocols on grasps whose outcome is known by construction, and robust labels."""
from __future__ import annotations

import numpy as np
import pytest

from sagp_batched.benchmarks.designed_grasps import designed_box_grasps
from sagp_batched.config import Config, load_config
from sagp_batched.datasets.grasp_geometry import contact_widths, object_surface
from sagp_batched.datasets.labelling import FloatingPlacement, label_object_grasps
from sagp_batched.grasps import GraspPoses
from sagp_batched.robot.description import load_robot


@pytest.mark.parametrize("protocol", ["floating", "tabletop"])
def test_the_designed_grasps_are_held_dropped_and_collisions_in_both_protocols(designed_box, protocol):
    labels = label_object_grasps(designed_box, designed_box_grasps(designed_box, load_robot()), None, protocol, Config())
    assert [(label.held, label.failure_reason, label.simulated) for label in labels] == [
        (True, None, True), (False, "not_lifted", True), (False, "collision", False)]
    assert labels[2].failed_at == "grasp_pose" and all(label.protocol == protocol for label in labels)
    assert labels[0].held_fraction == 1.0 and labels[1].held_fraction == 0.0
    assert labels[0].shake_achieved_peak_accelerations is not None


def test_a_robust_label_is_the_majority_of_its_perturbed_simulations_and_the_same_in_any_order(designed_box):
    config = load_config(None, {"labelling": {"perturbed_simulations": 3}})
    poses = designed_box_grasps(designed_box, load_robot())
    forward = label_object_grasps(designed_box, poses, None, "floating", config)
    backward = label_object_grasps(designed_box, GraspPoses(poses.position.flip(0), poses.rotation.flip(0), "object"), None, "floating", config)[::-1]
    assert forward == backward
    single = label_object_grasps(designed_box, poses, None, "floating", load_config(None, {"labelling": {"perturbed_simulations": 1}}))
    assert [label.held_fraction for label in single] == [None, None, None]
    assert [label.held for label in single] == [label.held for label in forward]


def test_floating_needs_no_table_and_the_object_can_float_turned(designed_box):
    poses = designed_box_grasps(designed_box, load_robot())
    turned = FloatingPlacement(designed_box, (0.3, -0.2, 1.5), (0.0, 0.0, 0.38268343, 0.92387953))  # 45 deg about z: gravity stays along -z
    labels = label_object_grasps(designed_box, poses, None, "floating", Config(), placement=turned)
    assert [label.held for label in labels] == [True, False, False]


def test_widths_are_measured_on_the_mesh_where_none_are_given(designed_box):
    _, width, height = designed_box.extents_m
    poses = designed_box_grasps(designed_box, load_robot())
    widths = contact_widths(object_surface(designed_box), poses, 0.08)
    assert widths[0] == pytest.approx(width, abs=1e-4) and widths[1] == 0.0


def test_the_protocol_is_checked_before_anything_is_simulated(designed_box):
    with pytest.raises(ValueError, match="protocol must be one of tabletop, floating"):
        label_object_grasps(designed_box, designed_box_grasps(designed_box, load_robot()), None, "upside_down", Config())
    with pytest.raises(ValueError, match="the tabletop protocol needs an ObjectPlacement"):
        label_object_grasps(designed_box, designed_box_grasps(designed_box, load_robot()), None, "tabletop", Config(), placement=FloatingPlacement(designed_box))


def test_every_protocol_the_settings_name_is_one_object_that_says_where_things_start():
    from sagp_batched.config.run import LABEL_PROTOCOLS
    from sagp_batched.datasets.protocols import PROTOCOLS, HandTarget, ObjectPlacement

    assert tuple(PROTOCOLS) == LABEL_PROTOCOLS
    spec = object()
    target = HandTarget(np.array([0.0, 0.0, 1.2]), np.array([0.0, 0.0, 1.1]), np.array([1.0, 0.0, 0.0, 0.0]))
    tabletop = PROTOCOLS["tabletop"].start(ObjectPlacement(spec, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0)), target)
    assert tabletop.table and tabletop.gravity and tabletop.object_frame == "com" and tabletop.hand_position is target.start
    floating = PROTOCOLS["floating"].start(FloatingPlacement(spec), target)
    assert not floating.table and not floating.gravity and floating.object_frame == "link" and floating.hand_position is target.grasp
