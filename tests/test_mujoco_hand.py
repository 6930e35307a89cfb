"""The MuJoCo engine of hand-mode labels: the designed grasps labelled as designed in both protocols, the same
simulation giving the same label whatever was labelled before it, the hand built from the project's robot
description, the shake it reaches, its settings, and the engine named where labels are made."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from sagp_batched.benchmarks.designed_grasps import designed_box_grasps
from sagp_batched.config import Config, ConfigError, load_config
from sagp_batched.datasets.engines import ENGINES, hand_engine
from sagp_batched.datasets.labelling import FloatingPlacement, label_object_grasps, thin_margin
from sagp_batched.datasets.protocols import FLOATING, HandTarget, WorldStart
from sagp_batched.grasps import GraspPoses
from sagp_batched.robot.description import load_robot, robot_of

# The MuJoCo engine is an optional extra: without MuJoCo these tests are skipped.
MuJoCoHand = pytest.importorskip("sagp_batched.datasets.mujoco_hand", exc_type=ImportError).MuJoCoHand

ONE_SIMULATION = {"labelling": {"perturbed_simulations": 1}}


@pytest.mark.parametrize("protocol", ["floating", "tabletop"])
def test_mujoco_labels_the_designed_grasps_held_dropped_and_a_collision_in_both_protocols(designed_box, protocol):
    labels = label_object_grasps(designed_box, designed_box_grasps(designed_box, load_robot()), None, protocol, Config(), engine="mujoco")
    assert [(label.held, label.failure_reason, label.simulated) for label in labels] == [
        (True, None, True), (False, "not_lifted", True), (False, "collision", False)]
    assert labels[1].held_fraction is None and labels[0].held_fraction == (1.0 if thin_margin(labels[0], Config().labelling) else None)
    # The box stays in the fingers through the shake: it slides a centimetre along the closing axis, as in
    # PyBullet (each finger holds its own force, so the pair moves together), and hardly turns.
    assert labels[0].object_motion_during_shaking_linear < 0.02 and labels[0].object_motion_during_shaking_angular < np.radians(5)


def test_the_hand_reaches_the_shake_s_peak_accelerations(designed_box):
    (label, *_) = label_object_grasps(designed_box, designed_box_grasps(designed_box, load_robot()), None, "floating",
                                      load_config(None, ONE_SIMULATION), engine="mujoco")
    shake = Config().labelling.shake
    wanted = (*shake.linear_peak_acceleration_m_s2, *shake.angular_peak_acceleration_rad_s2)
    assert np.allclose(label.shake_achieved_peak_accelerations, wanted, rtol=0.05)


def _shifted(poses: GraspPoses, shift_m: float) -> GraspPoses:
    """The grasps moved along the box's long side: other simulations than the designed ones, of outcomes of their own."""
    return GraspPoses(poses.position + poses.position.new_tensor([shift_m, 0.0, 0.0]), poses.rotation, "object")


def test_a_label_is_the_same_alone_in_a_batch_and_in_any_order(designed_box):
    config = load_config(None, {"labelling": {"perturbed_simulations": 3}})
    designed = designed_box_grasps(designed_box, load_robot())
    order = [0, 3, 1, 4]  # the held and the dropped grasp, each beside its shifted copy
    poses = GraspPoses(torch.cat([designed.position, _shifted(designed, 0.012).position])[order],
                       torch.cat([designed.rotation, designed.rotation])[order], "object")
    forward = label_object_grasps(designed_box, poses, None, "floating", config, engine="mujoco")
    backward = label_object_grasps(designed_box, GraspPoses(poses.position.flip(0), poses.rotation.flip(0), "object"), None,
                                   "floating", config, engine="mujoco")[::-1]
    alone = [label_object_grasps(designed_box, GraspPoses(poses.position[i : i + 1], poses.rotation[i : i + 1], "object"), None,
                                 "floating", config, engine="mujoco")[0] for i in (3, 1)]
    assert forward == backward and [forward[3], forward[1]] == alone


def test_the_same_simulation_twice_in_one_engine_gives_the_same_label_to_the_last_digit(designed_box):
    config = load_config(None, ONE_SIMULATION)
    grasp = designed_box_grasps(designed_box, load_robot())
    position, quat = grasp.position[0].numpy(), Rotation.from_matrix(grasp.rotation[0].numpy()).as_quat()
    placement, moved = FloatingPlacement(designed_box), position + [0.01, 0, 0]
    with MuJoCoHand(config) as engine:
        first = FLOATING.simulate(engine, placement, HandTarget(position, position, quat), config)
        FLOATING.simulate(engine, placement, HandTarget(moved, moved, quat), config)
        again = FLOATING.simulate(engine, placement, HandTarget(position, position, quat), config)
    assert first == again and first.held


# Run with PyBullet made unimportable: any import of it on the way fails the script.
WITHOUT_PYBULLET = """
import pickle, sys
sys.modules["pybullet"] = None
from sagp_batched.config import Config
from sagp_batched.datasets.mujoco_hand import MuJoCoHand
from sagp_batched.datasets.protocols import FLOATING, FloatingPlacement, HandTarget
spec, position, quat = pickle.loads(sys.stdin.buffer.read())
config = Config()
with MuJoCoHand(config) as engine:
    label = FLOATING.simulate(engine, FloatingPlacement(spec), HandTarget(position, position, quat), config)
print(label.held)
"""


