"""Seeded sampling of contact point pairs from a point cloud.

The candidate set of a trial must be reproducible and identical for every method compared, so
all randomness comes from an explicit ``torch.Generator``.
"""
from __future__ import annotations

import math

import torch

from .compiled import MIN_COMPILED_ROWS, compiled, padded_rows

# (pair, proposal) combinations the guided sampler scores at once, in ~10 work tensors of up to
# 1.5 MB made once per call: reused, they cost none of the page faults of whole chunks scored in
# fresh tensors.
SCORE_BLOCK_ELEMENTS = 131_072
# The guided sampler reads proposals' qualities from a table of every (anchor, proposal) pair of
# the cloud when that table is smaller than the proposals drawn, up to this many entries (64 MB):
# at 500,000 pairs of 64 proposals a 3,000-point cloud's 9M entries replace 32M proposals scored.
QUALITY_TABLE_MAX_ENTRIES = 16_777_216
# Proposals read from the table are drawn this many at a time (int32, 16 MB) and read in blocks of
# this many (4 MB of indices, 4 MB of qualities), their pairs sorted by anchor so that the table is
# read row by row: smaller draws leave the reads less local, larger ones gain little for their memory.
QUALITY_TABLE_DRAW_ELEMENTS = 4_194_304
QUALITY_TABLE_BLOCK_ELEMENTS = 1_048_576


def sample_pair_indices(n_points: int, n_pairs: int, generator: torch.Generator) -> torch.Tensor:
    """Draw ``n_pairs`` ordered pairs of distinct point indices uniformly at random.

    Args:
        n_points: number of points in the cloud, at least 2.
        n_pairs: number of pairs P to draw, at least 0.
        generator: CPU ``torch.Generator``; the same generator state gives the same pairs.

    Returns:
        (P, 2) int64 tensor of indices ``(i, j)`` into the cloud, ``i != j``. Pairs are drawn with
        replacement, so a pair (or its reverse) may appear more than once.
    """
    if n_points < 2:
        raise ValueError(f"need at least 2 points to sample pairs, got n_points={n_points}")
    if n_pairs < 0:
        raise ValueError(f"n_pairs must be >= 0, got {n_pairs}")
    first = torch.randint(0, n_points, (n_pairs,), generator=generator, device=generator.device)
    # Drawing the second index from n_points - 1 values and skipping the first gives distinct
    # indices without rejection, so the number of draws (and the generator state) is fixed.
    second = torch.randint(0, n_points - 1, (n_pairs,), generator=generator, device=generator.device)
    second = second + (second >= first).to(second.dtype)
    return torch.stack((first, second), dim=1)


