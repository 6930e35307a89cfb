"""Grippers as data: each described once, its geometry read from its own URDF, the planner planning for the
one named, the files naming it, and bad names refused in one line."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from sagp_batched.benchmarks.designed_grasps import wide_ball_candidates
from sagp_batched.config import Config, ConfigError, load_config
from sagp_batched.config.world import GRIPPERS
from sagp_batched.description_files import link_hulls, link_poses
from sagp_batched.formats.frames import acronym_gripper_transforms_object, grasp_poses_from_acronym
from sagp_batched.grasps import GraspPoses
from sagp_batched.planning import jaw_width_limit, widest_pair_m
from sagp_batched.robot import gripper_by_file_name, load_gripper, load_robot, robot_of
from sagp_batched.robot.gripper_description import linkage_table, pad_gap_m
from sagp_batched.robot.hand import load_hand_geometry

from ycb_paths import REPO

ROBOTIQ = ("robotiq_2f85", "robotiq_2f140")


def test_the_package_describes_the_panda_hand_and_both_robotiq_grippers():
    assert set(GRIPPERS) == {"franka_panda", *ROBOTIQ}
    assert load_robot().gripper.name == "franka_panda" and load_robot().gripper_mounted
    for name in ROBOTIQ:
        robot = load_robot("panda", name)
        assert robot.gripper.name == name and not robot.gripper_mounted
        assert robot.hand_collision_links == robot.gripper.collision_links, "no arm link beside a gripper the arm does not carry"


@pytest.mark.parametrize("name, opening_m, closed_pad_travel_m", [("robotiq_2f85", 0.086, 0.014), ("robotiq_2f140", 0.1285, 0.0237)])
def test_a_linkage_s_opening_and_pad_travel_come_from_its_urdf_kinematics(name, opening_m, closed_pad_travel_m):
    gripper = load_gripper(name)
    values, gaps = linkage_table(gripper)
    assert gaps[0] == pytest.approx(opening_m, abs=5e-4) and gripper.open_width_m == pytest.approx(gaps[0], abs=5e-4)
    assert np.all(np.diff(gaps) < 0), "the gap narrows as the driven joint turns"
    for width in (0.01, 0.03, 0.06, 0.08):
        if width < gripper.open_width_m:
            assert pad_gap_m(gripper, gripper.finger_joint_value(width)) == pytest.approx(width, abs=2e-4)

    hulls = link_hulls(gripper.urdf_path, gripper.pad_links)

    def pad_centre_z(joint_value: float) -> float:
        poses = link_poses(gripper.urdf_path, {joint: joint_value for joint in gripper.finger_joints})
        return float(np.mean([(hulls[link] @ poses[link][:3, :3].T + poses[link][:3, 3])[:, 2].mean() for link in gripper.pad_links]))

    # The pads move on along the approach as they close: the four-bar's arc, not a slide.
    assert pad_centre_z(values[-1]) - pad_centre_z(values[0]) == pytest.approx(closed_pad_travel_m, abs=1e-3)
    # The grasp target is the pads' centre at half the opening.
    assert pad_centre_z(gripper.finger_joint_value(gripper.open_width_m / 2)) == pytest.approx(gripper.grasp_depth_m, abs=5e-4)


@pytest.mark.parametrize("name", GRIPPERS)
def test_the_open_hand_s_pads_straddle_the_grasp_target_at_the_opening(name):
    robot = load_robot("panda", name)
    hand = load_hand_geometry(robot)
    pads = [hull for link, hull in zip(hand.links, hand.hull_vertices) if link in robot.gripper.pad_links]
    inner_faces = sorted(float(hull[:, 1].abs().min()) for hull in pads)
    assert all(face == pytest.approx(robot.gripper.open_width_m / 2, abs=2.5e-3) for face in inner_faces)
    for hull in pads:  # the grasp target lies within each pad's length along the approach
        assert float(hull[:, 2].min()) < 0.0 < float(hull[:, 2].max())


def test_the_planner_draws_pairs_up_to_the_named_gripper_s_opening_and_no_wider():
    for name in GRIPPERS:
        config = Config().override("planner", gripper=name)
        robot = robot_of(config)
        assert widest_pair_m(robot, config.planner) == robot.gripper.open_width_m
        assert jaw_width_limit(robot, config.planner) < robot.gripper.open_width_m
    # A set width stays the user's.
    assert widest_pair_m(load_robot(), Config().override("planner", max_width_m=0.05).planner) == 0.05


@pytest.mark.parametrize("name", GRIPPERS)
def test_a_ball_too_wide_for_the_gripper_is_never_a_candidate(name):
    assert wide_ball_candidates(load_config("dataset").override("planner", gripper=name)) == 0


def test_files_name_their_gripper_and_its_grasp_depth_places_the_gripper_frame():
    rng = np.random.default_rng(0)
    rotation = torch.as_tensor(np.linalg.qr(rng.normal(size=(5, 3, 3)))[0], dtype=torch.float64)
    rotation = rotation * torch.sign(torch.linalg.det(rotation))[:, None, None]
    poses = GraspPoses(torch.as_tensor(rng.normal(size=(5, 3)) * 0.05), rotation, "object")
    for name in GRIPPERS:
        gripper = load_gripper(name)
        transforms = acronym_gripper_transforms_object(poses, gripper)
        # The gripper base lies the grasp depth behind the grasp target, along the approach.
        assert np.allclose(transforms[:, :3, 3] + gripper.grasp_depth_m * transforms[:, :3, 2], poses.position.numpy())
        back = grasp_poses_from_acronym(transforms, gripper)
        assert torch.allclose(back.position, poses.position) and torch.allclose(back.rotation, poses.rotation)
        assert gripper_by_file_name(gripper.file_name) == gripper
    assert gripper_by_file_name("panda").name == "franka_panda", "ACRONYM's own files name the Franka hand 'panda'"
    with pytest.raises(ConfigError, match="unknown gripper 'robotiq_3f' in the grasp file; known: franka_panda, panda, robotiq_2f_140, robotiq_2f_85"):
        gripper_by_file_name("robotiq_3f")


def test_a_gripper_the_arm_does_not_carry_has_no_arm_and_a_grip_force_outside_its_range_is_refused():
    from sagp_batched.execution.pick import execute_grasp
    from sagp_batched.grasps import Grasp
    from sagp_batched.robot.kinematics import arm_chain
    from sagp_batched.world.scene import Scene

    config = Config().override("planner", gripper="robotiq_2f85")
    with Scene(config) as scene:  # a scene settles objects and renders captures for any gripper; the arm keeps its own
        assert scene.robot.gripper.name == "franka_panda"
        with pytest.raises(ConfigError, match="executing a grasp with the arm needs the gripper on the arm: robot 'panda' carries no 'robotiq_2f85'"):
            execute_grasp(scene, config, Grasp.from_pose((0.5, 0.0, 0.7), (1.0, 0.0, 0.0, 0.0), 0.03, (0.0, 0.0, -1.0)))
    with pytest.raises(ConfigError, match="the arm's IK needs the gripper on the arm"):
        arm_chain(robot_of(config))
    with pytest.raises(ConfigError, match="execution.gripper_force_n 150 N is outside the 10-125 N of gripper 'robotiq_2f140'"):
        robot_of(Config().override("planner", gripper="robotiq_2f140").override("execution", gripper_force_n=150.0))
    with pytest.raises(ConfigError, match="planner.gripper"):
        Config().override("planner", gripper="robotiq_3f")


def test_a_grasp_file_s_gripper_chooses_the_relabel_s_and_an_unknown_one_is_refused_in_one_line(tmp_path):
    import h5py
    import trimesh

    from sagp_batched.datasets.relabelling import InputError, check_inputs

    (tmp_path / "meshes").mkdir()
    trimesh.creation.box((0.04, 0.05, 0.08)).export(tmp_path / "meshes" / "box.obj")

    def grasp_file(gripper_type: bytes | None):
        path = tmp_path / f"box_{gripper_type}.h5"
        with h5py.File(path, "w") as f:
            f["grasps/transforms"] = np.tile(np.eye(4), (3, 1, 1))
            f["grasps/qualities/flex/object_in_gripper"] = np.array([1, 0, 1])
            f["object/file"], f["object/scale"] = np.bytes_(b"box.obj"), 1.0
            if gripper_type is not None:
                f["gripper/type"] = np.bytes_(gripper_type)
        return path

    config = Config().override("run", out=str(tmp_path / "out"))
    for written, chosen in ((b"robotiq_2f_140", "robotiq_2f140"), (b"panda", "franka_panda"), (None, "franka_panda")):
        inputs = check_inputs(grasp_file(written), tmp_path / "meshes", config)
        assert inputs.gripper == chosen and inputs.configured(config).planner.gripper == chosen
    with pytest.raises(InputError, match=r"box_b'robotiq_3f'.h5: unknown gripper 'robotiq_3f' in the grasp file; known: franka_panda, panda"):
        check_inputs(grasp_file(b"robotiq_3f"), tmp_path / "meshes", config)


def test_the_documentation_s_gripper_pictures_are_drawn(tmp_path):
    from runners.gripper_frames import main

    assert main(["--out", str(tmp_path), "--grippers", "robotiq_2f85"]) == 0
    assert (tmp_path / "robotiq_2f85.png").stat().st_size > 20_000
    assert main(["--out", str(tmp_path), "--grippers", "robotiq_3f"]) == 2


def test_a_linkage_s_fingertips_closing_on_a_thin_part_near_the_table_are_caught_where_the_open_hand_clears_it():
    from sagp_batched.planning.screens import closing_finger_points, table_check_points
    from sagp_batched_kernels.table_penetration import table_penetration

    robot = load_robot("panda", "robotiq_2f85")
    table_z, device = 0.625, torch.device("cpu")
    down = torch.tensor([[[[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]]])  # columns: x, y (closing), z (approach) down
    centre = torch.tensor([[0.5, 0.0, table_z + 0.015]])
    (fingers, cover), _ = table_check_points(robot, device)
    assert not table_penetration(centre, down, fingers, 0.0, table_z, cover).item(), "the open fingertips reach 7 mm past the grasp target"
    widths, swept = closing_finger_points(robot, device)

    def closing_dips(width_m: float) -> bool:
        vertices, sweep_cover = swept[int(torch.searchsorted(widths, torch.tensor(width_m), right=True)) - 1]
        return bool(table_penetration(centre, down, vertices, 0.0, table_z, sweep_cover).item())

    # Closing on a 1 cm part, the fingertips reach 13 mm further along the approach than when open.
    assert closing_dips(0.01) and not closing_dips(0.08)


def test_a_collision_origin_turned_about_several_axes_places_the_hull_as_urdf_fixed_axis_rpy_does(tmp_path):
    from scipy.spatial.transform import Rotation

    from sagp_batched.description_files import link_hulls

    urdf = tmp_path / "tilted.urdf"
    urdf.write_text('<robot name="tilted"><link name="block"><collision><origin xyz="0.1 0.2 0.3" rpy="0.3 -0.5 1.1"/>'
                    '<geometry><box size="0.02 0.04 0.06"/></geometry></collision></link></robot>')
    corners = np.array(np.meshgrid([-0.01, 0.01], [-0.02, 0.02], [-0.03, 0.03], indexing="ij")).reshape(3, -1).T
    # URDF's rpy: roll about the fixed x, then pitch about the fixed y, then yaw about the fixed z.
    expected = corners @ Rotation.from_euler("xyz", [0.3, -0.5, 1.1]).as_matrix().T + [0.1, 0.2, 0.3]
    hull = link_hulls(urdf, ("block",))["block"]
    assert np.allclose(np.sort(hull, axis=0), np.sort(expected, axis=0), atol=1e-12)


def test_the_gripper_agreement_runner_labels_the_same_grasps_with_each_gripper_and_refuses_one_gripper(tmp_path):
    import json
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "runners.bench_dataset", "--grippers", "franka_panda,robotiq_2f85", "--objects", "005_tomato_soup_can",
         "--grasps", "3", "--pairs", "2000", "--perturbed-simulations", "1", "--out", str(out)],
        cwd=repo, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads((out / "gripper_agreement.json").read_text())
    assert report["planned_for"] == "franka_panda" and set(report["grippers"]) == {"franka_panda", "robotiq_2f85"}
    assert all(row["grasps"] == 3 for row in report["grippers"].values()) and report["pairs"]["franka_panda/robotiq_2f85"]["n"] <= 3
    assert json.loads((out / "provenance.json").read_text())["grippers"] == ["franka_panda", "robotiq_2f85"]
    refused = subprocess.run([sys.executable, "-m", "runners.bench_dataset", "--grippers", "robotiq_2f85", "--out", str(tmp_path / "x")],
                             cwd=repo, capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "--grippers takes two or more" in refused.stderr and not (tmp_path / "x").exists()


def test_the_open_hand_test_of_no_grasps_is_empty(designed_box):
    from sagp_batched.datasets.grasp_geometry import floating_hand_links, object_surface, open_hand_collisions

    robot = load_robot("panda", "robotiq_2f85")
    none = GraspPoses(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, 3, dtype=torch.float64), "object")
    object_hit, table_hit = open_hand_collisions(object_surface(designed_box), none, robot, floating_hand_links(robot), 0.001)
    assert object_hit.shape == table_hit.shape == (0,)


SHARED_GRIPPERS_DIR = REPO.parent / "shared" / "grippers"


def _collision_hulls(model) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """(volume, lower corner, upper corner) in the world of each colliding mesh geom at the model's rest pose."""
    import mujoco
    from scipy.spatial import ConvexHull

    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    hulls = []
    for geom in range(model.ngeom):
        if model.geom_type[geom] != mujoco.mjtGeom.mjGEOM_MESH or not (model.geom_contype[geom] or model.geom_conaffinity[geom]):
            continue
        mesh = model.geom_dataid[geom]
        vertices = model.mesh_vert[model.mesh_vertadr[mesh]: model.mesh_vertadr[mesh] + model.mesh_vertnum[mesh]]
        world = vertices @ data.geom_xmat[geom].reshape(3, 3).T + data.geom_xpos[geom]
        hulls.append((ConvexHull(world).volume, world.min(axis=0), world.max(axis=0)))
    return hulls


