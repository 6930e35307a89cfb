"""Both labelling protocols on grasps whose outcome is known by construction, and robust labels."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sagp_batched.benchmarks.designed_grasps import designed_box_grasps
from sagp_batched.config import Config, load_config
from sagp_batched.datasets.grasp_geometry import contact_widths, object_surface
from sagp_batched.datasets.labelling import FloatingPlacement, label_object_grasps, thin_margin
from sagp_batched.grasps import GraspPoses
from sagp_batched.robot.description import load_robot


@pytest.mark.parametrize("protocol", ["floating", "tabletop"])
def test_the_designed_grasps_are_held_dropped_and_collisions_in_both_protocols(designed_box, protocol):
    labels = label_object_grasps(designed_box, designed_box_grasps(designed_box, load_robot()), None, protocol, Config())
    assert [(label.held, label.failure_reason, label.simulated) for label in labels] == [
        (True, None, True), (False, "not_lifted", True), (False, "collision", False)]
    assert labels[2].failed_at == "grasp_pose" and all(label.protocol == protocol for label in labels)
    # Dropped in the close: labelled by its own simulation; the held one by its copies too where it moved in the fingers.
    assert labels[1].held_fraction is None and labels[0].held_fraction == (1.0 if thin_margin(labels[0], Config().labelling) else None)
    assert labels[0].shake_achieved_peak_accelerations is not None


def test_a_robust_label_is_the_majority_of_its_perturbed_simulations_and_the_same_in_any_order(designed_box):
    config = load_config(None, {"labelling": {"perturbed_simulations": 3, "perturb_only_thin_margins": False}})
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


class _Counting:
    """An engine passed through, counting the protocol steps it is asked to take."""

    def __init__(self, engine):
        self.engine, self.steps = engine, 0

    def step(self, steps):
        self.steps += steps
        self.engine.step(steps)

    def follow(self, positions, quats=None):
        self.steps += len(positions)
        return self.engine.follow(positions, quats)

    def __getattr__(self, name):
        return getattr(self.engine, name)


def _designed_targets(designed_box):
    from scipy.spatial.transform import Rotation

    from sagp_batched.datasets.protocols import HandTarget

    poses = designed_box_grasps(designed_box, load_robot())
    return [HandTarget(p, p, Rotation.from_matrix(r).as_quat()) for p, r in zip(poses.position.numpy(), poses.rotation.numpy())]


@pytest.mark.parametrize("engine_name", ["pybullet", "mujoco"])
def test_following_a_trajectory_is_moving_and_stepping_through_it_to_the_last_digit(designed_box, engine_name):
    from scipy.spatial.transform import Rotation

    from sagp_batched.datasets.engines import hand_engine
    from sagp_batched.datasets.protocols import FLOATING

    config, target = Config(), _designed_targets(designed_box)[0]
    turns = Rotation.from_rotvec(np.linspace(0.0, 0.05, 30)[:, None] * [1.0, 0.0, 0.0]) * Rotation.from_quat(target.quat)
    positions, quats = target.grasp + np.linspace(0.0, 0.03, 30)[:, None] * [0.0, 0.0, 1.0], turns.as_quat()
    runs = []
    with hand_engine(engine_name, config) as engine:
        for batched in (True, False):
            engine.build(FLOATING.start(FloatingPlacement(designed_box), target))
            engine.command_fingers(0.0)
            engine.step(20)
            engine.set_gravity(True)
            if batched:
                hand = np.concatenate([engine.follow(positions[:10]), engine.follow(positions[10:], quats[10:])])
            else:
                hand = []
                for index, position in enumerate(positions.tolist()):
                    engine.move(position, None if index < 10 else quats[index].tolist())
                    engine.step(1)
                    hand.append(np.concatenate(engine.hand_pose()))
            runs.append((np.asarray(hand), engine.object_pose(), engine.fingers_touching(), engine.hand_touching()))
    (batched_hand, *batched_rest), (stepped_hand, *stepped_rest) = runs
    assert batched_hand.shape == (30, 7) and np.array_equal(batched_hand, stepped_hand)
    assert np.array_equal(np.concatenate(batched_rest[0]), np.concatenate(stepped_rest[0])) and batched_rest[1:] == stepped_rest[1:] == [True, True]


@pytest.mark.parametrize("engine_name", ["pybullet", "mujoco"])
def test_a_simulation_stops_once_the_object_has_fallen_away_and_only_then(designed_box, engine_name):
    from sagp_batched.datasets.engines import hand_engine
    from sagp_batched.datasets.protocols import FLOATING

    held, dropped, _ = _designed_targets(designed_box)
    placement, labels, steps = FloatingPlacement(designed_box), {}, {}
    for distance in (0.0, 0.05):
        config = load_config(None, {"labelling": {"early_stop_distance_m": distance}})
        with hand_engine(engine_name, config) as engine:
            for name, target in (("held", held), ("dropped", dropped)):
                counting = _Counting(engine)
                labels[name, distance], steps[name, distance] = FLOATING.simulate(counting, placement, target, config), counting.steps
    full = steps["held", 0.0]
    # The held grasp runs to the end, labelled to the last digit as without the stop.
    assert labels["held", 0.05] == labels["held", 0.0] and labels["held", 0.0].held and steps["held", 0.05] == full
    # The box the hand closed beside falls from the lift's start: the same label, decided before the lift ends
    # (without the stop, it is judged after the hold).
    labelling = Config().labelling
    assert (labels["dropped", 0.05].held, labels["dropped", 0.05].failure_reason, labels["dropped", 0.05].failed_at) == (False, "not_lifted", "close")
    # Where the falling object is when judged is all that differs.
    assert dataclasses.replace(labels["dropped", 0.05], object_in_hand_at_verdict=None) == dataclasses.replace(labels["dropped", 0.0], object_in_hand_at_verdict=None)
    assert steps["dropped", 0.0] == labelling.hand_close_steps + labelling.hand_lift_steps + labelling.hand_hold_steps
    assert steps["dropped", 0.05] < labelling.hand_close_steps + labelling.hand_lift_steps


def test_perturbed_copies_are_simulated_only_where_the_first_simulation_s_margin_is_thin(designed_box):
    from sagp_batched.datasets.protocols import GraspLabel

    labelling = Config().labelling
    firm = GraspLabel("hand", True, None, None, object_motion_during_shaking_linear=0.002, object_motion_during_shaking_angular=np.radians(1))
    assert not thin_margin(firm, labelling)
    assert thin_margin(dataclasses.replace(firm, object_motion_during_shaking_linear=0.02), labelling)
    assert thin_margin(dataclasses.replace(firm, object_motion_during_shaking_angular=np.radians(10)), labelling)
    assert thin_margin(GraspLabel("hand", False, "slipped", "shake"), labelling) and thin_margin(GraspLabel("hand", False, "slipped", "lift"), labelling)
    assert not thin_margin(GraspLabel("hand", False, "not_lifted", "close"), labelling)
    assert thin_margin(firm, dataclasses.replace(labelling, perturb_only_thin_margins=False))
    # End to end: the firm designed grasp and the box closed beside are labelled by their own simulation, where
    # a margin no grasp keeps sends every held grasp to its copies.
    poses = designed_box_grasps(designed_box, load_robot())
    margins = {"thin_margin_slip_m": 0.05, "thin_margin_rotation_deg": 90.0}
    once = label_object_grasps(designed_box, poses, None, "floating", load_config(None, {"labelling": margins}))
    copies = label_object_grasps(designed_box, poses, None, "floating", load_config(None, {"labelling": {**margins, "thin_margin_slip_m": 0.0}}))
    assert [label.held_fraction for label in once] == [None, None, None] and [label.held for label in once] == [True, False, False]
    assert copies[0].held_fraction == 1.0 and copies[1].held_fraction is None
