"""planner.pair_sampling: validated at load, and sample_inputs draws the pairs it names."""
import pytest
import torch

from planner_clouds import box_surface, make_cloud
from sagp_batched.config import Config, ConfigError, load_config
from sagp_batched.planning import sample_inputs, widest_pair_m
from sagp_batched.robot.description import load_robot
from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.sampling import sample_pair_indices

ROBOT = load_robot()
MEMORY = Config().memory


def test_unknown_pair_sampling_mode_is_a_config_error_naming_the_known_modes():
    with pytest.raises(ConfigError, match=r"planner.pair_sampling.*'antipodel'.*uniform, guided"):
        load_config("ci", overrides={"planner": {"pair_sampling": "antipodel"}})
    with pytest.raises(ConfigError, match="pair_proposals"):
        load_config("ci", overrides={"planner": {"pair_proposals": 0}})


def test_sample_inputs_follows_the_configured_mode():
    points, normals = box_surface((0.05, 0.06, 0.1), (0.5, 0.0, 0.675))
    cloud = make_cloud(points, normals)
    uniform_config = Config().override("planner", pair_sampling="uniform").planner
    guided_config = Config().override("planner", pair_sampling="guided").planner
    uniform = sample_inputs(cloud, ROBOT, uniform_config, MEMORY, seed=3)
    guided = sample_inputs(cloud, ROBOT, guided_config, MEMORY, seed=3)
    assert torch.equal(uniform.pair_indices, sample_pair_indices(cloud.n_points, uniform_config.n_pairs, torch.Generator().manual_seed(3)))
    assert guided.pair_indices.shape == uniform.pair_indices.shape
    assert torch.equal(guided.pair_indices, sample_inputs(cloud, ROBOT, guided_config, MEMORY, seed=3).pair_indices)

    def n_antipodal(pairs):
        planner = guided_config
        result = antipodal_pairs(
            cloud.points_world, cloud.normals_world, pairs, planner.min_width_m, widest_pair_m(ROBOT, planner), planner.max_contact_angle_deg
        )
        return int(result["antipodal"].sum())

    assert n_antipodal(guided.pair_indices) > 3 * n_antipodal(uniform.pair_indices)