def sample_guided_pair_indices(
    points: torch.Tensor,
    normals: torch.Tensor,
    n_pairs: int,
    n_proposals: int,
    min_width_m: float,
    max_width_m: float,
    generator: torch.Generator,
    chunk_elements: int,
    compile: bool = False,
) -> torch.Tensor:
    """Draw ``n_pairs`` pairs whose second point is chosen among proposals for being antipodal to the first.

    The antipodal-sampler idea of Dex-Net and GPD: a uniform pair lands on two small opposing
    patches (a mug handle's two faces) almost never, so each first point ``i`` is drawn uniformly
    and ``n_proposals`` second points ``j`` are drawn uniformly from the rest of the cloud; the
    pair keeps the proposal with the best antipodal quality ``min(cos_i, cos_j)`` (the contact
    cosines of ``antipodal.antipodal_pairs``, outward normals) among those at a distance in
    ``[min_width_m, max_width_m]``, or the first proposal when none is in range. Proposals are
    global, not drawn from a neighbourhood of ``i``: a point's nearest neighbours lie on its own
    face, so they miss the opposing face the pinch needs.

    Args:
        points: (N, 3) float cloud points, metres, any frame shared with ``normals``; N >= 2.
        normals: (N, 3) unit outward surface normals in the same frame.
        n_pairs: number of pairs P to draw, at least 0.
        n_proposals: second-point proposals K per pair, at least 1.
        min_width_m: the smallest contact distance a proposal may have, metres.
        max_width_m: the largest, metres (the gripper's reach).
        generator: CPU ``torch.Generator``; the same generator state gives the same pairs. It is
            advanced by exactly P + P * K draws, whatever the geometry.
        chunk_elements: (pair, proposal) combinations evaluated at once (~80 bytes each), at least 1;
            proposals read from a quality table are drawn and read in chunks of their own size.
        compile: score proposals with the compiled ``_fused_quality`` (``compiled``), the same
            arithmetic in one pass: the same pairs.

    Returns:
        (P, 2) int64 tensor of indices ``(i, j)`` into ``points``, ``i != j``. Pairs are drawn with
        replacement, so a pair may appear more than once.
    """
    _check_guided_inputs(points, normals, n_pairs, n_proposals, min_width_m, max_width_m, chunk_elements)
    n_points = points.shape[0]
    first = torch.randint(0, n_points, (n_pairs,), generator=generator, device=generator.device).to(points.device)
    if n_points * (n_points - 1) < min(n_pairs * n_proposals, QUALITY_TABLE_MAX_ENTRIES + 1):
        table = _proposal_quality_table(points, normals, min_width_m, max_width_m, compile)
        return torch.stack((first, _best_proposals_from_table(table, first, n_proposals, generator)), dim=1)
    second = _best_proposals_by_scoring(points, normals, first, n_proposals, min_width_m, max_width_m, generator, chunk_elements, compile)
    return torch.stack((first, second), dim=1)


