"""Seeded sampling of contact point pairs from a point cloud.

The candidate set of a trial must be reproducible and identical for every method compared, so
all randomness comes from an explicit ``torch.Generator``.
"""
from __future__ import annotations

import torch


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
    first = torch.randint(0, n_points, (n_pairs,), generator=generator)
    # Drawing the second index from n_points - 1 values and skipping the first gives distinct
    # indices without rejection, so the number of draws (and the generator state) is fixed.
    second = torch.randint(0, n_points - 1, (n_pairs,), generator=generator)
    second = second + (second >= first).to(second.dtype)
    return torch.stack((first, second), dim=1)


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
        return torch.arange(n_points)
    return torch.randperm(n_points, generator=generator)[:max_points].sort().values
