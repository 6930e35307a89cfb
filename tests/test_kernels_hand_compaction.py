import pytest
import torch

from sagp_batched.config import Config
from sagp_batched.planning import hand_geometry
from sagp_batched.robot.description import load_robot
from sagp_batched.robot.hand import DOP_DIRECTIONS
from sagp_batched_kernels.grasp_frames import scene_points_about
from sagp_batched_kernels.hand_clearance import _compacted, _least_per_run, hand_clearance, row_blocks, scene_extents

ROBOT = load_robot()

CONFIG = Config()


def test_compacted_keeps_each_rows_chosen_points_about_its_centre_in_index_order_then_nan():
    generator = torch.Generator().manual_seed(3)
    points = torch.randn(2, 40, 3, generator=generator)
    scene = torch.tensor([0, 1, 1, 0, 1, 0])
    centre = torch.randn(6, 3, generator=generator)
    chosen = torch.rand(6, 40, generator=generator) < 0.3
    chosen[2] = False  # a row with none chosen is all padding
    per_row = chosen.sum(dim=1)
    compact = _compacted(points, scene, centre, chosen, per_row)
    relative = scene_points_about(points, scene, centre)
    assert compact.shape == (6, int(per_row.max()), 3)
    for row in range(6):
        kept = relative[row, chosen[row]]
        assert torch.equal(compact[row, : len(kept)], kept)
        assert compact[row, len(kept):].isnan().all()


def test_least_per_run_picks_each_runs_first_least_column():
    bound = torch.tensor([[3.0, 1.0, 2.0, 5.0, 5.0, 4.0], [float("inf")] * 3 + [0.0, -1.0, -1.0]])
    assert torch.equal(_least_per_run(bound, 2), torch.tensor([[1, 5], [0, 4]]))
    assert torch.equal(_least_per_run(bound, 3), torch.tensor([[1, 2, 5], [0, 3, 4]]))


def _dense_separation(points, object_index, centre, rotation, directions, low, high):
    """(C, N) every point's separation: the definition the culled kernel reproduces."""
    relative = points[object_index] - centre[:, None, :]
    projection = ((directions @ rotation.transpose(-1, -2)) @ relative.transpose(1, 2))[:, None]
    excess = ((projection - ((low + high) / 2)[None, :, :, None]).abs() - ((high - low) / 2)[None, :, :, None]).amax(dim=2).amin(dim=1)
    return torch.nan_to_num(excess, nan=float("inf"))


def _assert_meets_the_contract(swept, separation, margin_m):
    """``blocked`` exactly where some point is under the margin; an unblocked row's clearance the
    least separation, a blocked row's the separation of some point under the margin."""
    dense = separation.amin(dim=1)
    assert torch.equal(swept.blocked, dense < margin_m)
    assert torch.equal(swept.clearance_m[~swept.blocked], dense[~swept.blocked])
    blocked = swept.clearance_m[swept.blocked]
    assert (blocked < margin_m).all()
    assert (separation[swept.blocked] == blocked[:, None]).any(dim=1).all()
    assert swept.blocked.any() and not swept.blocked.all()


def _two_scenes(generator):
    """Two scenes a metre out from the origin (world coordinates, where the bounds are taken), the
    second smaller, and 400 candidates near their points, interleaved so every block mixes them."""
    points = torch.randn(2, 300, 3, generator=generator) * 0.05 + torch.tensor([[[0.6, 0.0, 0.7]], [[0.4, 0.3, 0.8]]])
    points[1, 250:] = float("nan")
    object_index = torch.arange(400) % 2
    centre = points[object_index, torch.randint(0, 250, (400,), generator=generator)] + torch.randn(400, 3, generator=generator) * 0.03
    rotation = torch.linalg.qr(torch.randn(400, 3, 3, generator=generator)).Q
    return points, object_index, centre, rotation


def test_blocks_mixing_scenes_give_what_one_scene_blocks_and_every_point_give():
    """Candidates of two scenes interleaved in every block, against each scene on its own: the same
    verdicts and unblocked clearances (a blocked row's only has to be some blocking point's)."""
    points, object_index, centre, rotation = _two_scenes(torch.Generator().manual_seed(7))
    probes = points[:, ::10]
    low, high = hand_geometry(ROBOT).swept((0.0, 0.0, -CONFIG.motion.pregrasp_offset_m))
    directions = DOP_DIRECTIONS
    arguments = (directions, low, high, 0.003, 20 * low.numel() * 300)
    mixed = hand_clearance(points, probes, object_index, centre, rotation, *arguments)
    separation = _dense_separation(points, object_index, centre, rotation, directions, low, high)
    for index in (0, 1):
        alone = hand_clearance(points[index:index + 1], probes[index:index + 1], torch.zeros(200, dtype=torch.int64),
                               centre[index::2], rotation[index::2], *arguments)
        _assert_meets_the_contract(alone, separation[index::2], 0.003)
    _assert_meets_the_contract(mixed, separation, 0.003)


@pytest.mark.parametrize("probe_stride", [1, 7, 300])
def test_any_probe_subset_gives_the_exact_verdicts_and_unblocked_clearances(probe_stride):
    """The probes only find blocking points early: every point's, a coarse subset's or a single
    point's probes all leave ``blocked`` and the unblocked clearances exact."""
    points, object_index, centre, rotation = _two_scenes(torch.Generator().manual_seed(11))
    low, high = hand_geometry(ROBOT).swept((0.0, 0.0, -CONFIG.motion.pregrasp_offset_m))
    swept = hand_clearance(points, points[:, ::probe_stride], object_index, centre, rotation, DOP_DIRECTIONS, low, high, 0.003,
                           20 * low.numel() * 300)
    _assert_meets_the_contract(swept, _dense_separation(points, object_index, centre, rotation, DOP_DIRECTIONS, low, high), 0.003)


def test_scene_extents_end_each_scene_at_its_last_row_without_nan():
    points = torch.zeros(3, 5, 3)
    points[0, 3:] = float("nan")
    points[1, 1:4, 2] = float("nan")  # NaN rows inside a scene are its own, the last real row ends it
    points[2] = float("nan")
    assert scene_extents(points).tolist() == [3, 5, 0]


def test_row_blocks_cover_the_rows_in_order_within_the_budget_one_scene_each():
    scene = torch.tensor([0] * 7 + [1] * 3 + [2] * 9 + [0] * 2)
    width = torch.tensor([10, 40, 5])
    blocks = row_blocks(scene, width, 60)
    assert [start for start, *_ in blocks] == [0] + [end for _, end, *_ in blocks[:-1]] and blocks[-1][1] == scene.numel()
    for start, end, block_width, block_scene in blocks:
        assert (scene[start:end] == block_scene).all() and block_width == int(width[block_scene]) and (end - start) * block_width <= 60
    # A block never reaches into the next scene's rows, even where the budget has room.
    assert row_blocks(torch.tensor([2, 2, 0]), width, 60) == [(0, 2, 5, 2), (2, 3, 10, 0)]
    # A row wider than the whole budget still gets a block of its own.
    assert row_blocks(torch.tensor([1, 1]), width, 30) == [(0, 1, 40, 1), (1, 2, 40, 1)]
    assert row_blocks(torch.zeros(0, dtype=torch.int64), width, 60) == []
