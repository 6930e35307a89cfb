"""``[planner] compile`` changes how the sampler and the screens compute, never what they decide: with
their long element-wise chains compiled by inductor, plans, pairs, volume verdicts and swept-hand
clearances are the eager ones, bit for bit (the first run compiles the kernels, ~1 min; later runs
load them from the inductor cache)."""
import dataclasses

import numpy as np
import pytest
import torch

from planner_clouds import box_surface, cylinder_surface, make_cloud
from sagp_batched.config import Config
from sagp_batched.planning import plan_batch, screen_candidates

EAGER = Config().override("planner", n_pairs=1500)
COMPILED = EAGER.override("planner", compile=True)
TABLE_Z = EAGER.scene.table_top_z_m


@pytest.fixture(scope="module")
def clouds():
    """A box, a can beside another can's points, and a cube of few points (few enough that the
    guided sampler reads proposals from its quality table)."""
    rng = np.random.default_rng(0)
    box = box_surface((0.06, 0.05, 0.15), (0.55, 0.0, TABLE_Z + 0.075))
    can = cylinder_surface(0.035, 0.1, (0.5, 0.1, TABLE_Z))
    neighbour = cylinder_surface(0.035, 0.1, (0.5, 0.185, TABLE_Z))[0]
    cube = box_surface((0.04, 0.04, 0.04), (0.45, -0.1, TABLE_Z + 0.02), spacing_m=0.008)
    jitter = [(points + rng.normal(scale=0.0005, size=points.shape), normals) for points, normals in (box, can, cube)]
    assert len(jitter[2][0]) * (len(jitter[2][0]) - 1) < EAGER.planner.n_pairs * EAGER.planner.pair_proposals
    return [make_cloud(*jitter[0], "box"), make_cloud(*jitter[1], "can", obstacles=neighbour), make_cloud(*jitter[2], "cube")]


def test_compiled_plans_are_the_eager_plans(clouds):
    seeds = [3, 4, 5]
    for eager, compiled in zip(plan_batch(clouds, EAGER, seeds), plan_batch(clouds, COMPILED, seeds), strict=True):
        assert compiled.counts == eager.counts and len(eager.candidates) > 0
        for field in dataclasses.fields(eager.candidates):
            value, reference = getattr(compiled.candidates, field.name), getattr(eager.candidates, field.name)
            assert torch.equal(value, reference) if isinstance(reference, torch.Tensor) else value == reference, field.name


def test_compiled_screens_decide_every_pose_as_the_eager_screens(clouds):
    eager, compiled = screen_candidates(clouds, EAGER, [1, 2, 3]), screen_candidates(clouds, COMPILED, [1, 2, 3])
    assert torch.equal(compiled.pair_indices, eager.pair_indices)
    usable = eager.usable
    assert torch.equal(compiled.usable, usable) and usable.any() and not usable.all()
    rows, slots = usable.nonzero(as_tuple=True)
    swept, compiled_swept = eager.hand_clearance(rows, slots), compiled.hand_clearance(rows, slots)
    assert torch.equal(compiled_swept.blocked, swept.blocked) and swept.blocked.any() and not swept.blocked.all()
    assert torch.equal(compiled_swept.clearance_m[~swept.blocked], swept.clearance_m[~swept.blocked])
