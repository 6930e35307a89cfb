"""Why engines disagree: each simulation records the object's pose in the hand at the close's end and at the
verdict, a drop is classed knocked out, torsion, slip or other by that record, and a two-engine dataset's
report counts its disagreements by cause and engine with a picture of one of each."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from sagp_batched.benchmarks.designed_grasps import _top_down
from sagp_batched.config import load_config
from sagp_batched.datasets.dataset_directory import write_object
from sagp_batched.datasets.dataset_report import write_dataset_report
from sagp_batched.datasets.disagreement_causes import CAUSES, failure_cause, label_cause, motion_in_hand
from sagp_batched.datasets.labelling import label_object_grasps
from sagp_batched.datasets.object_plan import ObjectLabels
from sagp_batched.formats.object_grasps import LabelledGrasps, UntestedGrasps
from sagp_batched.robot import load_gripper
from sagp_batched.world.objects import load_object_set

KNOCK = 0.01
REST = (0.0, 0.0, 0.04, 0.0, 0.0, 0.0, 1.0)  # the centre of mass 4 cm along the approach from the grasp centre


def _turned(rotvec, shift=(0.0, 0.0, 0.0)) -> tuple[float, ...]:
    """REST turned by ``rotvec`` about the grasp centre (the hand's origin), then moved by ``shift``."""
    turn = Rotation.from_rotvec(rotvec)
    return (*(turn.apply(REST[:3]) + shift), *turn.as_quat())


def test_a_turn_splits_into_its_twist_about_the_normal_and_the_rest_and_the_grasp_centre_point_follows_the_object():
    motion = motion_in_hand(REST, _turned([0.0, 0.5, 0.0]))
    assert motion.turn_about_normal_rad == pytest.approx(0.5) and motion.turn_other_rad == pytest.approx(0.0, abs=1e-9)
    assert motion.slip_in_pad_plane_m == pytest.approx(0.0, abs=1e-9), "a turn about the grasp centre moves its point nowhere"
    # A turn about an axis between the normal and the pad plane: split by its axis, also near half a turn.
    motion = motion_in_hand(REST, _turned([0.3, 0.4, 0.0]))
    assert (motion.turn_about_normal_rad, motion.turn_other_rad) == (pytest.approx(0.4), pytest.approx(0.3))
    motion = motion_in_hand(REST, _turned([2.4, 1.6, 0.0]))
    assert (motion.turn_about_normal_rad, motion.turn_other_rad) == (pytest.approx(1.6), pytest.approx(2.4))
    motion = motion_in_hand(REST, _turned([0.0, 0.0, 0.0], (0.02, 0.01, -0.3)))
    assert (motion.slip_in_pad_plane_m, motion.slip_along_normal_m) == (pytest.approx(math.hypot(0.02, 0.3)), pytest.approx(0.01))
    assert motion_in_hand(None, REST) is None and motion_in_hand(REST, (math.nan,) * 7) is None


def test_the_rule_classes_each_cause_from_its_record():
    fell = _turned([0.0, 0.0, 0.0], (0.0, 0.0, -0.3))
    assert failure_cause("close", 0.0, REST, fell, KNOCK) == "knocked out", "failed in the close"
    assert failure_cause("lift", 0.02, REST, fell, KNOCK) == "knocked out", "the close moved it past the tolerance"
    assert failure_cause("lift", 0.005, REST, fell, KNOCK) == "slip", "within the tolerance the close did not knock it"
    assert failure_cause("shake", 0.0, REST, _turned([0.0, 1.0, 0.0], (0.0, 0.0, -0.3)), KNOCK) == "torsion"
    assert failure_cause("shake", 0.0, REST, _turned([1.0, 0.0, 0.0], (0.0, 0.0, -0.3)), KNOCK) == "other", "rolled about a pad-plane axis"
    assert failure_cause("shake", 0.0, REST, _turned([0.1, 0.0, 0.0], (0.0, 0.3, 0.0)), KNOCK) == "other", "pushed out along the normal"
    assert failure_cause("shake", 0.0, REST, _turned([0.0, 0.2, 0.0], (0.0, 0.0, -0.3)), KNOCK) == "slip", "a turn under the minimum"
    assert failure_cause("lift", None, None, None, KNOCK) == "other", "no record"


def _shape(folder, extents, mass_kg):
    trimesh.creation.box(extents).export(folder / "shape.obj")
    (folder / "objects.json").write_text(json.dumps({"shape": {"mass_kg": mass_kg}}))
    return load_object_set(folder).get("shape")


@pytest.mark.parametrize("engine", ["pybullet", "mujoco"])
def test_a_heavy_bar_gripped_far_from_its_centre_turns_out_and_a_heavy_box_slides_out(tmp_path, engine):
    config = load_config(None, {"labelling": {"perturbed_simulations": 1}})
    (tmp_path / "bar").mkdir()
    (tmp_path / "box").mkdir()
    # The bar's weight 13 cm from the contacts: a moment of 15 N m, far past any pad's torsional friction. It swings
    # down about the contacts, and at the bottom of the swing pulls on them with three times its weight, past their
    # sliding limit (at 8 kg a crowned pad held it hanging, turned 110 deg).
    bar = _shape(tmp_path / "bar", (0.30, 0.03, 0.03), 12.0)
    # The box 40 kg at its centre: a weight past the pads' friction, on the line through the contacts.
    box = _shape(tmp_path / "box", (0.05, 0.04, 0.08), 40.0)
    turned = label_object_grasps(bar, _top_down([[0.13, 0.0, bar.extents_m[2] / 2]]), None, "floating", config, engine=engine)[0]
    slid = label_object_grasps(box, _top_down([[0.0, 0.0, box.extents_m[2] - 0.02]]), None, "floating", config, engine=engine)[0]
    assert not turned.held and not slid.held
    for label in (turned, slid):
        assert len(label.object_in_hand_after_closing) == 7 and len(label.object_in_hand_at_verdict) == 7
    assert label_cause(turned, config.execution.knock_tolerance_m) == "torsion"
    assert label_cause(slid, config.execution.knock_tolerance_m) == "slip"


def _disagreeing_grasps(n_rows: int) -> LabelledGrasps:
    """Five simulated grasps: four that MuJoCo or PyBullet alone dropped, one of each cause, and one both held."""
    rng = np.random.default_rng(0)
    transforms = np.tile(np.eye(4), (n_rows, 1, 1))
    transforms[:, :3, 3] = rng.normal(scale=0.02, size=(n_rows, 3))
    fell = _turned([0.0, 0.0, 0.0], (0.0, 0.0, -0.3))
    # knocked out (MuJoCo), torsion (MuJoCo), slip (PyBullet), other (PyBullet), held by both
    verdicts = [fell, _turned([0.0, 1.2, 0.0], (0.0, 0.0, -0.3)), fell, _turned([1.2, 0.0, 0.0], (0.0, 0.0, -0.3)), REST]
    pybullet = np.array([True, True, False, False, True])
    mujoco = np.array([False, False, True, True, True])
    failures = {"pybullet": ["", "", "slipped@lift", "slipped@shake", ""], "mujoco": ["not_lifted@close", "slipped@shake", "", "", ""]}
    zeros = np.zeros(n_rows)
    return LabelledGrasps(
        transforms=transforms, width_m=np.full(n_rows, 0.04), contacts=rng.normal(scale=0.02, size=(n_rows, 2, 3)),
        resting_pose=np.zeros(n_rows, dtype=np.int64), verdict=["feasible"] * n_rows, verdict_reason=[""] * n_rows,
        held=pybullet & mujoco, held_fraction=(pybullet & mujoco).astype(float), decided_by=["simulation"] * n_rows,
        failure_reason=[p or m for p, m in zip(failures["pybullet"], failures["mujoco"])],
        motion_closing_linear_m=np.array([0.03, 0.0, 0.0, 0.0, 0.0]), motion_closing_angular_rad=zeros, motion_shaking_linear_m=zeros,
        motion_shaking_angular_rad=zeros, s_geom=zeros, s_reach=zeros, zone=[""] * n_rows, zone_rating={},
        engine_held={"pybullet": pybullet, "mujoco": mujoco}, engine_held_fraction={"pybullet": pybullet * 1.0, "mujoco": mujoco * 1.0},
        engine_failure=failures, object_in_hand_after_closing=np.tile(REST, (n_rows, 1)), object_in_hand_at_verdict=np.array(verdicts))


def test_a_two_engine_datasets_report_counts_its_disagreements_by_cause_and_draws_one_of_each(tmp_path):
    config = load_config("dataset", overrides={"dataset": {"engines": ["pybullet", "mujoco"], "protocol": "floating"}})
    objects = load_object_set(None)
    spec = objects.get("025_mug")
    labels = ObjectLabels("025_mug", _disagreeing_grasps(5), UntestedGrasps(np.zeros((0, 4, 4)), []), "prior", {}, np.zeros(3))
    write_object(tmp_path, spec, labels, "hand", "floating", load_gripper("franka_panda"))
    write_dataset_report(tmp_path, config, objects, ["025_mug"])
    report = (tmp_path / "report.md").read_text()
    for row in ("| knocked out | 0 | 1 |", "| torsion | 0 | 1 |", "| slip | 1 | 0 |", "| other | 1 | 0 |"):
        assert row in report
    for cause in CAUSES:
        picture = f"pictures/cause_{cause.replace(' ', '_')}.png"
        assert f"[picture]({picture})" in report and (tmp_path / picture).stat().st_size > 10_000
