"""Guided (antipodal) pair sampling on constructed geometry with exact normals."""
import numpy as np
import pytest
import torch

from planner_clouds import box_surface
from sagp_batched.config import Config
from sagp_batched.planning import widest_pair_m
from sagp_batched.robot import load_robot
from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.sampling import sample_guided_pair_indices, sample_pair_indices

PLANNER = Config().planner
# The widest pair the planner draws for the default gripper (the Panda hand: 0.08 m).
WIDEST_M = widest_pair_m(load_robot(), PLANNER)
CHUNK = Config().memory.pair_proposal_chunk_elements


def _tensors(points, normals):
    return torch.as_tensor(points, dtype=torch.float32), torch.as_tensor(normals, dtype=torch.float32)


def _guided(points, normals, n_pairs, seed, n_proposals=PLANNER.pair_proposals, chunk=CHUNK):
    return sample_guided_pair_indices(
        points, normals, n_pairs, n_proposals, PLANNER.min_width_m, WIDEST_M, torch.Generator().manual_seed(seed), chunk
    )


def _antipodal(points, normals, pairs):
    return antipodal_pairs(points, normals, pairs, PLANNER.min_width_m, WIDEST_M, PLANNER.max_contact_angle_deg)["antipodal"]


def test_guided_pairs_on_a_box_are_far_more_often_antipodal_than_uniform_ones():
    points, normals = _tensors(*box_surface((0.05, 0.06, 0.1), (0.0, 0.0, 0.0)))
    uniform = sample_pair_indices(len(points), 5000, torch.Generator().manual_seed(11))
    guided = _guided(points, normals, 5000, 11)
    n_uniform = int(_antipodal(points, normals, uniform).sum())
    n_guided = int(_antipodal(points, normals, guided).sum())
    assert n_guided > 3 * n_uniform
    # Only the 10 cm z-faces have no partner in reach; every other face's first point finds one.
    assert n_guided > 0.5 * 5000


def test_guided_sampling_finds_a_small_part_next_to_a_large_one():
    # A 10 cm cube (wider than the jaws on every axis) beside a 1 cm thick fin holding ~7 % of the
    # points: the shape of a mug body and its handle.
    body_points, body_normals = box_surface((0.1, 0.1, 0.1), (0.0, 0.0, 0.05))
    fin_points, fin_normals = box_surface((0.01, 0.03, 0.04), (-0.07, 0.0, 0.05))
    points, normals = _tensors(np.concatenate((body_points, fin_points)), np.concatenate((body_normals, fin_normals)))
    on_fin = torch.arange(len(points)) >= len(body_points)
    assert on_fin.float().mean() < 0.08

    def fin_antipodal(pairs):
        return int((_antipodal(points, normals, pairs) & on_fin[pairs[:, 0]] & on_fin[pairs[:, 1]]).sum())

    uniform = fin_antipodal(sample_pair_indices(len(points), 5000, torch.Generator().manual_seed(2)))
    guided = fin_antipodal(_guided(points, normals, 5000, 2))
    assert guided > 10 * max(uniform, 1)


def test_same_seed_same_pairs_whatever_the_chunk_size():
    points, normals = _tensors(*box_surface((0.05, 0.06, 0.1), (0.0, 0.0, 0.0)))
    a = _guided(points, normals, 3000, 5)
    assert torch.equal(a, _guided(points, normals, 3000, 5))
    assert torch.equal(a, _guided(points, normals, 3000, 5, chunk=1000))
    assert not torch.equal(a, _guided(points, normals, 3000, 6))


def test_pair_count_distinct_indices_and_generator_draws_are_fixed():
    box_points, box_normals = _tensors(*box_surface((0.05, 0.06, 0.1), (0.0, 0.0, 0.0)))
    # Same number of points spread over 100 m: no proposal is ever in reach, every pair falls back.
    far_points = torch.rand(len(box_points), 3, generator=torch.Generator().manual_seed(0)) * 100.0
    states = []
    for points in (box_points, far_points):
        generator = torch.Generator().manual_seed(9)
        pairs = sample_guided_pair_indices(
            points, box_normals, 4000, 16, PLANNER.min_width_m, WIDEST_M, generator, CHUNK
        )
        assert pairs.shape == (4000, 2) and pairs.dtype == torch.int64
        assert (pairs[:, 0] != pairs[:, 1]).all()
        assert pairs.min() >= 0 and pairs.max() < len(points)
        states.append(torch.rand(4, generator=generator))
    assert torch.equal(states[0], states[1])
    assert sample_guided_pair_indices(box_points, box_normals, 0, 16, 0.005, 0.08, torch.Generator(), CHUNK).shape == (0, 2)


