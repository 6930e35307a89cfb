"""Grasps whose outcome is known by construction, made for each gripper from its own geometry.

On a box lying 4 cm tall (``DESIGNED_BOX_M``), top-down:

1. across its 4 cm width, the pads on its sides: held;
2. the same, moved beyond its end until both fingers close beside it: dropped (not lifted);
3. the palm 6 mm into its top: a collision, decided by geometry before any simulation;

and on a ball too wide for the gripper (``wide_ball_radius_m``: every pair of its points whose normals lie within
the planner's contact angle of the line between them is wider than the opening; a cube would not do, its edges
are narrow pinches):

4. across its middle: a collision (the open hand cannot surround it), and
5. the planner, given the ball's surface, proposes no candidate at all (``wide_ball_candidates``).

Depths and offsets come from the gripper's hulls (``robot.hand``), so the same five hold for any gripper.
"""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sagp_batched_kernels.grasp_frames import grasp_rotations

from ..config import Config
from ..config.run import LABEL_PROTOCOLS
from ..grasps import GraspPoses
from ..robot.description import RobotDescription, robot_of
from ..robot.hand import load_hand_geometry
from ..types import PerceivedCloud
from ..world.mesh_settings import MeshImportSettings
from ..world.objects import ObjectSpec

# The designed box (m): lying on its 5 x 8 face, 4 cm tall, once imported.
DESIGNED_BOX_M = (0.05, 0.04, 0.08)
# The held grasp's grasp target this far below the box's top, or less where the open fingertips would come
# nearer than FINGERTIP_TABLE_CLEARANCE_M to the box's bottom (the table, in the tabletop protocol).
ACROSS_DEPTH_M = 0.02
FINGERTIP_TABLE_CLEARANCE_M = 0.008
# How far the fingers clear the box's end in the dropped grasp, and how deep the palm goes into it.
FINGERS_CLEAR_M = 0.004
PALM_INTO_BOX_M = 0.006
# The wide ball's diameter as a multiple of the gripper's opening: a chord meeting the surface within 45 deg of
# its normals is at least cos(45 deg) = 0.71 diameters long, here 1.13 openings.
WIDE_BALL_OPENINGS = 1.6
# Per designed grasp on the box, then the grasp across the wide ball, (held, simulated).
DESIGNED_OUTCOMES = ((True, True), (False, True), (False, False), (False, False))
DOWN, CLOSING = np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])


def _top_down(positions: list[list[float]]) -> GraspPoses:
    rotation = grasp_rotations(torch.tensor(CLOSING), torch.tensor(DOWN))
    return GraspPoses(torch.tensor(positions, dtype=torch.float64), rotation.expand(len(positions), 3, 3).clone(), "object")


def designed_box_grasps(box: ObjectSpec, robot: RobotDescription) -> GraspPoses:
    """Top-down grasps by ``robot.gripper`` on the box lying in its link frame (long side along x), closing across
    its width: the pads on its sides; the fingers clear of its end; the palm ``PALM_INTO_BOX_M`` into it."""
    length, _, height = box.extents_m
    hand, gripper = load_hand_geometry(robot), robot.gripper
    fingertip_reach = float(hand.vertices(gripper.pad_links)[:, 2].max())
    palm_face = float(hand.vertices((gripper.base_link,))[:, 2].max())  # negative: behind the grasp target
    depth = min(ACROSS_DEPTH_M, height - fingertip_reach - FINGERTIP_TABLE_CLEARANCE_M)
    beside = length / 2 + gripper.gripper_boxes.finger_width_m / 2 + FINGERS_CLEAR_M
    return _top_down([[0.0, 0.0, height - depth], [beside, 0.0, height - depth], [0.0, 0.0, height + palm_face - PALM_INTO_BOX_M]])


def wide_ball_radius_m(robot: RobotDescription) -> float:
    """The radius of a ball too wide for ``robot.gripper`` to pinch anywhere."""
    return WIDE_BALL_OPENINGS * robot.gripper.open_width_m / 2.0


def _imported(mesh, folder: Path, cache_dir: Path | None) -> ObjectSpec:
    from ..world.objects import load_object_set

    mesh.export(folder / "shape.obj")
    # The wide ball is wider than every hand on purpose: the import would refuse it as ungraspable.
    return load_object_set(folder, MeshImportSettings(max_grasp_width_m=2.0 * float(mesh.extents.max()), cache_dir=cache_dir)).get("shape")


def designed_grasps(config: Config, cache_dir: Path | None = None, engine: str = "pybullet") -> dict[str, dict[str, Any]]:
    """Per protocol, how many of the designed grasps ``engine`` labels with the outcome they were designed for,
    with the configured gripper."""
    import trimesh

    from ..datasets.labelling import label_object_grasps

    robot = robot_of(config)
    results = {}
    with tempfile.TemporaryDirectory(prefix="sagp_designed_box_") as box_folder, tempfile.TemporaryDirectory(prefix="sagp_wide_ball_") as wide_folder:
        box = _imported(trimesh.creation.box(DESIGNED_BOX_M), Path(box_folder), cache_dir)
        wide = _imported(trimesh.creation.icosphere(subdivisions=3, radius=wide_ball_radius_m(robot)), Path(wide_folder), cache_dir)
        across_wide = _top_down([[0.0, 0.0, wide.extents_m[2] / 2.0]])
        for protocol in LABEL_PROTOCOLS:
            labels = label_object_grasps(box, designed_box_grasps(box, robot), None, protocol, config, engine=engine)
            labels += label_object_grasps(wide, across_wide, None, protocol, config, engine=engine)
            got = [(label.held, label.simulated) for label in labels]
            results[protocol] = {"correct": sum(g == e for g, e in zip(got, DESIGNED_OUTCOMES)), "of": len(DESIGNED_OUTCOMES),
                                 "labels": [{"held": l.held, "simulated": l.simulated, "failure": l.failure_reason} for l in labels]}
    return results


def wide_ball_candidates(config: Config, n_points: int = 4000) -> int:
    """How many candidates the planner returns for the surface of a ball too wide for the configured gripper,
    resting on the table: none, where the width limits hold."""
    from ..planning import plan_batch

    radius = wide_ball_radius_m(robot_of(config))
    # A Fibonacci sphere: points spread evenly, each its own outward normal.
    index = np.arange(n_points) + 0.5
    polar, azimuth = np.arccos(1.0 - 2.0 * index / n_points), np.pi * (1.0 + 5.0**0.5) * index
    normals = np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], axis=1)
    centre = np.array([*config.scene.table_center_xy_m, config.scene.table_top_z_m + radius])
    cloud = PerceivedCloud(
        points_world=torch.as_tensor(normals * radius + centre, dtype=torch.float32), normals_world=torch.as_tensor(normals, dtype=torch.float32),
        view_index=torch.zeros(n_points, dtype=torch.int64), crop_rgb=np.zeros((1, 1, 3), dtype=np.uint8), cameras=[],
        object_id="wide_ball", object_position_world=centre, object_quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]),
    )
    return len(plan_batch([cloud], config)[0].candidates)
