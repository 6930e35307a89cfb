"""The derived seeds keep their published values: a change would silently redraw every earlier run and dataset."""
from sagp_batched.config import load_config
from sagp_batched.seeds import candidate_seed, capture_trial, ik_restart_seed, labelling_seed, scene_seed


def test_derived_seeds_are_the_configured_ones_plus_the_trial_or_capture():
    config = load_config("paper", overrides={"scene": {"seed_base": 42}, "planner": {"seed": 7}, "dataset": {"seed": 1000}})
    assert scene_seed(config, 3) == ik_restart_seed(config, 3) == 45
    assert candidate_seed(config, 3) == 52
    assert capture_trial(config, 2) == labelling_seed(config, 2) == 1002
