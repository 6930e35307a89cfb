"""The open gripper's straight descent: a grasp whose fingers or palm would land on the object on the
way down is rejected, though the SPEC's closing-sweep occupancy lets it through."""
import math

import numpy as np
import torch

from planner_clouds import box_surface, cylinder_surface, make_cloud
from sagp_batched.config import Config
from sagp_batched.planner import gripper_geometry, screen_candidates
from sagp_batched_kernels.grasp_frames import grasp_rotations
from sagp_batched_kernels.gripper_volume import gripper_occupancy

CONFIG = Config()
PLANNER = CONFIG.planner
DESCENT_M = CONFIG.execution.pregrasp_offset_m
DOWN = torch.tensor([0.0, 0.0, -1.0])


def _top_down(centre, closing=(0.0, 1.0, 0.0)):
    rotation = grasp_rotations(torch.tensor([[closing]]), DOWN.view(1, 1, 3))
    return torch.tensor([centre], dtype=torch.float32), rotation


def _occupancy(points, centre, rotation, width, descent_m=DESCENT_M):
    points = torch.as_tensor(points, dtype=torch.float32)
    return gripper_occupancy(
        points[None], torch.tensor([0]), centre, rotation, torch.tensor([width]), gripper_geometry(PLANNER), 10**7, descent_m
    )


def test_fingers_landing_on_a_mug_rim_are_caught_by_the_descent_sweep():
    """Inner-wall pair of a mug-like cup (outer radius 4.6 cm, wall 8 mm): 7 cm across, under the
    jaws' 8 cm, but the open fingers (inner faces 4 cm from the centre) come down on the wall."""
    outer, _ = cylinder_surface(0.046, 0.08, (0.0, 0.0, 0.0))
    inner, _ = cylinder_surface(0.038, 0.08, (0.0, 0.0, 0.0))
    inner = inner[inner[:, 2] > 0.005]  # the inner wall, not a second bottom
    cup = np.concatenate((outer[outer[:, 2] < 0.079], inner[np.hypot(inner[:, 0], inner[:, 1]) > 0.037]))
    rim = np.array([(r * math.cos(t), r * math.sin(t), 0.08) for r in np.arange(0.038, 0.0461, 0.003) for t in np.linspace(0, 2 * math.pi, 120)])
    cup = np.concatenate((cup, rim))
    centre, rotation = _top_down((0.0, 0.0, 0.05))
    occupancy = _occupancy(cup, centre, rotation, 0.07)
    # The SPEC's 12 % proxy alone accepts this grasp...
    assert occupancy.total.item() <= PLANNER.occupancy_max_fraction * len(cup)
    # ...the descent sweep does not.
    assert occupancy.descent.item() > PLANNER.descent_max_fraction * len(cup)


def test_a_box_grasped_across_has_a_clear_descent():
    box, _ = box_surface((0.05, 0.06, 0.1), (0.0, 0.0, 0.05))
    centre, rotation = _top_down((0.0, 0.0, 0.08), closing=(1.0, 0.0, 0.0))
    occupancy = _occupancy(box, centre, rotation, 0.05)
    assert occupancy.descent.item() == 0


def test_an_overhang_on_the_way_down_counts_only_for_the_descent():
    """A plate 16 cm above a top-down grasp is beyond the palm at the grasp pose, but the palm
    passes through it on the 10 cm descent from the pre-grasp."""
    box, _ = box_surface((0.04, 0.04, 0.04), (0.0, 0.0, 0.0))
    plate, _ = box_surface((0.08, 0.08, 0.004), (0.0, 0.0, 0.16))
    points = np.concatenate((box, plate))
    centre, rotation = _top_down((0.0, 0.0, 0.0), closing=(1.0, 0.0, 0.0))
    with_descent = _occupancy(points, centre, rotation, 0.04)
    at_grasp_only = _occupancy(points, centre, rotation, 0.04, descent_m=0.0)
    assert with_descent.total.item() == at_grasp_only.total.item() == 0
    assert at_grasp_only.descent.item() == 0
    assert with_descent.descent.item() > PLANNER.descent_max_fraction * len(points)


def test_planner_keeps_no_grasp_whose_descent_hits_an_overhang():
    """A 4 cm block under a shelf: every top-down approach is blocked, side approaches stay usable."""
    table = CONFIG.scene.table_top_z_m
    block, block_normals = box_surface((0.04, 0.04, 0.04), (0.55, 0.0, table + 0.02))
    shelf, _ = box_surface((0.12, 0.12, 0.004), (0.55, 0.0, table + 0.16))
    cloud = make_cloud(block, block_normals, table, obstacles=shelf)
    screened = screen_candidates([cloud], CONFIG, [0])
    assert screened.usable.any()
    usable_approach = screened.approach[screened.usable]
    # Usable approaches come in from the side: none points within 30 deg of straight down.
    assert (usable_approach @ DOWN < math.cos(math.radians(30.0))).all()
    unblocked = screen_candidates([make_cloud(block, block_normals, table)], CONFIG, [0])
    assert (unblocked.approach[unblocked.usable] @ DOWN > 0.99).any()
