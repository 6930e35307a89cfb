import torch

from sagp_batched_kernels.hand_clearance import _compacted


def test_compacted_keeps_each_rows_chosen_points_in_index_order_then_nan():
    generator = torch.Generator().manual_seed(3)
    relative = torch.randn(6, 40, 3, generator=generator)
    chosen = torch.rand(6, 40, generator=generator) < 0.3
    chosen[2] = False  # a row with none chosen is all padding
    per_row = chosen.sum(dim=1)
    compact = _compacted(relative, chosen, per_row)
    assert compact.shape == (6, int(per_row.max()), 3)
    for row in range(6):
        kept = relative[row, chosen[row]]
        assert torch.equal(compact[row, : len(kept)], kept)
        assert compact[row, len(kept):].isnan().all()