def test_pairs_stay_in_reach_when_a_proposal_is_in_reach():
    points, normals = _tensors(*box_surface((0.03, 0.03, 0.03), (0.0, 0.0, 0.0)))
    pairs = _guided(points, normals, 2000, 4, n_proposals=8)
    width = (points[pairs[:, 1]] - points[pairs[:, 0]]).norm(dim=1)
    # The cube's diagonal (5.2 cm) is in reach, so only proposals under 5 mm can be missed.
    assert (width <= WIDEST_M).all()
    assert (width >= PLANNER.min_width_m).float().mean() > 0.99


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(normals=torch.zeros(10, 2)), "points and normals must both be"),
        (dict(points=torch.zeros(10, 3, dtype=torch.int64), normals=torch.zeros(10, 3, dtype=torch.int64)), "floating point"),
        (dict(points=torch.zeros(1, 3), normals=torch.zeros(1, 3)), "at least 2 points"),
        (dict(n_pairs=-1), "n_pairs"),
        (dict(n_proposals=0), "n_proposals"),
        (dict(min_width_m=0.1, max_width_m=0.08), "min_width_m <= max_width_m"),
        (dict(chunk_elements=0), "chunk_elements"),
    ],
)
def test_bad_inputs_raise_named_errors(change, message):
    arguments = dict(
        points=torch.rand(10, 3), normals=torch.rand(10, 3), n_pairs=5, n_proposals=4, min_width_m=0.005,
        max_width_m=0.08, generator=torch.Generator(), chunk_elements=CHUNK,
    )
    arguments.update(change)
    with pytest.raises(ValueError, match=message):
        sample_guided_pair_indices(**arguments)


@pytest.mark.parametrize("spread_m", [None, 100.0])
@pytest.mark.parametrize("draw_block_elements", [None, (1100, 300)])
def test_proposals_read_from_the_quality_table_give_the_pairs_scoring_each_proposal_gives(monkeypatch, spread_m, draw_block_elements):
    # A grid box's points tie in quality often (argmax must break ties alike); points spread over
    # 100 m leave every proposal out of reach (the fallback to the first proposal). Draws of 17
    # pairs read in blocks of 4 (the last of each short) must give the pairs one draw gives.
    if draw_block_elements is not None:
        monkeypatch.setattr("sagp_batched_kernels.sampling.QUALITY_TABLE_DRAW_ELEMENTS", draw_block_elements[0])
        monkeypatch.setattr("sagp_batched_kernels.sampling.QUALITY_TABLE_BLOCK_ELEMENTS", draw_block_elements[1])
    points, normals = _tensors(*box_surface((0.05, 0.06, 0.1), (0.0, 0.0, 0.0)))
    keep = torch.randperm(len(points), generator=torch.Generator().manual_seed(1))[:400]
    points, normals = points[keep], normals[keep]
    if spread_m is not None:
        points = torch.rand(len(points), 3, generator=torch.Generator().manual_seed(0)) * spread_m
    n_pairs = 3000  # 3,000 x 64 proposals > 400 x 399 table entries: the table is used
    assert len(points) * (len(points) - 1) < n_pairs * PLANNER.pair_proposals
    generator = torch.Generator().manual_seed(4)
    from_table = sample_guided_pair_indices(points, normals, n_pairs, PLANNER.pair_proposals, PLANNER.min_width_m, WIDEST_M, generator, 5000)
    table_state = torch.rand(4, generator=generator)
    monkeypatch.setattr("sagp_batched_kernels.sampling.QUALITY_TABLE_MAX_ENTRIES", 0)
    generator = torch.Generator().manual_seed(4)
    scored = sample_guided_pair_indices(points, normals, n_pairs, PLANNER.pair_proposals, PLANNER.min_width_m, WIDEST_M, generator, 5000)
    assert torch.equal(from_table, scored)
    assert torch.equal(table_state, torch.rand(4, generator=generator))
    assert (from_table[:, 0] != from_table[:, 1]).all()


@pytest.mark.parametrize("min_width_m", [PLANNER.min_width_m, 0.0])
def test_quality_table_scored_on_one_triangle_equals_scoring_every_pair(monkeypatch, min_width_m):
    from sagp_batched_kernels import sampling

    generator = torch.Generator().manual_seed(5)
    # Points over 0.2 m, so many pairs are out of reach, with a few coincident points.
    points = torch.rand(300, 3, generator=generator) * 0.2
    points[::37] = points[1]
    normals = torch.nn.functional.normalize(torch.randn(300, 3, generator=generator), dim=1)
    # Blocks of a few rows, growing as the rows shorten: the mirrored blocks must tile the table.
    monkeypatch.setattr(sampling, "SCORE_BLOCK_ELEMENTS", 1000)
    table = sampling._proposal_quality_table(points, normals, min_width_m, WIDEST_M)
    everything = torch.arange(len(points))
    full = sampling._proposal_quality(
        points, normals, everything, None, sampling._ScoreWork(len(points) ** 2, points.dtype, points.device), min_width_m, WIDEST_M
    )
    expected = full[~torch.eye(len(points), dtype=torch.bool)].view(len(points), len(points) - 1)
    # Bit for bit, except that a coincident pair's zero quality (in reach when the minimum width
    # is 0) may swap sign: -0.0 and 0.0 compare equal, so the sampler's argmax is unchanged.
    assert torch.equal(table, expected)
    if min_width_m > 0:
        assert torch.equal(table.view(torch.int32), expected.view(torch.int32))
