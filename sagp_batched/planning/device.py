"""The torch device a plan runs on (``[planner] device``), checked before any tensor moves there."""
from __future__ import annotations

import platform

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


def device_name(device: str) -> str:
    """What runs a plan on ``device`` (``planning_device``'s), in words: the GPU's name or the CPU's
    model, so a benchmark's figures say what they were measured on (these machines are not all alike)."""
    if torch.device(device).type == "cuda":
        return torch.cuda.get_device_name(torch.device(device))
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            return next((line.split(":", 1)[1].strip() for line in cpuinfo if line.startswith("model name")), platform.machine())
    except OSError:
        return platform.machine()
