"""Process-wide runtime settings, set once by entry points (runners, workers), never at import."""
from __future__ import annotations

import torch

# Measured: with 2 intra-op threads torch sometimes stalls for seconds on these 2-vCPU
# machines in small-tensor loops; 1 thread did not. The planner's tensors are small (<= 1e6
# elements), so one thread costs little and parallelism comes from worker processes instead.
DEFAULT_TORCH_THREADS = 1


def configure_torch(threads: int = DEFAULT_TORCH_THREADS) -> None:
    torch.set_num_threads(threads)