@pytest.mark.skipif(not SHARED_GRIPPERS_DIR.is_dir(), reason=f"the grippers' source models are not at {SHARED_GRIPPERS_DIR}")
@pytest.mark.parametrize("name", [name for name in GRIPPERS if load_gripper(name).mjcf_path is not None])
def test_a_packaged_mjcf_weighs_and_collides_as_its_source(name):
    """The package's MJCF, its largest meshes made compact by ``runners.import_grippers``, has its source's
    masses and inertias and collides the same hulls (to the nanometres of STL's single precision)."""
    import mujoco

    packaged = load_gripper(name).mjcf_path
    source = mujoco.MjModel.from_xml_path(str(SHARED_GRIPPERS_DIR / name / "mjcf" / packaged.name))
    model = mujoco.MjModel.from_xml_path(str(packaged))
    for field in ("body_mass", "body_inertia", "body_ipos", "body_iquat"):
        assert np.array_equal(getattr(model, field), getattr(source, field)), field
    hulls, source_hulls = _collision_hulls(model), _collision_hulls(source)
    assert len(hulls) == len(source_hulls) > 0
    for (volume, low, high), (source_volume, source_low, source_high) in zip(hulls, source_hulls):
        assert volume == pytest.approx(source_volume, rel=1e-6)
        assert np.allclose(low, source_low, atol=1e-8) and np.allclose(high, source_high, atol=1e-8)
    assert sum(path.stat().st_size for path in packaged.parent.rglob("*") if path.is_file()) < 1_500_000
