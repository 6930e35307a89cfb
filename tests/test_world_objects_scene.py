"""Object registry and scene: clear errors for bad object sets, deterministic seeded scenes."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pybullet
import pytest

from sagp_batched import Config
from sagp_batched.robot.description import load_robot
from sagp_batched.world.objects import (
    PYBULLET_DATA_SET,
    YCB_DIR_ENV,
    ObjectLoadError,
    ObjectSetError,
    UnknownObjectError,
    load_object_set,
)
from sagp_batched.world.scene import Scene

from ycb_paths import YCB_DIR, needs_ycb

ROBOT = load_robot()


@pytest.fixture(scope="module")
def scene():
    with Scene(Config()) as created:
        yield created


@pytest.fixture(scope="module")
def ycb():
    if not (YCB_DIR / "objects.json").is_file():
        pytest.skip(f"YCB models not found at {YCB_DIR}")
    return load_object_set(YCB_DIR)


def _copy_object(src_dir: Path, dst_dir: Path, object_id: str) -> dict:
    entry = json.loads((src_dir / "objects.json").read_text())[object_id]
    shutil.copytree(src_dir / object_id, dst_dir / object_id)
    return entry


@needs_ycb
def test_ycb_set_has_the_spec_categories_and_asymmetric_flags(ycb):
    assert ycb.source.startswith("ycb:")
    assert len(ycb.targets()) == 14 and len(ycb.distractors()) == 7
    asymmetric = {spec.id for spec in ycb.targets() if spec.asymmetric}
    assert asymmetric == {"025_mug", "019_pitcher_base", "035_power_drill", "037_scissors", "051_large_clamp", "011_banana", "040_large_marker"}
    assert ycb.get("021_bleach_cleanser").category == "boxes"
    assert len(ycb.checksum()) == 64


def test_builtin_set_is_selected_by_name_and_settles(scene):
    builtin = load_object_set(PYBULLET_DATA_SET)
    assert builtin.source.startswith("builtin:")
    assert "mug" in builtin.ids and len(builtin.distractors()) >= 4
    for spec in builtin.targets():
        scene.reset(spec, trial=0)
        linear, angular = pybullet.getBaseVelocity(scene.target_id, physicsClientId=scene.client)
        assert np.linalg.norm(linear) < 0.01 and np.linalg.norm(angular) < 0.1, f"{spec.id} did not settle"
        lower, _ = pybullet.getAABB(scene.target_id, physicsClientId=scene.client)
        assert abs(lower[2] - Config().scene.table_top_z_m) < 0.005, f"{spec.id} is not resting on the table"


def test_env_variable_selects_the_directory(monkeypatch, tmp_path):
    monkeypatch.setenv(YCB_DIR_ENV, str(tmp_path / "nowhere"))
    with pytest.raises(ObjectSetError, match="nowhere"):
        load_object_set(None)


def test_unknown_object_id_names_it_and_the_known_ids():
    builtin = load_object_set(PYBULLET_DATA_SET)
    with pytest.raises(UnknownObjectError, match="999_unicorn.*mug"):
        builtin.get("999_unicorn")


def test_missing_dir_and_malformed_index_are_named(tmp_path):
    with pytest.raises(ObjectSetError, match="does not exist"):
        load_object_set(tmp_path / "missing")
    with pytest.raises(ObjectSetError, match="no objects.json"):
        load_object_set(tmp_path)
    (tmp_path / "objects.json").write_text("{not json")
    with pytest.raises(ObjectSetError, match="not valid JSON"):
        load_object_set(tmp_path)
    (tmp_path / "objects.json").write_text(json.dumps({"001_thing": {"urdf": "001_thing/model.urdf"}}))
    with pytest.raises(ObjectSetError, match="001_thing"):
        load_object_set(tmp_path)


@needs_ycb
def test_broken_urdfs_are_named(tmp_path, scene):
    entry = _copy_object(YCB_DIR, tmp_path, "005_tomato_soup_can")
    (tmp_path / "objects.json").write_text(json.dumps({"005_tomato_soup_can": entry}))
    urdf = tmp_path / "005_tomato_soup_can" / "model.urdf"
    urdf.write_text("<robot name='broken'><link name='base_link'>")
    with pytest.raises(ObjectLoadError, match="005_tomato_soup_can.*not valid XML"):
        load_object_set(tmp_path)
    urdf.unlink()
    with pytest.raises(ObjectLoadError, match="does not exist"):
        load_object_set(tmp_path)
    # Valid XML that PyBullet cannot turn into a body fails when the scene loads it.
    urdf.write_text("<robot name='empty'></robot>")
    spec = load_object_set(tmp_path).get("005_tomato_soup_can")
    with pytest.raises(ObjectLoadError, match="005_tomato_soup_can"):
        scene.reset(spec, trial=0)


@needs_ycb
def test_same_trial_gives_the_same_settled_pose_and_trials_differ(scene, ycb):
    can = ycb.get("005_tomato_soup_can")
    scene.reset(can, trial=3)
    first = scene.object_link_pose(scene.target_id)
    scene.reset(ycb.get("025_mug"), trial=3)
    scene.reset(can, trial=3)
    again = scene.object_link_pose(scene.target_id)
    assert np.abs(first[0] - again[0]).max() < 1e-6
    assert np.abs(first[1] - again[1]).max() < 1e-6
    scene.reset(can, trial=4)
    other = scene.object_link_pose(scene.target_id)
    assert np.linalg.norm(other[0][:2] - first[0][:2]) > 0.01
    config = Config()
    assert config.scene.object_x_range_m[0] - 0.01 <= first[0][0] <= config.scene.object_x_range_m[1] + 0.01
    assert abs(first[0][2] - config.scene.table_top_z_m) < 0.003  # link frame at the bottom face: resting on the table


def test_table_top_is_exactly_at_the_configured_height(scene):
    scene.reset(load_object_set(PYBULLET_DATA_SET).get("cube_small"), trial=0)
    config = Config()
    hit = pybullet.rayTest([0.9, 0.3, 2.0], [0.9, 0.3, 0.0], physicsClientId=scene.client)[0]
    assert hit[0] == scene.table_id
    assert abs(hit[3][2] - config.scene.table_top_z_m) < 1e-6
    lower, upper = pybullet.getAABB(scene.table_id, physicsClientId=scene.client)
    margin = 0.01  # PyBullet pads AABBs by a small collision margin
    assert abs((upper[0] - lower[0]) - config.scene.table_size_m[0]) < margin
    assert abs((upper[1] - lower[1]) - config.scene.table_size_m[1]) < margin


@needs_ycb
def test_distractors_are_seeded_near_the_target_without_overlap(scene, ycb):
    config = Config()
    for trial in range(3):
        scene.reset(ycb.get("006_mustard_bottle"), trial=trial, distractors=ycb.distractors())
        assert 3 <= len(scene.distractor_ids) <= 4
        target_lo, target_hi = (np.array(v) for v in pybullet.getAABB(scene.target_id, physicsClientId=scene.client))
        boxes = [(target_lo, target_hi)]
        for body in scene.distractor_ids:
            lo, hi = (np.array(v) for v in pybullet.getAABB(body, physicsClientId=scene.client))
            gap = np.maximum(0.0, np.maximum(target_lo[:2] - hi[:2], lo[:2] - target_hi[:2]))
            assert np.linalg.norm(gap) <= config.scene.distractor_max_distance_m + 0.01
            for other_lo, other_hi in boxes:
                assert not np.all((lo[:2] < other_hi[:2]) & (other_lo[:2] < hi[:2])), "footprints overlap"
            boxes.append((lo, hi))
        speed = np.linalg.norm(pybullet.getBaseVelocity(scene.distractor_ids[0], physicsClientId=scene.client)[0])
        assert speed < 0.01, "distractors should be settled"
    first_ids = [spec.id for spec in scene.distractor_specs]
    scene.reset(ycb.get("006_mustard_bottle"), trial=2, distractors=ycb.distractors())
    assert [spec.id for spec in scene.distractor_specs] == first_ids


@needs_ycb
def test_restore_state_returns_to_the_settled_scene(scene, ycb):
    scene.reset(ycb.get("005_tomato_soup_can"), trial=1)
    settled = scene.object_link_pose(scene.target_id)[0]
    pybullet.resetBasePositionAndOrientation(scene.target_id, [0.5, 0.3, 1.0], [0, 0, 0, 1], physicsClientId=scene.client)
    scene.set_arm_joints(ROBOT.ik_reference_joints)
    scene.restore_state()
    assert np.abs(scene.object_link_pose(scene.target_id)[0] - settled).max() < 1e-9
    assert np.allclose(scene.arm_joints(), ROBOT.home_joints, atol=1e-4)
