"""The planner's stages as a clock and the profiler see them: the seconds and the work (pairs, poses,
IK targets) of each stage of one ``plan_batch`` call, and each stage's operations inside a
``torch.profiler`` range named after it, so a profile can be read stage by stage."""
from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

import torch

STAGES = ("sampling", "antipodal", "frames_volume", "hand_sweep", "ik", "motion")
# A stage's profiler range is this prefix and the stage's name.
STAGE_RANGE_PREFIX = "sagp_stage:"


class StageClock:
    """Seconds and work items each stage has taken so far; ``stage`` times one piece of a stage."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(STAGES, 0.0)
        self.items = dict.fromkeys(STAGES, 0)

    @contextlib.contextmanager
    def stage(self, name: str, items: int = 0) -> Iterator[None]:
        """The block as part of stage ``name`` (one of ``STAGES``), which took ``items`` more work items."""
        start = time.perf_counter()
        with torch.profiler.record_function(STAGE_RANGE_PREFIX + name):
            yield
        self.seconds[name] += time.perf_counter() - start
        self.items[name] += items
