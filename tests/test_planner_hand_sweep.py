"""The real hand on the way down: the Panda's collision hulls, derived from its URDF, swept from the
pre-grasp to the grasp must clear the object and obstacles, which the SPEC's 12 % proxy alone does not see."""
import math

import numpy as np
import pybullet
import torch

from planner_clouds import box_surface, cylinder_surface, make_cloud
from sagp_batched.config import Config
from sagp_batched.planning import gripper_geometry, hand_geometry, plan
from sagp_batched.robot.description import load_robot
from sagp_batched.robot.hand import DOP_DIRECTIONS
from sagp_batched_kernels.grasp_frames import grasp_rotations
from sagp_batched_kernels.gripper_occupancy import gripper_occupancy
from sagp_batched_kernels.hand_clearance import hand_clearance

ROBOT = load_robot()

CONFIG = Config()
PLANNER = CONFIG.planner
DESCENT_M = CONFIG.motion.pregrasp_offset_m
DOWN = torch.tensor([0.0, 0.0, -1.0])
PYBULLET_AABB_MARGIN_M = 0.004


def _top_down(centre, closing=(0.0, 1.0, 0.0)):
    rotation = grasp_rotations(torch.tensor([[closing]]), DOWN.view(1, 1, 3))
    return torch.tensor([centre], dtype=torch.float32), rotation


def swept_hand(points, centre, rotation, descent_m=DESCENT_M):
    low, high = hand_geometry(ROBOT).swept((0.0, 0.0, -descent_m))
    points = torch.as_tensor(points, dtype=torch.float32)
    return hand_clearance(points[None], points[None], torch.tensor([0]), centre, rotation[:, 0], DOP_DIRECTIONS, low, high,
                          PLANNER.hand_clearance_margin_m, 10**8)


def _cup():
    """A mug-like cup: outer radius 4.6 cm, 8 mm wall, 8 cm tall, with its rim."""
    outer, _ = cylinder_surface(0.046, 0.08, (0.0, 0.0, 0.0))
    inner, _ = cylinder_surface(0.038, 0.08, (0.0, 0.0, 0.0))
    inner = inner[inner[:, 2] > 0.005]
    cup = np.concatenate((outer[outer[:, 2] < 0.079], inner[np.hypot(inner[:, 0], inner[:, 1]) > 0.037]))
    rim = np.array([(r * math.cos(t), r * math.sin(t), 0.08) for r in np.arange(0.038, 0.0461, 0.003) for t in np.linspace(0, 2 * math.pi, 120)])
    return np.concatenate((cup, rim))


def test_fingers_that_would_strike_the_mug_rim_on_the_way_down_are_caught():
    """An inner-wall pair across the cup (7 cm, under the jaws' 8 cm): the open fingers, whose inner
    faces are 4 cm from the centre, come down on the 8 mm wall."""
    cup = _cup()
    centre, rotation = _top_down((0.0, 0.0, 0.05))
    occupancy = gripper_occupancy(torch.as_tensor(cup, dtype=torch.float32)[None], torch.tensor([0]), centre, rotation,
                                  torch.tensor([0.07]), gripper_geometry(ROBOT, PLANNER), 10**7)
    # The SPEC's 12 % proxy alone accepts this grasp...
    assert occupancy.total.item() <= PLANNER.occupancy_max_fraction * len(cup)
    # ...the swept hand does not, and its clearance says it goes through the wall.
    swept = swept_hand(cup, centre, rotation)
    assert swept.blocked.item()
    assert swept.clearance_m.item() < 0.0


def test_a_box_grasped_across_has_a_clear_descent():
    box, _ = box_surface((0.05, 0.06, 0.1), (0.0, 0.0, 0.05))
    centre, rotation = _top_down((0.0, 0.0, 0.08), closing=(1.0, 0.0, 0.0))
    swept = swept_hand(box, centre, rotation)
    assert not swept.blocked.item()
    # The fingers' inner faces are 4 cm from the centre, the box faces 2.5 cm: 1.5 cm of air.
    assert 0.01 < swept.clearance_m.item() < 0.02


def test_an_overhang_on_the_way_down_counts_only_with_the_descent():
    """A plate 20 cm above a top-down grasp is beyond the hand and wrist (16 cm deep) at the grasp
    pose, but they pass through it on the 10 cm descent from the pre-grasp."""
    box, _ = box_surface((0.04, 0.04, 0.04), (0.0, 0.0, 0.0))
    plate, _ = box_surface((0.08, 0.08, 0.004), (0.0, 0.0, 0.20))
    points = np.concatenate((box, plate))
    centre, rotation = _top_down((0.0, 0.0, 0.0), closing=(1.0, 0.0, 0.0))
    assert swept_hand(points, centre, rotation, descent_m=0.0).blocked.item() is False
    assert swept_hand(points, centre, rotation).blocked.item() is True


def test_planner_keeps_no_grasp_whose_descent_hits_an_overhang():
    """A 4 cm block under a shelf: every top-down approach is blocked, side approaches stay."""
    table = CONFIG.scene.table_top_z_m
    block, block_normals = box_surface((0.04, 0.04, 0.04), (0.55, 0.0, table + 0.02))
    shelf, _ = box_surface((0.12, 0.12, 0.004), (0.55, 0.0, table + 0.16))
    under_shelf = plan(make_cloud(block, block_normals, obstacles=shelf), CONFIG, seed=0)
    assert len(under_shelf.candidates) > 0 and under_shelf.counts.rejected_hand > 0
    assert (under_shelf.candidates.approach @ DOWN < math.cos(math.radians(30.0))).all()
    free = plan(make_cloud(block, block_normals), CONFIG, seed=0).candidates
    assert (free.approach @ DOWN > 0.99).any()


