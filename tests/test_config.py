"""Profiles resolve to one config; flags override them; bad settings are clear errors."""
import dataclasses
import math
import re

import pytest

from sagp_batched.config import Config, ConfigError, load_config


# Every number the published method and experiment fix, as the paper states them. The paper
# profile must resolve to each, whether paper.toml writes it or leaves it to the built-in default,
# so an edit of either that moves a published number fails here.
PUBLISHED = {
    "camera.width_px": 640, "camera.height_px": 480, "camera.fov_deg": 60.0,
    "perception.normal_radius_m": 0.02, "perception.normal_max_neighbours": 30, "perception.crop_padding_fraction": 0.2,
    "planner.n_pairs": 5000, "planner.min_width_m": 0.005, "planner.max_width_m": 0.08,
    "planner.max_contact_angle_deg": 45.0, "planner.occupancy_max_fraction": 0.12, "planner.max_candidates": 200,
    "planner.min_reach": 0.5,
    "zones.protrusion_distance_factor": 1.5, "zones.dbscan_eps_m": 0.01, "zones.dbscan_min_samples": 10,
    "zones.min_protrusion_points": 20, "zones.up_world": (0.0, 0.0, 1.0),
    "weights.geom": 0.3, "weights.reach": 0.1, "weights.afford": 0.3, "weights.avoid": 0.2, "weights.task": 0.1,
    "rating.approach_tolerance_deg": 30.0, "rating.upright_max_tilt_deg": 15.0, "rating.vd_num_candidates": 20,
    "scene.time_step_s": 1 / 240, "scene.table_size_m": (1.2, 0.8), "scene.table_top_z_m": 0.625, "scene.seed_base": 42,
    "scene.distractor_count_range": (3, 4), "scene.distractor_max_distance_m": 0.15,
    "execution.ik_iterations": 500, "execution.settle_steps": 60, "motion.pregrasp_offset_m": 0.1,
    "motion.lift_height_m": 0.2, "execution.hold_steps": 80, "execution.success_height_above_table_m": 0.15,
    "execution.max_attempts": 3,
    "tasks.orientation_tolerance_deg": 15.0, "tasks.distractor_tolerance_m": 0.05,
    "run.n_trials": 20, "run.tasks": ("t1", "t2", "t3"), "run.methods": ("go", "sagp", "vd"),
}


@pytest.mark.parametrize("setting, published", PUBLISHED.items(), ids=list(PUBLISHED))
def test_paper_profile_resolves_to_every_published_number(setting, published):
    section, key = setting.split(".")
    resolved = getattr(getattr(load_config("paper"), section), key)
    assert resolved == (pytest.approx(published) if isinstance(published, float) else published)


def test_every_named_profile_loads():
    assert load_config("ci").run.n_trials < load_config("paper").run.n_trials
    assert load_config("datagen").run.export_grasps is True


def test_overrides_beat_the_profile_and_none_means_unset():
    config = load_config("paper", overrides={"run": {"n_trials": 3, "out": None}, "planner": {"n_pairs": 700}})
    assert config.run.n_trials == 3 and config.run.out == "runs/paper" and config.planner.n_pairs == 700


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"run": {"n_trails": 3}}, "unknown setting 'run.n_trails'"),
        ({"planner": {"n_pairs": "many"}}, "planner.n_pairs: expected a number"),
        ({"planner": {"n_pairs": 2.5}}, "expected a whole number"),
        ({"bogus": {}}, "unknown setting 'bogus'"),
    ],
)
def test_bad_settings_name_what_is_wrong(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_config("paper", overrides=overrides)


def test_unknown_profile_lists_the_named_ones(tmp_path):
    with pytest.raises(ConfigError, match="named profiles: .*paper"):
        load_config("no_such_profile")
    broken = tmp_path / "broken.toml"
    broken.write_text("[run\nn_trials = ")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(broken)


def _numeric_settings():
    """(section, field, default) of every setting holding a number or a tuple of numbers."""
    config = Config()
    for section in dataclasses.fields(config):
        values = getattr(config, section.name)
        for declared in dataclasses.fields(values):
            default = getattr(values, declared.name)
            if _first_number(default) is not None:
                yield section.name, declared.name, default


def _first_number(value):
    if isinstance(value, tuple):
        return next((n for n in map(_first_number, value) if n is not None), None)
    return value if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _out_of_range(value):
    """``value`` with its first number made invalid: nan for a float, -1 for a count (every count is >= 0)."""
    if isinstance(value, tuple):
        first = next(i for i, entry in enumerate(value) if _first_number(entry) is not None)
        return value[:first] + (_out_of_range(value[first]),) + value[first + 1:]
    return -1 if isinstance(value, int) else math.nan


NUMERIC_SETTINGS = list(_numeric_settings())


@pytest.mark.parametrize("section, key, default", NUMERIC_SETTINGS, ids=[f"{s}.{k}" for s, k, _ in NUMERIC_SETTINGS])
def test_every_numeric_setting_refuses_an_out_of_range_value_by_name(section, key, default):
    with pytest.raises(ConfigError, match=re.escape(f"{section}.{key}")) as refused:
        load_config(overrides={section: {key: _out_of_range(default)}})
    assert refused.value.setting == f"{section}.{key}"


def test_sections_made_in_code_are_checked_like_profiles():
    with pytest.raises(ConfigError, match=r"planner.n_pairs must be between 1 and 5,000,000, got 0"):
        dataclasses.replace(Config().planner, n_pairs=0)


def test_the_robot_is_read_from_its_file_and_an_unknown_one_is_refused_by_name():
    from sagp_batched.robot.description import load_robot

    robot = load_robot("panda")
    assert robot.n_arm_joints == len(robot.arm_joints) == len(robot.home_joints) == len(robot.joint_twist_rad)
    assert robot.base_xyz_m == (-0.05, 0.0, 0.625) and robot.gripper.gripper_boxes.finger_width_m == 0.021
    with pytest.raises(ConfigError, match="scene.robot: unknown value 'ur5' \\(known: panda\\)") as caught:
        load_config(overrides={"scene": {"robot": "ur5"}})
    assert caught.value.setting == "scene.robot" and "\n" not in str(caught.value)


def test_the_default_worker_count_is_the_cores_this_process_may_use(monkeypatch):
    import os

    from sagp_batched.config import MAX_WORKERS
    from sagp_batched.config.run import available_cores

    expected = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert Config().run.workers == load_config("ci").run.workers == available_cores() == min(expected, MAX_WORKERS)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    assert Config().run.workers == 3
    monkeypatch.delattr(os, "sched_getaffinity")
    monkeypatch.setattr(os, "cpu_count", lambda: 5000)
    assert Config().run.workers == MAX_WORKERS
    # A flag or a profile's value is kept whatever the machine has.
    assert load_config("ci", overrides={"run": {"workers": 1}}).run.workers == 1
