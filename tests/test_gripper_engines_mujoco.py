"""The MuJoCo engine simulates the Robotiq grippers from their Menagerie MJCF: a commanded opening gives that gap
between the pads, the pads press on a box fixed in the world with the grip force wherever the fingers stand,
and the designed box is held across its width and dropped with the fingers beside it, in both protocols."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from sagp_batched import description_files
from sagp_batched.config import Config, load_config
from sagp_batched.datasets.labelling import FloatingPlacement, label_object_grasps, tabletop_placement
from sagp_batched.datasets.protocols import WorldStart
from sagp_batched.grasps import GraspPoses
from sagp_batched.robot.description import robot_of

# The MuJoCo engine is an optional extra: without MuJoCo these tests are skipped.
mujoco = pytest.importorskip("mujoco")
MuJoCoHand = pytest.importorskip("sagp_batched.datasets.mujoco_hand", exc_type=ImportError).MuJoCoHand
from sagp_batched.datasets.mujoco_world import MJCF_PREFIX  # noqa: E402  (after the skip: it imports MuJoCo)

ROBOTIQS = ("robotiq_2f85", "robotiq_2f140")
# Top-down, the fingers closing along the box's y (its 5 cm side as the designed box lies).
TOP_DOWN = np.column_stack([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
TOP_DOWN_XYZW = (1.0, 0.0, 0.0, 0.0)  # TOP_DOWN as a quaternion: a half turn about x
# The open hand's lowest point is kept this far above the table.
TABLE_CLEARANCE_M = 0.005


def _config(gripper: str):
    return load_config(None, {"labelling": {"perturbed_simulations": 1}, "planner": {"gripper": gripper}})


@pytest.fixture(scope="module", params=ROBOTIQS)
def engine(request):
    with MuJoCoHand(_config(request.param)) as engine:
        yield engine


def _build(engine, box, hand_position) -> None:
    """The box floating at the origin (gravity off), the open hand top-down with its grasp target at ``hand_position``."""
    engine.build(WorldStart(box, ((0.0, 0.0, 0.0), (0, 0, 0, 1)), "link", np.asarray(hand_position, dtype=float), np.array(TOP_DOWN_XYZW),
                            table=False, gravity=False))


def _pad_geoms(engine) -> list[list[int]]:
    """Per pad link, the ids of its MJCF pad geoms."""
    model = engine.world.model
    return [[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, MJCF_PREFIX + name) for name in names]
            for names in engine.robot.gripper.mujoco_value("pad_geoms")]


def _pad_gap_m(engine) -> float:
    """The gap between the pads' faces along the hand's closing axis (y): the boxes' corners in the hand's frame."""
    model, data = engine.world.model, engine.data
    hand = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, engine.robot.gripper.base_link)
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
    ys = []
    for geoms in _pad_geoms(engine):
        corners = np.concatenate([(signs * model.geom_size[g]) @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g] for g in geoms])
        ys.append(((corners - data.xpos[hand]) @ data.xmat[hand].reshape(3, 3))[:, 1])
    low, high = sorted(ys, key=np.mean)
    return float(high.min() - low.max())


def _pad_normal_forces_n(engine) -> np.ndarray:
    """Per pad link, the normal force of its geoms' contacts with the object."""
    model, data, force = engine.world.model, engine.data, np.zeros(6)
    forces = np.zeros(len(engine.world.finger_bodies))
    for pad, geoms in enumerate(_pad_geoms(engine)):
        for index in range(data.ncon):
            pair = data.contact.geom[index]
            if np.isin(pair, geoms).any() and (model.geom_bodyid[pair] == engine.world.object_body).any():
                mujoco.mj_contactForce(model, data, index, force)
                forces[pad] += force[0]
    return forces


def _warnings(engine) -> dict[str, int]:
    return {mujoco.mjtWarning(kind).name: int(warning.number) for kind, warning in enumerate(engine.data.warning) if warning.number}


def test_a_commanded_opening_is_the_gap_between_the_pads(engine, designed_box):
    open_width = engine.robot.gripper.open_width_m
    for width in (0.15 * open_width, 0.5 * open_width, 0.95 * open_width):
        _build(engine, designed_box, [0.0, 0.0, 1.0])  # the box far below the hand
        engine.command_fingers(width)
        engine.step(240)
        assert _pad_gap_m(engine) == pytest.approx(width, abs=0.0015), f"commanded {width:.4f} m"
    assert not _warnings(engine)


@pytest.fixture(scope="module")
def boxes_across(tmp_path_factory):
    """Boxes 4 cm tall, 2 cm longer than they are across, at 35, 60 and 85 % of each Robotiq's opening."""
    import trimesh

    from sagp_batched.world.mesh_settings import MeshImportSettings
    from sagp_batched.world.objects import load_object_set

    folder = tmp_path_factory.mktemp("boxes_across")
    widths = sorted({round(fraction * robot_of(_config(name)).gripper.open_width_m, 4) for name in ROBOTIQS for fraction in (0.35, 0.6, 0.85)})
    for width in widths:
        trimesh.creation.box((width + 0.02, width, 0.04)).export(folder / f"box_{width * 1000:.1f}mm.obj")
    objects = load_object_set(folder, MeshImportSettings(cache_dir=tmp_path_factory.mktemp("cache")))
    return {width: objects.get(f"box_{width * 1000:.1f}mm") for width in widths}


