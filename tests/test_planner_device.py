"""The planner's device: every tensor a plan makes lives on the device its clouds were moved to, a
device this machine lacks is refused in one line before any work, and on a GPU a plan agrees with
the CPU's."""
from __future__ import annotations

import pytest
import torch

from planner_clouds import box_surface, cylinder_surface, make_cloud
from sagp_batched.config import Config, ConfigError
from sagp_batched.planning import plan, plan_batch
from sagp_batched.preflight import PreflightError, check_planner_device

CONFIG = Config().override("planner", n_pairs=2000, max_candidates=16)
TABLE_Z = CONFIG.scene.table_top_z_m


@pytest.fixture(scope="module")
def clouds():
    box = make_cloud(*box_surface((0.06, 0.05, 0.15), (0.55, 0.0, TABLE_Z + 0.075)), "box")
    can = make_cloud(*cylinder_surface(0.035, 0.1, (0.5, 0.1, TABLE_Z)), "can")
    return [box, can]


def _planned(clouds, config):
    results = plan_batch(clouds, config, [0, 1])
    return [(result.counts, result.candidates.contacts, result.candidates.joint_path, result.candidates.hand_clearance_m) for result in results]


@pytest.mark.parametrize("search, compile", [("lookahead", False), ("blocks", False), ("lookahead", True)])
def test_a_plan_makes_every_tensor_on_the_clouds_device(clouds, search, compile):
    """With torch's default device set to ``meta``, a tensor made without naming the clouds' device
    lands on meta and the first operation mixing it with the clouds' CPU tensors fails: whole plans
    running through, with the grasps they give outside, show that none is made that way."""
    config = CONFIG.override("planner", search=search, compile=compile)
    expected = _planned(clouds, config)  # also builds the robot's cached tensors, on the CPU
    with torch.device("meta"):
        got = _planned(clouds, config)
    for (want_counts, *want), (counts, *values) in zip(expected, got):
        assert counts == want_counts and want_counts.ik_feasible > 0
        for want_value, value in zip(want, values):
            assert value.device.type == "cpu" and torch.equal(want_value, value)


def test_a_device_that_is_not_one_is_refused_by_name():
    with pytest.raises(ConfigError, match="planner.device: unknown device 'gpu'"):
        Config().override("planner", device="gpu")


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device")
def test_a_cuda_plan_without_cuda_is_refused_in_one_line_before_any_work(clouds):
    config = CONFIG.override("planner", device="cuda")
    with pytest.raises(PreflightError, match="planner.device 'cuda': this torch .* sees no CUDA device") as raised:
        check_planner_device(config.planner)
    assert "\n" not in str(raised.value)
    with pytest.raises(ValueError, match="sees no CUDA device"):
        plan(clouds[0], config)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_plan_on_the_gpu_agrees_with_the_cpu(clouds):
    """The same draws (a CPU generator on every device), so the same candidates up to float paths:
    most chosen grasps are the same contact pairs, and every GPU result comes back on the CPU."""
    on_cpu = plan_batch(clouds, CONFIG, [0, 1])
    on_gpu = plan_batch(clouds, CONFIG.override("planner", device="cuda"), [0, 1])
    for cpu_result, gpu_result in zip(on_cpu, on_gpu):
        assert gpu_result.candidates.width_m.device.type == "cpu"
        cpu_pairs = {tuple(c.tolist()) for c in cpu_result.candidates.contacts.flatten(1).round(decimals=5)}
        gpu_pairs = {tuple(c.tolist()) for c in gpu_result.candidates.contacts.flatten(1).round(decimals=5)}
        assert len(cpu_pairs & gpu_pairs) >= 0.9 * len(cpu_pairs)
