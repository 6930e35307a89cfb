"""Descent checks: fingertips grazing the table on a flat object are no collision; driving them into it is."""
from __future__ import annotations


import numpy as np
import pybullet
import pytest
from scipy.spatial.transform import Rotation

from sagp_batched import Config, Grasp
from sagp_batched.execution.pick import execute_grasp
from sagp_batched.world.objects import load_object_set
from sagp_batched.world.scene import Scene

from ycb_paths import YCB_DIR
DOWN = np.array([0.0, 0.0, -1.0])


@pytest.fixture(scope="module")
def marker_scene():
    """The 1.9 cm-thick marker lying on the table, grasped top-down across its middle."""
    if not (YCB_DIR / "objects.json").is_file():
        pytest.skip(f"YCB models not found at {YCB_DIR}")
    with Scene(Config()) as scene:
        scene.reset(load_object_set(YCB_DIR).get("040_large_marker"), trial=1)
        yield scene


def _across_marker(scene: Scene, height_above_table_m: float):
    lower, upper = (np.array(v) for v in pybullet.getAABB(scene.target_id, physicsClientId=scene.client))
    _, link_quat = scene.object_link_pose(scene.target_id)
    # The marker's long axis is its model's x; the jaws close across it, along its horizontal y.
    closing = Rotation.from_quat(link_quat).apply([0.0, 1.0, 0.0])
    closing[2] = 0.0
    closing /= np.linalg.norm(closing)
    rotation = np.stack([np.cross(closing, DOWN), closing, DOWN], axis=1)
    centre = (lower + upper) / 2.0
    position = np.array([centre[0], centre[1], Config().scene.table_top_z_m + height_above_table_m])
    return position, Rotation.from_matrix(rotation).as_quat()


def test_grazing_the_table_while_grasping_a_marker_is_not_a_collision(marker_scene):
    config = Config()
    marker_scene.restore_state()
    # Grasp point 7 mm up: the finger hulls (7.3 mm past it) end level with the table top and touch it.
    position, quat = _across_marker(marker_scene, 0.007)
    attempt = execute_grasp(marker_scene, config, Grasp.from_pose(position, quat, 0.019, DOWN))
    assert attempt.success, (attempt.failure_reason, attempt.diagnostics)


def test_driving_the_fingers_into_the_table_is_a_collision(marker_scene):
    marker_scene.restore_state()
    # Fingertips 8 mm below the table top at the end of the descent: the arm presses on the table.
    position, quat = _across_marker(marker_scene, -0.001)
    attempt = execute_grasp(marker_scene, Config(), Grasp.from_pose(position, quat, 0.019, DOWN))
    assert attempt.failure_reason == "collision"
    assert attempt.diagnostics.failed_at == "descent"
    assert any(link.endswith("->table") for link in attempt.diagnostics.collision_links)
