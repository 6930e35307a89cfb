"""The PyBullet engine with the Robotiq linkage grippers: the opening it is commanded, the grip force each
pad presses with, and the designed grasps held and dropped in both protocols."""
from __future__ import annotations

import numpy as np
import pybullet
import pytest
import torch

from sagp_batched import description_files
from sagp_batched.config import Config
from sagp_batched.datasets.labelling import label_object_grasps
from sagp_batched.datasets.protocols import WorldStart
from sagp_batched.datasets.pybullet_hand import PyBulletHand
from sagp_batched.grasps import GraspPoses
from sagp_batched.robot.gripper_description import load_gripper
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.objects import load_object_set

LINKAGE_GRIPPERS = ("robotiq_2f85", "robotiq_2f140")
DOWN_CLOSING_ALONG_Y = (1.0, 0.0, 0.0, 0.0)  # the grasp frame turned half about x: approach down, closing along world y
HAND_AT = np.array([0.0, 0.0, 1.0])
SQUEEZED_BOX_HEIGHT_M = 0.02
# Both pads on the box and nothing else: the 2F-85's inner finger hull stands 1.3 mm behind its pad's face
# on the pad's palm half, so the box sits on the half toward the fingertips.
SQUEEZED_BOX_TOWARD_FINGERTIPS_M = 0.008
# The held grasp: across the box's width, this far below its top, or higher where the closed pads would
# otherwise come nearer the table than TABLE_CLEARANCE_M (the 2F-140's pads are longer than the box is tall).
ACROSS_DEPTH_M, TABLE_CLEARANCE_M, FINGERS_CLEAR_M = 0.02, 0.003, 0.004


def _config(gripper: str, **execution) -> Config:
    config = Config().override("planner", gripper=gripper)
    return config.override("execution", **execution) if execution else config


def _box(tmp_path, extents_m):
    import trimesh

    trimesh.creation.box(extents_m).export(tmp_path / "box.obj")
    return load_object_set(tmp_path, MeshImportSettings(cache_dir=tmp_path / "cache")).get("box")


def _pads_world(engine: PyBulletHand) -> list[np.ndarray]:
    """Each pad's collision hull vertices where PyBullet has the pad now."""
    hulls = description_files.link_hulls(engine.gripper.urdf_path, engine.gripper.pad_links)
    pads = []
    for name, link in zip(engine.gripper.pad_links, engine.pad_links):
        position, quat = pybullet.getLinkState(engine.hand, link, computeForwardKinematics=True, physicsClientId=engine.client)[4:6]
        pads.append(hulls[name] @ np.array(pybullet.getMatrixFromQuaternion(quat)).reshape(3, 3).T + position)
    return pads


def _pad_face_gap_m(engine: PyBulletHand) -> float:
    low, high = sorted((pad[:, 1] for pad in _pads_world(engine)), key=np.mean)
    return float(high.min() - low.max())


def _pads_beyond_target_z_m(gripper, width_m: float) -> np.ndarray:
    """(pads, V) how far along the approach each pad's hull vertices lie beyond the grasp target, the fingers at ``width_m``."""
    poses = description_files.link_poses(gripper.urdf_path, {gripper.finger_joints[0]: gripper.finger_joint_value(width_m)})
    hulls = description_files.link_hulls(gripper.urdf_path, gripper.pad_links)
    return np.stack([hulls[link] @ poses[link][2, :3] + poses[link][2, 3] for link in gripper.pad_links]) - gripper.grasp_depth_m


def _start(spec, object_at, hand_at) -> WorldStart:
    return WorldStart(spec, (tuple(object_at), (0.0, 0.0, 0.0, 1.0)), "link", np.asarray(hand_at, dtype=float),
                      np.array(DOWN_CLOSING_ALONG_Y), table=False, gravity=False)


@pytest.mark.parametrize("gripper", LINKAGE_GRIPPERS)
def test_a_commanded_opening_is_the_gap_between_the_pads(gripper, designed_box):
    with PyBulletHand(_config(gripper)) as engine:
        open_width = engine.gripper.open_width_m
        for width in (0.1 * open_width, 0.5 * open_width, 0.9 * open_width, open_width):
            engine.build(_start(designed_box, HAND_AT + [5.0, 0.0, 0.0], HAND_AT))
            engine.command_fingers(width)
            engine.step(engine.config.labelling.hand_close_steps)
            assert _pad_face_gap_m(engine) == pytest.approx(width, abs=1.5e-3), f"{gripper} commanded {width:.4f} m"