def _best_proposals_by_scoring(
    points: torch.Tensor, normals: torch.Tensor, first: torch.Tensor, n_proposals: int, min_width_m: float, max_width_m: float,
    generator: torch.Generator, chunk_elements: int, compile: bool,
) -> torch.Tensor:
    """(P,) int64 second points of the pairs with anchors ``first`` (P,): ``n_proposals`` proposals
    drawn per pair from ``generator``, the best of each by ``_proposal_quality`` on (N, 3)
    ``points`` and ``normals`` (``compile``: by the compiled ``_fused_best_proposal``), the first among equals."""
    n_pairs, n_points = first.shape[0], points.shape[0]
    second = torch.empty_like(first)
    chunk_pairs = max(1, chunk_elements // n_proposals)
    # Proposals are drawn a chunk at a time and scored a block at a time into work tensors made
    # once: fresh multi-megabyte temporaries cost more in page faults (the allocator hands them
    # back to the system between chunks) than the arithmetic on them. No value depends on the
    # blocking. A compiled chunk is scored whole, in registers, with no work tensors.
    block_pairs = max(1, min(chunk_pairs, n_pairs, SCORE_BLOCK_ELEMENTS // n_proposals))
    work = None if compile else _ScoreWork(block_pairs * n_proposals, points.dtype, points.device)
    columns = (points.T.contiguous(), normals.T.contiguous()) if compile else None
    for start in range(0, n_pairs, chunk_pairs):
        chunk_anchor = first[start : start + chunk_pairs]
        # Same skip trick as sample_pair_indices: distinct from the anchor without rejection.
        chunk_proposal = torch.randint(0, n_points - 1, (chunk_anchor.shape[0], n_proposals), generator=generator, device=generator.device)
        chunk_proposal = chunk_proposal.to(points.device)
        chunk_proposal += chunk_proposal >= chunk_anchor[:, None]
        if compile:
            column = compiled(_fused_best_proposal)(*columns, padded_rows(chunk_anchor), padded_rows(chunk_proposal), min_width_m,
                                                    max_width_m)[: chunk_anchor.shape[0]]
            second[start : start + chunk_anchor.shape[0]] = chunk_proposal.gather(1, column[:, None]).squeeze(1)
            continue
        for block in range(0, chunk_anchor.shape[0], block_pairs):
            anchor = chunk_anchor[block : block + block_pairs]
            proposal = chunk_proposal[block : block + block_pairs]
            quality = _proposal_quality(points, normals, anchor, proposal, work, min_width_m, max_width_m)
            # argmax of an all -inf row is 0, the first proposal: the fallback needs no special case.
            second[start + block : start + block + anchor.shape[0]] = proposal.gather(1, quality.argmax(dim=1, keepdim=True)).squeeze(1)
    return second


def _best_proposals_from_table(table: torch.Tensor, first: torch.Tensor, n_proposals: int, generator: torch.Generator) -> torch.Tensor:
    """(P,) int64 second points of the pairs with anchors ``first`` (P,): ``n_proposals`` proposals
    drawn per pair, in pair order, from ``generator`` as the scoring path draws them, the best of
    each by its quality in ``table`` (N, N - 1), the first among equals."""
    n_options = table.shape[1]
    table = table.view(-1)
    second = torch.empty_like(first)
    draw_pairs = max(1, min(first.shape[0], QUALITY_TABLE_DRAW_ELEMENTS // n_proposals))
    block_pairs = max(1, min(draw_pairs, QUALITY_TABLE_BLOCK_ELEMENTS // n_proposals))
    # Work tensors made once (fresh multi-megabyte ones cost page faults), of int32 rather than
    # int64 (the index arithmetic and gathers move half the bytes; the table's flat indices stay
    # below QUALITY_TABLE_MAX_ENTRIES): the generator's draws below 2**32 are the same numbers in
    # either type, one 32-bit draw each, element by element, so the chunking does not change them
    # either.
    drawn = torch.empty(draw_pairs, n_proposals, dtype=torch.int32, device=generator.device)
    index = torch.empty(block_pairs, n_proposals, dtype=torch.int32, device=table.device)
    quality = torch.empty(block_pairs, n_proposals, dtype=table.dtype, device=table.device)
    for start in range(0, first.shape[0], draw_pairs):
        proposal = drawn[: min(draw_pairs, first.shape[0] - start)].random_(0, n_options, generator=generator).to(table.device)
        # Pairs read in anchor order read the table (36 MB at 3,000 points) a row (12 KB) at a
        # time instead of at random, for the price of a sort and a permutation. Equal anchors may
        # come in any order: each pair is read alone.
        anchor, order = first[start : start + proposal.shape[0]].sort()
        for block in range(0, order.shape[0], block_pairs):
            pairs = order[block : block + block_pairs]
            row_start = anchor[block : block + block_pairs, None] * n_options
            flat = torch.index_select(proposal, 0, pairs, out=index[: pairs.shape[0]]).add_(row_start.to(torch.int32))
            read = torch.index_select(table, 0, flat.view(-1), out=quality[: pairs.shape[0]].view(-1)).view(flat.shape)
            # max's index is argmax's, the first maximal proposal (an all -inf row falls back to
            # the first), and max is the quicker of the two.
            column = flat.gather(1, read.max(dim=1, keepdim=True).indices).to(torch.int64).sub_(row_start).squeeze(1)
            # Same skip trick as sample_pair_indices: distinct from the anchor without rejection.
            second[start + pairs] = column + (column >= anchor[block : block + block_pairs])
    return second


def _proposal_quality_table(
    points: torch.Tensor, normals: torch.Tensor, min_width_m: float, max_width_m: float, compile: bool = False
) -> torch.Tensor:
    """(N, N - 1) ``_proposal_quality`` of every anchor (row) with every proposal as drawn (column
    j is point j + (j >= anchor), the sampler's skip), by the same elementwise arithmetic (``compile``:
    by the compiled ``_fused_quality``): each entry is bit for bit the value scoring that proposal
    gives, but for the sign of a coincident pair's zero quality (in reach only when ``min_width_m`` is 0)."""
    n_points = points.shape[0]
    work = None if compile else _ScoreWork(max(SCORE_BLOCK_ELEMENTS, n_points), points.dtype, points.device)
    columns = (points.T.contiguous(), normals.T.contiguous()) if compile else None
    table = torch.empty(n_points, n_points, dtype=points.dtype, device=points.device)
    start = 0
    while start < n_points:
        # Only the upper triangle is scored, then mirrored, sparing half the pairs' scoring:
        # swapping anchor and proposal negates the offset exactly (IEEE subtraction is
        # antisymmetric), so the width is the same and the axis exactly negated, and the two
        # contact cosines swap exactly (negation commutes with rounding), so min(cos_i, cos_j) is
        # the same bits. Coincident points (offset +0 both ways) are the one exception: in reach
        # only when min_width_m is 0, their zero quality may come out -0.0 one way, +0.0 the
        # other, which compare equal, so the argmax over proposals is the same.
        # A compiled block holds its qualities alone, no work tensors: it takes as many as a table read.
        budget = QUALITY_TABLE_BLOCK_ELEMENTS if compile else SCORE_BLOCK_ELEMENTS
        rows = max(MIN_COMPILED_ROWS if compile else 1, budget // (n_points - start))
        end = min(start + rows, n_points)
        if compile and n_points - end < MIN_COMPILED_ROWS:
            end = n_points  # no last block of one row, which a compiled kernel would specialise

        # Scoring the cloud from ``start`` on with its first rows as anchors proposes columns
        # start..N-1 by broadcasting.
        if compile:
            block = compiled(_fused_quality_rows)(*(values[:, start:end] for values in columns), *(values[:, start:] for values in columns),
                                                   min_width_m, max_width_m)
        else:
            block = _proposal_quality(points[start:], normals[start:], torch.arange(end - start, device=points.device), None, work, min_width_m,
                                      max_width_m)
        table[start:end, start:] = block
        table[start:, start:end] = block.T
        start = end
    # Each row without its diagonal entry, in order: the skip's columns.
    return table.view(-1)[1:].view(n_points - 1, n_points + 1)[:, :-1].reshape(n_points, n_points - 1)


def _check_guided_inputs(
    points: torch.Tensor, normals: torch.Tensor, n_pairs: int, n_proposals: int, min_width_m: float, max_width_m: float, chunk_elements: int
) -> None:
    if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape:
        raise ValueError(f"points and normals must both be (N, 3), got {tuple(points.shape)} and {tuple(normals.shape)}")
    if not points.is_floating_point() or not normals.is_floating_point():
        raise ValueError(f"points and normals must be floating point, got {points.dtype} and {normals.dtype}")
    if points.shape[0] < 2:
        raise ValueError(f"need at least 2 points to sample pairs, got n_points={points.shape[0]}")
    if n_pairs < 0:
        raise ValueError(f"n_pairs must be >= 0, got {n_pairs}")
    if n_proposals < 1:
        raise ValueError(f"n_proposals must be >= 1, got {n_proposals}")
    if not 0.0 <= min_width_m <= max_width_m:
        raise ValueError(f"need 0 <= min_width_m <= max_width_m, got {min_width_m} and {max_width_m}")
    if chunk_elements < 1:
        raise ValueError(f"chunk_elements must be >= 1, got {chunk_elements}")


def _proposal_quality(
    points: torch.Tensor, normals: torch.Tensor, anchor: torch.Tensor, proposal: torch.Tensor, work: "_ScoreWork",
    min_width_m: float, max_width_m: float,
) -> torch.Tensor:
    """(B, K) antipodal quality of proposals (B, K) for anchors (B,), -inf out of reach, scored in ``work``
    (the returned tensor is one of its work tensors). ``proposal`` None proposes every point, in
    order (K = N), taken by broadcasting instead of gathers."""
    n_proposed = points.shape[0] if proposal is None else proposal.shape[1]
    gathered, offset, width, cos_i, cos_j, term, out_of_reach, beyond = work.cut(anchor.shape[0], n_proposed)
    flat = None if proposal is None else proposal.reshape(-1)

    def proposed(values: torch.Tensor) -> torch.Tensor:
        # index_select of the flattened proposals gives the same rows as indexing with the (C, K)
        # tensor, through a cheaper path than advanced indexing: these gathers weigh most in sampling.
        return values[None] if flat is None else torch.index_select(values, 0, flat, out=gathered).view(offset.shape)

    torch.sub(proposed(points), points[anchor][:, None, :], out=offset)
    # The width as (x x + y y) + z z, not torch.linalg.vector_norm's fused multiply-adds: the same
    # arithmetic as the compiled ``_fused_quality``, where inductor fuses no multiply-add.
    _dot(offset, offset, width, term).sqrt_()
    # The clamped widths borrow cos_i's tensor until the cosines are taken.
    axis = offset.div_(torch.clamp_min(width, torch.finfo(points.dtype).tiny, out=cos_i).unsqueeze(-1))
    # The contact cosines as antipodal_pairs' (n * axis).sum(-1), whose sum over three
    # terms runs (x + y) + z: the same values from component products, without its
    # broadcast reduction over a last axis of 3.
    _dot(proposed(normals), axis, cos_j, term)
    _dot(normals[anchor][:, None, :], axis, cos_i, term).neg_()
    torch.lt(width, min_width_m, out=out_of_reach).logical_or_(torch.gt(width, max_width_m, out=beyond))
    return torch.minimum(cos_i, cos_j, out=cos_i).masked_fill_(out_of_reach, -torch.inf)


def _fused_quality(
    anchor_points: torch.Tensor, anchor_normals: torch.Tensor, proposed_points: torch.Tensor, proposed_normals: torch.Tensor,
    min_width_m: float, max_width_m: float,
) -> torch.Tensor:
    """``_proposal_quality``'s values, element by element in its order, of anchors against proposals
    given as (3, ...) x, y and z rows that broadcast against each other (for ``compiled``)."""
    offset = [proposed_points[axis] - anchor_points[axis] for axis in range(3)]
    width = ((offset[0] * offset[0] + offset[1] * offset[1]) + offset[2] * offset[2]).sqrt()
    clamped = width.clamp_min(torch.finfo(width.dtype).tiny)
    axis = [component / clamped for component in offset]
    cos_j = (proposed_normals[0] * axis[0] + proposed_normals[1] * axis[1]) + proposed_normals[2] * axis[2]
    cos_i = -((anchor_normals[0] * axis[0] + anchor_normals[1] * axis[1]) + anchor_normals[2] * axis[2])
    return torch.minimum(cos_i, cos_j).masked_fill((width < min_width_m) | (width > max_width_m), -torch.inf)


def _fused_best_proposal(
    points: torch.Tensor, normals: torch.Tensor, anchor: torch.Tensor, proposal: torch.Tensor, min_width_m: float, max_width_m: float
) -> torch.Tensor:
    """(B,) int64 column of the best of each of (B, K) ``proposal``'s points for (B,) ``anchor``,
    the first among equals, from (3, N) ``points`` and ``normals`` rows."""
    quality = _fused_quality(points[:, anchor, None], normals[:, anchor, None], points[:, proposal], normals[:, proposal], min_width_m, max_width_m)
    return quality.argmax(dim=1)


def _fused_quality_rows(
    anchor_points: torch.Tensor, anchor_normals: torch.Tensor, points: torch.Tensor, normals: torch.Tensor, min_width_m: float,
    max_width_m: float,
) -> torch.Tensor:
    """(R, M) qualities of R anchors ((3, R) rows) against M proposals ((3, M) rows)."""
    return _fused_quality(anchor_points[:, :, None], anchor_normals[:, :, None], points[:, None, :], normals[:, None, :], min_width_m, max_width_m)


class _ScoreWork:
    """The guided sampler's work tensors for blocks of up to ``elements`` (pair, proposal) combinations."""

    def __init__(self, elements: int, dtype: torch.dtype, device: torch.device):
        self.tensors = (
            torch.empty(elements, 3, dtype=dtype, device=device),  # gathered points, then normals
            torch.empty(elements, 3, dtype=dtype, device=device),  # offsets, then closing axes
            *(torch.empty(elements, dtype=dtype, device=device) for _ in range(4)),  # widths, cos_i, cos_j, a product
            *(torch.empty(elements, dtype=torch.bool, device=device) for _ in range(2)),  # out of reach, beyond
        )

    def cut(self, pairs: int, proposals: int) -> tuple[torch.Tensor, ...]:
        """The work tensors cut to a block of ``pairs`` pairs of ``proposals`` proposals: the
        gathered rows flat (pairs * proposals, 3), the others (pairs, proposals, ...)."""
        gathered, *rest = (tensor[: pairs * proposals] for tensor in self.tensors)
        return (gathered, *(tensor.view(pairs, proposals, *tensor.shape[1:]) for tensor in rest))


def _dot(vectors: torch.Tensor, axis: torch.Tensor, out: torch.Tensor, term: torch.Tensor) -> torch.Tensor:
    """``(vectors * axis).sum(-1)`` of (..., 3) tensors into ``out``, summed (x + y) + z as that sum is."""
    torch.mul(vectors[..., 0], axis[..., 0], out=out)
    out += torch.mul(vectors[..., 1], axis[..., 1], out=term)
    out += torch.mul(vectors[..., 2], axis[..., 2], out=term)
    return out


def sample_subset_indices(n_points: int, max_points: int, generator: torch.Generator) -> torch.Tensor:
    """A seeded subset of at most ``max_points`` distinct indices, sorted ascending.

    Args:
        n_points: number of points in the cloud.
        max_points: size cap M of the subset.
        generator: CPU ``torch.Generator``.

    Returns:
        (min(n_points, M),) int64 indices; all indices when the cloud is not larger than M.
    """
    if n_points <= max_points:
        return torch.arange(n_points, device=generator.device)
    return torch.randperm(n_points, generator=generator, device=generator.device)[:max_points].sort().values


def voxel_representatives(points: torch.Tensor, voxel_m: float) -> torch.Tensor:
    """One point per occupied voxel: the first (lowest index) point in each cubic cell.

    Unlike a random subset, the kept points cover every surface patch the cloud covers, with at
    most one ``voxel_m`` cell between neighbours, so a thin part (a rim, a handle) keeps points.

    Args:
        points: (N, 3) positions, metres.
        voxel_m: cell edge, metres, > 0.

    Returns:
        (V,) int64 indices into ``points``, sorted ascending.
    """
    if voxel_m <= 0.0:
        raise ValueError(f"voxel_m must be > 0, got {voxel_m}")
    if points.shape[0] == 0:
        return torch.zeros(0, dtype=torch.int64, device=points.device)
    cells = torch.floor(points / voxel_m).to(torch.int64)
    cells = cells - cells.min(dim=0).values
    extent = cells.max(dim=0).values + 1
    if math.prod(extent.tolist()) < 2**62:
        # One int64 key per cell: a 1-D unique sorts plain keys where unique over rows compares
        # rows, and which label a cell gets does not matter, only which points share one.
        cells = (cells[:, 0] * extent[1] + cells[:, 1]) * extent[2] + cells[:, 2]
        _, inverse = torch.unique(cells, return_inverse=True)
    else:
        _, inverse = torch.unique(cells, dim=0, return_inverse=True)
    first = torch.full((int(inverse.max()) + 1,), points.shape[0], dtype=torch.int64, device=points.device)
    first.scatter_reduce_(0, inverse, torch.arange(points.shape[0], device=points.device), reduce="amin")
    return first.sort().values
