"""Kernels' fused blocks compiled by ``torch.compile`` (inductor), each compiled once per process.

A block that runs a long chain of element-wise operations over (pose, point) pairs costs eager
torch one pass over memory and one dispatch per operation; inductor turns the chain into one loop
that keeps each pair's values in registers. Blocks are compiled for dynamic shapes, so one compiled
kernel serves every block size; a size of 0 or 1 would be specialised (compiled again), so callers
hand blocks of at least ``MIN_COMPILED_ROWS`` rows. Where inductor writes its compiled code (and
finds it again in a later process) is its cache directory, ``$TORCHINDUCTOR_CACHE_DIR``.
"""
from __future__ import annotations

import functools
from collections.abc import Callable

import torch

# Blocks this small are padded up to it: dynamic shapes still specialise sizes 0 and 1.
MIN_COMPILED_ROWS = 2


@functools.cache
def compiled(function: Callable) -> Callable:
    """``function`` compiled by inductor for dynamic shapes, the same object on every call."""
    return torch.compile(function, dynamic=True)


def padded_rows(tensor: torch.Tensor, rows: int = MIN_COMPILED_ROWS) -> torch.Tensor:
    """``tensor`` with its first row repeated until it has at least ``rows`` rows (contiguous)."""
    if tensor.shape[0] >= rows:
        return tensor.contiguous()
    return torch.cat([tensor, tensor[:1].expand(rows - tensor.shape[0], *tensor.shape[1:])]).contiguous()