@pytest.mark.parametrize("gripper, widths_m", [("robotiq_2f85", (0.03, 0.06)), ("robotiq_2f140", (0.04, 0.1))])
def test_each_pad_presses_a_box_with_the_grip_force(gripper, widths_m, tmp_path):
    """The box floats free without gravity, as in the floating protocol: its balance makes the two pads
    press alike and leaves no friction along the approach. A box fixed in the world against a hand held
    fixed would not: one driven joint and two contacts are statically indeterminate, and PyBullet splits
    the squeeze as it settles (51 N and 125 N under a 70 N grip on a 4 cm box with the 2F-85)."""
    for width in widths_m:
        folder = tmp_path / f"box_{width}"
        folder.mkdir()
        box = _box(folder, (width + 0.03, width, SQUEEZED_BOX_HEIGHT_M))
        for force in (load_gripper(gripper).grip_force_range_n[0], 70.0, load_gripper(gripper).grip_force_range_n[1]):
            with PyBulletHand(_config(gripper, gripper_force_n=force)) as engine:
                pads_at = float(_pads_beyond_target_z_m(engine.gripper, width).mean()) + SQUEEZED_BOX_TOWARD_FINGERTIPS_M
                engine.build(_start(box, (0.0, 0.0, HAND_AT[2] - pads_at), HAND_AT))
                engine.command_fingers(0.0)
                engine.step(engine.config.labelling.hand_close_steps)
                pressed = [sum(contact[9] for contact in pybullet.getContactPoints(
                    bodyA=engine.hand, bodyB=engine.target, linkIndexA=pad, physicsClientId=engine.client)) for pad in engine.pad_links]
            label = f"{gripper} on {width} m at {force} N: pads {pressed[0]:.1f} N, {pressed[1]:.1f} N"
            assert pressed == pytest.approx([force, force], rel=0.15), label
            assert abs(pressed[0] - pressed[1]) <= 0.1 * max(pressed), label


def _designed_grasps(box, gripper, table: bool) -> GraspPoses:
    """Top-down across the box's width, held; and the same beside the box's end, both fingers clear of it."""
    length, width, height = box.extents_m
    depth = min(ACROSS_DEPTH_M, height - float(_pads_beyond_target_z_m(gripper, width).max()) - TABLE_CLEARANCE_M) if table else ACROSS_DEPTH_M
    beside = length / 2 + gripper.gripper_boxes.finger_width_m / 2 + FINGERS_CLEAR_M
    rotation = np.column_stack([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])  # approach down, closing along y
    positions = [[0.0, 0.0, height - depth], [beside, 0.0, height - depth]]
    return GraspPoses(torch.tensor(positions, dtype=torch.float64), torch.tensor(np.stack([rotation] * 2)), "object")


@pytest.mark.parametrize("protocol", ["floating", "tabletop"])
@pytest.mark.parametrize("gripper", LINKAGE_GRIPPERS)
def test_a_grasp_across_the_box_is_held_and_one_beside_its_end_dropped(gripper, protocol, designed_box):
    config = _config(gripper).override("labelling", perturbed_simulations=1)
    poses = _designed_grasps(designed_box, load_gripper(gripper), table=protocol == "tabletop")
    labels = label_object_grasps(designed_box, poses, None, protocol, config, engine="pybullet")
    assert [(label.held, label.simulated) for label in labels] == [(True, True), (False, True)], [label.failure_reason for label in labels]


def test_a_cylinder_pinched_below_its_sliding_limit_stays_put_through_the_lift_and_past_it_slides_as_an_ideal_grip():
    """The 2F-85's world steps in 8 substeps; PyBullet's own substepping met the hand's carrying constraint's target once
    a protocol step, and the hand jerked there within the first substeps: this cylinder, pinched across its axis at 0.8
    of its sliding threshold, crept 21 mm down the pads in the lift and fell. The engine steps each substep itself, the
    target on a straight line through them."""
    import sagp_batched.benchmarks.analytic_grasps as analytic

    config = Config().override("planner", gripper="robotiq_2f85")
    chosen = ("cylinder across its axis mass x0.8", "cylinder across its axis mass x1.2")
    cases = [case for case in analytic.analytic_cases(analytic.analytic_config(config)) if case.name in chosen]
    rows = analytic.analytic_grasps(config, engines=("pybullet",), protocols=("floating",), note=lambda line: None, cases=cases)["cases"]
    below, past = ({row["case"]: row for row in rows}[name] for name in chosen)
    assert below["outcomes"]["pybullet/floating"]["as_on_paper"] and below["outcomes"]["pybullet/floating"]["slip_mm"] < 1.0, below
    assert past["outcomes"]["pybullet/floating"]["as_on_paper"], past
    assert past["outcomes"]["pybullet/floating"]["slip_mm"] == pytest.approx(past["paper_slide_mm"], abs=1.5), past