def test_the_hand_geometry_is_the_urdf_collision_shapes_as_pybullet_places_them():
    """The hulls come from panda.urdf by code: placed at the grasp target's pose in PyBullet, each
    link's hull has the bounding box PyBullet computes for that link's collision shape. PyBullet
    boxes a hull by turning its local box and pads it by a 4 mm contact margin, so the hand is
    posed axis-aligned (pointing down) and the margin is taken off; link 7 sits turned 45 deg
    about the approach, so its hull must lie inside PyBullet's box and match it along z."""
    geometry = hand_geometry(ROBOT)
    assert geometry.links == ROBOT.hand_collision_links
    client = pybullet.connect(pybullet.DIRECT)
    try:
        robot = pybullet.loadURDF(str(ROBOT.urdf_path), useFixedBase=True, physicsClientId=client)
        names = {pybullet.getJointInfo(robot, j, physicsClientId=client)[12].decode(): j
                 for j in range(pybullet.getNumJoints(robot, physicsClientId=client))}
        for joint, angle in zip(range(7), ROBOT.ik_reference_joints):
            pybullet.resetJointState(robot, joint, angle, physicsClientId=client)
        for finger in ("panda_leftfinger", "panda_rightfinger"):
            pybullet.resetJointState(robot, names[finger], ROBOT.gripper.open_width_m / 2, physicsClientId=client)
        state = pybullet.getLinkState(robot, names["panda_grasptarget"], computeForwardKinematics=True, physicsClientId=client)
        rotation = np.array(pybullet.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        for name, hull in zip(geometry.links, geometry.hull_vertices):
            world = hull.double().numpy() @ rotation.T + np.array(state[4])
            lower, upper = (np.array(v) for v in pybullet.getAABB(robot, names[name], physicsClientId=client))
            lower, upper = lower + PYBULLET_AABB_MARGIN_M, upper - PYBULLET_AABB_MARGIN_M
            if name == "panda_link7":
                assert (world.min(axis=0) >= lower - 1e-4).all() and (world.max(axis=0) <= upper + 1e-4).all()
                assert np.allclose([world[:, 2].min(), world[:, 2].max()], [lower[2], upper[2]], atol=1e-4)
            else:
                assert np.allclose(world.min(axis=0), lower, atol=1e-4), name
                assert np.allclose(world.max(axis=0), upper, atol=1e-4), name
    finally:
        pybullet.disconnect(client)


def test_k_dop_clearance_is_a_lower_bound_of_the_distance_to_each_hull():
    geometry = hand_geometry(ROBOT)
    low, high = geometry.swept((0.0, 0.0, 0.0))
    generator = torch.Generator().manual_seed(3)
    points = (torch.rand(4000, 3, generator=generator) - 0.5) * torch.tensor([0.3, 0.4, 0.5])
    swept = hand_clearance(points.view(4000, 1, 3), points.view(4000, 1, 3), torch.arange(4000), torch.zeros(4000, 3), torch.eye(3).expand(4000, 3, 3),
                           DOP_DIRECTIONS, low, high, 0.0, 10**8)
    vertices = torch.cat(geometry.hull_vertices)
    # A hull vertex is inside its own k-DOP, so a point at distance d from it has clearance <= d.
    nearest_vertex = torch.cdist(points, vertices).min(dim=1).values
    assert (swept.clearance_m <= nearest_vertex + 1e-6).all()
    assert swept.blocked.sum() > 0


def test_a_grasp_whose_pregrasp_is_out_of_reach_is_rejected_though_the_grasp_pose_is_reachable():
    """Reached from beyond the object (approach tilted 30 deg toward the robot) at 65 cm, the hand
    can close on the grasp, but the pre-grasp 10 cm back along the approach lies outside the arm's reach."""
    from sagp_batched.robot.ik import panda_ik
    from sagp_batched.planning import check_motions

    tilt = math.radians(30.0)
    approach = torch.tensor([[-math.sin(tilt), 0.0, -math.cos(tilt)]])
    rotation = grasp_rotations(torch.tensor([[[0.0, 1.0, 0.0]]]), approach[:, None, :])
    centre = torch.tensor([[0.6, 0.0, 0.7]])
    ik = panda_ik(CONFIG)
    assert ik.solve(centre, rotation[:, 0]).success.item()
    motion = check_motions(centre, approach, rotation[:, 0], ik, CONFIG)
    assert not motion.feasible.item()
    assert motion.rejected_by.tolist() == [[0, 1]]  # passed the grasp-pose IK, failed the motion
    # The same grasp approached straight down has a reachable motion.
    down = grasp_rotations(torch.tensor([[[0.0, 1.0, 0.0]]]), DOWN.view(1, 1, 3))
    motion_down = check_motions(centre, DOWN.view(1, 3), down[:, 0], ik, CONFIG)
    assert motion_down.feasible.item()
    # Its joint path reaches every waypoint through pytorch-kinematics' forward kinematics.
    from sagp_batched.robot.motion import motion_waypoints

    reached = ik.forward(motion_down.joint_path[0])[:, :3, 3]
    waypoints = motion_waypoints(centre, DOWN.view(1, 3), CONFIG.motion)[0]
    assert (reached - waypoints).norm(dim=1).max() < ROBOT.ik_position_tolerance_m
