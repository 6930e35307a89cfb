"""The screens' verdicts held against their exhaustive references: the planner's kernels decide every
pose of real and unseen clouds as the plain computation does, and the comparison sees a screen that
does not."""
from __future__ import annotations

import pytest
import torch

from sagp_batched.benchmarks.verdict_agreement import CHECKS, screen_agreement, unseen_shape_clouds
from sagp_batched.config import Config
from sagp_batched.planning.screens import ScreenedCandidates

CONFIG = Config().override("planner", n_pairs=1500)
OBJECT_XY_M = (0.55, 0.0)


@pytest.fixture(scope="module")
def unseen_clouds():
    return unseen_shape_clouds(CONFIG, 2, 1500, OBJECT_XY_M, seed=3)


def test_unseen_shapes_rest_on_the_table_at_the_place_asked(unseen_clouds):
    assert len({cloud.object_id for cloud in unseen_clouds}) == 2
    for cloud in unseen_clouds:
        # Placed by the mesh's bounds: its surface samples come within a few millimetres of them.
        lowest = float(cloud.points_world[:, 2].min())
        assert CONFIG.scene.table_top_z_m <= lowest + 1e-6 < CONFIG.scene.table_top_z_m + 0.005
        middle = (cloud.points_world[:, :2].amin(0) + cloud.points_world[:, :2].amax(0)) / 2
        assert torch.allclose(middle, torch.tensor(OBJECT_XY_M), atol=0.005)
        assert torch.allclose(cloud.normals_world.norm(dim=1), torch.ones(1), atol=1e-5)


def test_every_screen_decides_every_pose_as_its_exhaustive_reference(unseen_clouds):
    agreement = screen_agreement(unseen_clouds, CONFIG, [0, 1])
    for check in CHECKS:
        assert agreement[check].poses > 100, check
        assert agreement[check].agree == agreement[check].poses, (check, agreement[check].disagreements[:5])


def test_a_screen_that_lets_every_pose_through_is_caught(unseen_clouds, monkeypatch):
    monkeypatch.setattr(ScreenedCandidates, "volume_within", lambda self, rows, rotation, poses: poses.clone())
    agreement = screen_agreement(unseen_clouds, CONFIG, [0, 1])
    volume = agreement["volume"]
    assert volume.agree < volume.poses
    # Every pose it wrongly passes holds more points than the limit allows.
    assert all(d["reference_margin"] < 0 for d in volume.disagreements)
