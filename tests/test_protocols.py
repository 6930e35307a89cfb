"""Both labelling protocols on grasps whose outcome is known by construction, and robust labels."""
from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from sagp_batched.config import Config, load_config
from sagp_batched.datasets.grasp_geometry import contact_widths, object_surface
from sagp_batched.datasets.labelling import FloatingPlacement, label_object_grasps
from sagp_batched.grasps import GraspPoses
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.objects import load_object_set

DOWN = np.array([0.0, 0.0, -1.0])
# The Panda's finger hull is 21 mm wide: a grasp centre this far beyond a face closes both fingers beside it.
FINGER_HALF_WIDTH_M = 0.0105


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    folder = tmp_path_factory.mktemp("box")
    trimesh.creation.box((0.05, 0.04, 0.08)).export(folder / "box.obj")
    return load_object_set(folder, MeshImportSettings(cache_dir=tmp_path_factory.mktemp("cache"))).get("box")


def _top_down(positions, closing=(0.0, 1.0, 0.0)) -> GraspPoses:
    closing = np.asarray(closing)
    rotation = np.column_stack([np.cross(closing, DOWN), closing, DOWN])
    return GraspPoses(torch.tensor(np.asarray(positions, dtype=float)), torch.tensor(np.stack([rotation] * len(positions))), "object")


def _designed(box) -> GraspPoses:
    """Top-down grasps on the box lying in its link frame (long side along x, 4 cm tall): across its
    width 2 cm below the top (held); the fingers clear of its end (dropped); the palm 6 mm into it (collision)."""
    length, _, height = box.extents_m
    return _top_down([[0.0, 0.0, height - 0.02], [length / 2 + FINGER_HALF_WIDTH_M + 0.004, 0.0, height - 0.02], [0.0, 0.0, height - 0.045]])


@pytest.mark.parametrize("protocol", ["floating", "tabletop"])
def test_the_designed_grasps_are_held_dropped_and_collisions_in_both_protocols(box, protocol):
    labels = label_object_grasps(box, _designed(box), None, protocol, Config())
    assert [(label.held, label.failure_reason, label.simulated) for label in labels] == [
        (True, None, True), (False, "not_lifted", True), (False, "collision", False)]
    assert labels[2].failed_at == "grasp_pose" and all(label.protocol == protocol for label in labels)
    assert labels[0].held_fraction == 1.0 and labels[1].held_fraction == 0.0
    assert labels[0].shake_achieved_peak_accelerations is not None


def test_a_robust_label_is_the_majority_of_its_perturbed_simulations_and_the_same_in_any_order(box):
    config = load_config(None, {"labelling": {"perturbed_simulations": 3}})
    poses = _designed(box)
    forward = label_object_grasps(box, poses, None, "floating", config)
    backward = label_object_grasps(box, GraspPoses(poses.position.flip(0), poses.rotation.flip(0), "object"), None, "floating", config)[::-1]
    assert forward == backward
    single = label_object_grasps(box, poses, None, "floating", load_config(None, {"labelling": {"perturbed_simulations": 1}}))
    assert [label.held_fraction for label in single] == [None, None, None]
    assert [label.held for label in single] == [label.held for label in forward]


def test_floating_needs_no_table_and_the_object_can_float_turned(box):
    poses = _designed(box)
    turned = FloatingPlacement(box, (0.3, -0.2, 1.5), (0.0, 0.0, 0.38268343, 0.92387953))  # 45 deg about z: gravity stays along -z
    labels = label_object_grasps(box, poses, None, "floating", Config(), placement=turned)
    assert [label.held for label in labels] == [True, False, False]


def test_widths_are_measured_on_the_mesh_where_none_are_given(box):
    _, width, height = box.extents_m
    poses = _designed(box)
    widths = contact_widths(object_surface(box), poses, 0.08)
    assert widths[0] == pytest.approx(width, abs=1e-4) and widths[1] == 0.0


def test_the_protocol_is_checked_before_anything_is_simulated(box):
    with pytest.raises(ValueError, match="protocol must be one of tabletop, floating"):
        label_object_grasps(box, _designed(box), None, "upside_down", Config())
    with pytest.raises(ValueError, match="the tabletop protocol needs an ObjectPlacement"):
        label_object_grasps(box, _designed(box), None, "tabletop", Config(), placement=FloatingPlacement(box))
