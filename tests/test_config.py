"""Profiles resolve to one config; flags override them; bad settings are clear errors."""
import pytest

from sagp_batched.config import GEOMETRY_ONLY_WEIGHTS, ConfigError, load_config


def test_paper_profile_holds_the_published_settings():
    config = load_config("paper")
    assert config.planner.n_pairs == 5000
    assert (config.weights.geom, config.weights.reach, config.weights.afford, config.weights.avoid, config.weights.task) == (0.3, 0.1, 0.3, 0.2, 0.1)
    assert config.run.n_trials == 20 and set(config.run.tasks) == {"t1", "t2", "t3"}
    assert config.scene.table_top_z_m == 0.625 and config.scene.seed_base == 42
    assert config.planner.occupancy_max_fraction == 0.12 and config.planner.max_candidates == 200


def test_every_named_profile_loads():
    assert load_config("ci").run.n_trials < load_config("paper").run.n_trials
    assert load_config("datagen").run.export_grasps is True


def test_overrides_beat_the_profile_and_none_means_unset():
    config = load_config("paper", overrides={"run": {"n_trials": 3, "out": None}, "planner": {"n_pairs": 700}})
    assert config.run.n_trials == 3 and config.run.out == "runs/paper" and config.planner.n_pairs == 700


def test_geometry_only_weights_are_s_geom_alone():
    assert (GEOMETRY_ONLY_WEIGHTS.geom, GEOMETRY_ONLY_WEIGHTS.afford, GEOMETRY_ONLY_WEIGHTS.task) == (1.0, 0.0, 0.0)


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
