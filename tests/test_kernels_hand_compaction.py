import torch

from sagp_batched.config import Config
from sagp_batched.hand import DOP_DIRECTIONS
from sagp_batched.planner import hand_geometry
from sagp_batched_kernels.grasp_frames import scene_points_about
from sagp_batched_kernels.hand_clearance import _compacted, _nearest, hand_clearance

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


def test_nearest_picks_the_set_topk_picks_with_and_without_ties_at_the_kth_value():
    generator = torch.Generator().manual_seed(5)
    bound = torch.randn(50, 40, generator=generator)
    bound[:10] = bound[:10].round(decimals=1)  # many ties, some at the k-th value
    bound[10:15, 30:] = float("inf")  # padding of a smaller scene
    bound[15, :] = float("inf")
    for k in (1, 8, 16):
        expected = torch.zeros_like(bound, dtype=torch.bool).scatter_(1, bound.topk(k, dim=1, largest=False).indices, True)
        nearest = _nearest(bound, k)
        assert nearest.shape == (50, k)
        assert torch.equal(torch.zeros_like(expected).scatter_(1, nearest, True), expected)


def _dense_clearance(points, object_index, centre, rotation, directions, low, high):
    """Every point's separation: the definition the culled kernel reproduces where not blocked."""
    relative = points[object_index] - centre[:, None, :]
    projection = ((directions @ rotation.transpose(-1, -2)) @ relative.transpose(1, 2))[:, None]
    excess = ((projection - ((low + high) / 2)[None, :, :, None]).abs() - ((high - low) / 2)[None, :, :, None]).amax(dim=2).amin(dim=1)
    return torch.nan_to_num(excess, nan=float("inf")).amin(dim=1)


def test_blocks_mixing_scenes_give_what_one_scene_blocks_and_every_point_give():
    """Two scenes a metre out from the origin (world coordinates, where the point pass bounds),
    candidates interleaved so that every block mixes them, against each scene on its own."""
    generator = torch.Generator().manual_seed(7)
    points = torch.randn(2, 300, 3, generator=generator) * 0.05 + torch.tensor([[[0.6, 0.0, 0.7]], [[0.4, 0.3, 0.8]]])
    points[1, 250:] = float("nan")  # the second scene is smaller
    probes = points[:, ::10]
    object_index = torch.arange(400) % 2
    centre = points[object_index, torch.randint(0, 250, (400,), generator=generator)] + torch.randn(400, 3, generator=generator) * 0.03
    rotation = torch.linalg.qr(torch.randn(400, 3, 3, generator=generator)).Q
    low, high = hand_geometry(CONFIG.planner).swept((0.0, 0.0, -CONFIG.execution.pregrasp_offset_m))
    directions = DOP_DIRECTIONS
    arguments = (directions, low, high, 0.003, 20 * low.numel() * 300)
    mixed = hand_clearance(points, probes, object_index, centre, rotation, *arguments)
    for index in (0, 1):
        alone = hand_clearance(points[index:index + 1], probes[index:index + 1], torch.zeros(200, dtype=torch.int64),
                               centre[index::2], rotation[index::2], *arguments)
        assert torch.equal(mixed.blocked[index::2], alone.blocked)
        assert torch.equal(mixed.clearance_m[index::2], alone.clearance_m)
    dense = _dense_clearance(points, object_index, centre, rotation, directions, low, high)
    assert torch.equal(mixed.blocked, dense < 0.003)
    assert torch.equal(mixed.clearance_m[~mixed.blocked], dense[~mixed.blocked])
    assert mixed.blocked.any() and not mixed.blocked.all()
