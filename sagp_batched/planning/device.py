"""The torch device a plan runs on (``[planner] device``), checked before any tensor moves there."""
from __future__ import annotations

import torch

from ..config import PlannerConfig


def planning_device(planner: PlannerConfig) -> torch.device:
    """The device ``planner.device`` names; ``ValueError`` in one line where this torch cannot use it."""
    device = torch.device(planner.device)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"planner.device {planner.device!r}: this torch ({torch.__version__}) sees no CUDA device")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ValueError(f"planner.device {planner.device!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    return device