def test_the_mujoco_engine_imports_and_labels_without_pybullet(designed_box):
    import pickle
    import subprocess
    import sys

    grasp = designed_box_grasps(designed_box, load_robot())
    position, quat = grasp.position[0].numpy(), Rotation.from_matrix(grasp.rotation[0].numpy()).as_quat()
    done = subprocess.run([sys.executable, "-c", WITHOUT_PYBULLET], input=pickle.dumps((designed_box, position, quat)),
                          capture_output=True, timeout=600)
    assert done.returncode == 0, done.stderr.decode()[-3000:]
    assert done.stdout.decode().split()[-1] == "True", "the designed grasp across the box is held, as with PyBullet there"


def test_the_hand_is_the_robot_description_s_open_hand_at_the_commanded_grasp(designed_box):
    config = Config()
    robot = robot_of(config)
    turn = Rotation.from_euler("xyz", [0.3, -0.2, 1.0])
    with MuJoCoHand(config) as engine:
        engine.build(WorldStart(designed_box, ((0.0, 0.0, 0.0), (0, 0, 0, 1)), "link", np.array([0.1, 0.2, 0.5]), turn.as_quat(),
                                table=False, gravity=False))
        world, data = engine.world, engine.data
        assert len(world.finger_qpos) == len(robot.gripper.finger_joints) == 2
        assert data.qpos[list(world.finger_qpos)].sum() == pytest.approx(robot.gripper.open_width_m)
        assert world.model.jnt_range[world.model.jnt_qposadr.tolist().index(world.finger_qpos[0])][1] * 2 == pytest.approx(robot.gripper.open_width_m)
        position, quat = engine.hand_pose()
        assert np.allclose(position, [0.1, 0.2, 0.5]) and (Rotation.from_quat(quat) * turn.inv()).magnitude() < 1e-9
        assert engine.hand_in_contact() == (False, False)


def test_the_centre_of_mass_frame_is_where_it_was_put(designed_box):
    with MuJoCoHand(Config()) as engine:
        com = ((0.4, -0.1, 0.9), tuple(Rotation.from_euler("z", 0.7).as_quat()))
        engine.build(WorldStart(designed_box, com, "com", np.array([0.4, -0.1, 1.3]), np.array([0, 0, 0, 1.0]), table=True, gravity=True))
        position, quat = engine.object_pose()
        assert np.allclose(position, com[0]) and np.allclose(np.abs(np.dot(quat, com[1])), 1.0)


def test_the_engine_is_named_where_labels_are_made_and_an_unknown_one_is_refused(designed_box):
    assert ENGINES == ("pybullet", "mujoco")
    with hand_engine("mujoco", Config()) as engine:
        assert engine.name == "mujoco"
    with pytest.raises(ValueError, match="^engine must be one of pybullet, mujoco, got 'bullet'$"):
        label_object_grasps(designed_box, designed_box_grasps(designed_box, load_robot()), None, "floating", Config(), FloatingPlacement(designed_box), engine="bullet")


def test_mujoco_settings_load_from_a_profile_section_and_bad_ones_are_clear_errors():
    config = load_config(None, {"labelling": {"mujoco": {"substeps": 2, "cone": "pyramidal"}}})
    assert config.labelling.mujoco.substeps == 2 and config.labelling.mujoco.cone == "pyramidal"
    with pytest.raises(ConfigError, match="labelling.mujoco.solver: unknown value 'gauss'"):
        load_config(None, {"labelling": {"mujoco": {"solver": "gauss"}}})
    with pytest.raises(ConfigError, match="labelling.mujoco.substeps"):
        load_config(None, {"labelling": {"mujoco": {"substeps": 0}}})


def test_the_engine_benchmark_refuses_a_bad_variant_in_one_line_before_any_work(tmp_path, capsys):
    from runners import bench_dataset

    with pytest.raises(SystemExit) as exit_info:
        bench_dataset.main(["--engines", "--out", str(tmp_path / "out"), "--mujoco-variants", '[{"substeps": 0}]'])
    assert exit_info.value.code == 2 and "labelling.mujoco.substeps must be between 1 and 100, got 0" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_the_engine_benchmark_compares_both_engines_on_planned_grasps(tmp_path):
    import trimesh

    from sagp_batched.benchmarks.engine_agreement import agreement_markdown, engine_agreement
    from sagp_batched.world.mesh_settings import MeshImportSettings
    from sagp_batched.world.objects import load_object_set

    trimesh.creation.box((0.05, 0.05, 0.05)).export(tmp_path / "cube.obj")
    objects = load_object_set(tmp_path, MeshImportSettings(max_resting_poses=1, cache_dir=tmp_path / "cache"))
    config = load_config("dataset", {"planner": {"n_pairs": 2000}, **ONE_SIMULATION})
    report = engine_agreement(config, objects, ["cube"], 8, [{}, {"substeps": 2}], note=lambda line: None)
    assert report["pybullet"]["designed"] == {"tabletop": 4, "floating": 4}
    for row in report["variants"]:
        assert row["designed"] == {"tabletop": 4, "floating": 4} and row["agreement"]["all"]["n"] > 0
        assert row["speed"]["simulations_per_s_per_core"] > 0
    assert "| substeps=2 |" in agreement_markdown(report)
