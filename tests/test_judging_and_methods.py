"""Task success by the published task definitions, with the thresholds the config holds; the method registry; the robot description."""
import pytest

from sagp_batched.config import TaskConfig
from sagp_batched.study.judging import judge_task

PUBLISHED = TaskConfig()


def test_a_stable_pickup_needs_only_the_grasp_to_succeed():
    assert judge_task("t1", True, False, 40.0, 0.2, PUBLISHED).task_success
    assert not judge_task("t1", False, True, 0.0, 0.0, PUBLISHED).task_success


def test_a_functional_grasp_needs_the_preferred_zone_and_the_orientation_kept_within_15_degrees():
    assert judge_task("t2", True, True, 14.9, 0.0, PUBLISHED).task_success
    tilted = judge_task("t2", True, True, 15.1, 0.0, PUBLISHED)
    assert not tilted.task_success and not tilted.orientation_kept
    assert not judge_task("t2", True, False, 1.0, 0.0, PUBLISHED).task_success


def test_a_cluttered_grasp_fails_when_a_distractor_moves_more_than_5_cm():
    assert judge_task("t3", True, False, 30.0, 0.049, PUBLISHED).task_success
    assert not judge_task("t3", True, False, 0.0, 0.051, PUBLISHED).task_success


def test_the_thresholds_come_from_the_config():
    lenient = TaskConfig(orientation_tolerance_deg=30.0, distractor_tolerance_m=0.1)
    assert judge_task("t2", True, True, 20.0, 0.0, lenient).task_success
    assert judge_task("t3", True, False, 0.0, 0.08, lenient).task_success


def test_an_unknown_task_is_named():
    with pytest.raises(ValueError, match="unknown task 't9'"):
        judge_task("t9", True, True, 0.0, 0.0, PUBLISHED)


def test_every_method_name_has_one_registered_ranking_only_vlm_direct_asks_a_model_itself_only_sagp_ranks_by_the_rating_and_only_go_is_timed_without_it():
    from sagp_batched.study.methods import REGISTRY, get_method
    from sagp_batched.types import METHODS

    assert tuple(REGISTRY) == METHODS
    assert [name for name, method in REGISTRY.items() if method.needs_model] == ["vd"]
    assert [name for name, method in REGISTRY.items() if method.uses_rating] == ["sagp"]
    assert [name for name, method in REGISTRY.items() if not method.plan_time_counts_rating] == ["go"]
    with pytest.raises(ValueError, match="unknown method 'xx'"):
        get_method("xx")


def test_the_robot_is_described_once_and_its_joints_are_found_by_name_in_the_loaded_urdf():
    import pybullet

    from sagp_batched.robot.description import load_robot
    from sagp_batched.world.scene import body_indices

    robot = load_robot()

    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(robot.urdf_path), useFixedBase=True, physicsClientId=client)
        indices = body_indices(robot, body, client)
        names = {pybullet.getJointInfo(body, j, physicsClientId=client)[1].decode(): j for j in range(pybullet.getNumJoints(body, physicsClientId=client))}
        assert indices.arm_joints == tuple(names[name] for name in robot.arm_joints) and len(indices.arm_joints) == 7
        assert pybullet.getJointInfo(body, indices.grasp_target_link, physicsClientId=client)[12].decode() == robot.gripper.grasp_target_link
    finally:
        pybullet.disconnect(client)
    # The grasp target's offset from the hand comes from the URDF (pybullet_data's is 0.105 m).
    assert abs(robot.gripper.grasp_depth_m - 0.105) < 1e-6