@pytest.mark.parametrize("fraction", [0.35, 0.6, 0.85])
def test_the_pads_press_a_fixed_box_with_the_grip_force_across_the_stroke(engine, boxes_across, fraction):
    """Across a box at a fraction of the opening, its centre at the grasp target, the box held where it is (its
    free joint reset every substep) while the servo's cap follows the fingers as the engine's steps set it: the
    pads' normal forces over the second second of the squeeze (steady there). A cap fixed at one opening pressed
    up to 1.3x the grip force at the widest (the linkage's transmission and its springs vary along the stroke);
    the 2F-140's left and right linkages differ slightly, its pads by under 10 %."""
    grip_force = engine.config.execution.gripper_force_n
    box = boxes_across[round(fraction * engine.robot.gripper.open_width_m, 4)]
    _build(engine, box, [0.0, 0.0, box.extents_m[2] / 2])
    model, data, world = engine.world.model, engine.data, engine.world
    dof = model.jnt_dofadr[model.body_jntadr[world.object_body]]
    held_at = data.qpos[world.object_qpos : world.object_qpos + 7].copy()
    engine.command_fingers(0.0)
    forces = []
    for step in range(480):
        world.cap_grip_force(data)
        for _ in range(engine.substeps):
            mujoco.mj_step(model, data)
            data.qpos[world.object_qpos : world.object_qpos + 7], data.qvel[dof : dof + 6] = held_at, 0.0
        if step >= 240:
            forces.append(_pad_normal_forces_n(engine))
    mean = np.mean(forces, axis=0)
    assert mean == pytest.approx([grip_force, grip_force], rel=0.08)
    assert abs(mean[0] - mean[1]) < 0.1 * mean.max()
    assert not _warnings(engine)


@pytest.mark.parametrize("fraction", [0.35, 0.85])
def test_a_pull_along_the_approach_changes_the_pads_force_as_the_linkages_kinematics_say(engine, boxes_across, fraction):
    """A linkage swings its pads on arcs: closing, they also move away from the palm, by the slope the URDF's kinematics
    give (``pad_path_slope``). By virtual work, with the servo's force capped, a pull P on the box along the approach
    (away from the palm, shared by the two pads' friction) adds slope x P / 2 to each pad's normal force, and a push
    toward the palm takes as much away. The MJCF is Menagerie's model of the linkage, not the URDF: measured 0.27-0.72
    N/N where the URDF's kinematics say 0.17-0.66 (the 2F-85 at 35 % of its opening the farthest)."""
    width = round(fraction * engine.robot.gripper.open_width_m, 4)
    pull_n, forces = 30.0, {}
    for pull in (pull_n, -pull_n):
        _build(engine, boxes_across[width], [0.0, 0.0, boxes_across[width].extents_m[2] / 2])
        engine.command_fingers(0.0)
        pressed = []
        for step in range(480):
            # The hand is top-down: the approach is the world's -z. The pull starts once the fingers have closed.
            engine.data.xfrc_applied[engine.world.object_body, 2] = -pull if step >= 120 else 0.0
            engine.step(1)
            if step >= 240:
                pressed.append(_pad_normal_forces_n(engine))
        forces[pull] = np.mean(pressed, axis=0)
        assert not _warnings(engine)
    measured_slope = (forces[pull_n] - forces[-pull_n]) / pull_n
    assert measured_slope == pytest.approx([engine.robot.gripper.pad_path_slope(width)] * 2, abs=0.13)


def _designed_grasps(gripper, box) -> GraspPoses:
    """Top-down across the box's 5 cm side: at its centre, held; with both fingers beside its end, dropped. The
    grasp target 2 cm below the top, or higher where the open fingers would reach into the table (their
    lowest point ``TABLE_CLEARANCE_M`` above it)."""
    length, _, height = box.extents_m
    open_links = description_files.link_poses(gripper.urdf_path, {})
    hulls = description_files.link_hulls(gripper.urdf_path, gripper.collision_links)
    # Top-down, the fingertips' reach along the approach is how far they come below the grasp target.
    reach = max((hull @ open_links[link][:3, :3].T + open_links[link][:3, 3])[:, 2].max() for link, hull in hulls.items())
    depth = max(height - 0.02, reach - gripper.grasp_depth_m + TABLE_CLEARANCE_M)
    beside_end = length / 2 + gripper.gripper_boxes.finger_width_m / 2 + 0.004
    positions = [[0.0, 0.0, depth], [beside_end, 0.0, depth]]
    return GraspPoses(torch.tensor(positions, dtype=torch.float64), torch.tensor(np.stack([TOP_DOWN] * 2)), "object")


@pytest.mark.parametrize("gripper", ROBOTIQS)
@pytest.mark.parametrize("protocol", ["floating", "tabletop"])
def test_the_designed_box_is_held_across_and_dropped_beside_its_end(designed_box, gripper, protocol):
    config = _config(gripper)
    # The box settles on the table in PyBullet's scene, which carries the robot with its own gripper.
    placement = tabletop_placement(designed_box, Config()) if protocol == "tabletop" else FloatingPlacement(designed_box)
    labels = label_object_grasps(designed_box, _designed_grasps(robot_of(config).gripper, designed_box), None, protocol, config,
                                 placement, engine="mujoco")
    assert [(label.held, label.failure_reason, label.simulated) for label in labels] == [(True, None, True), (False, "not_lifted", True)]
