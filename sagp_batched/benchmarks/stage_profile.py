"""Where a plan's time goes, stage by stage: one ``plan_batch`` under ``torch.profiler``, its
operators attributed to the stage range (``planning.stages``) they ran in.

A stage's cost on a CPU is the work inside its operators plus a fixed cost per operator (dispatch,
allocation, the Python between them): ``ops`` counts the operators a stage called from Python
(those a compiled kernel runs inside count as the one call), ``op_s`` the profiled seconds inside
them, ``profiled_s`` the stage's whole profiled time, so ``profiled_s - op_s`` is the interpreter's
share. ``search`` is what ``plan_batch`` does outside the stages (the candidate search's bookkeeping).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from torch.profiler import ProfilerActivity, profile, record_function

from ..config import Config
from ..planning import plan_batch
from ..planning.stages import STAGE_RANGE_PREFIX, STAGES
from ..types import PerceivedCloud

PLAN_RANGE = "sagp_plan"
SEARCH = "search"  # the plan's time outside every stage
PROFILED_STAGES = (*STAGES, SEARCH)


def _is_operator(event) -> bool:
    return event.name.startswith(("aten::", "Torch-Compiled Region", "CompiledFunction"))


def _stage_of(event) -> str | None:
    """The stage whose range ``event`` ran in, ``SEARCH`` inside the plan but outside every stage, None outside the plan."""
    parent = event.cpu_parent
    while parent is not None:
        if parent.name.startswith(STAGE_RANGE_PREFIX):
            return parent.name[len(STAGE_RANGE_PREFIX):]
        if parent.name == PLAN_RANGE:
            return SEARCH
        parent = parent.cpu_parent
    return None


def profile_stages(clouds: Sequence[PerceivedCloud], config: Config, seeds: Sequence[int], singles: bool = False) -> dict[str, dict[str, Any]]:
    """Per stage of one ``plan_batch(clouds, config, seeds)`` (``singles``: of one ``plan_batch``
    per cloud, summed) (``PROFILED_STAGES``): ``ops`` (operators called from Python), ``op_s``
    (profiled seconds inside them) and ``profiled_s`` (the stage's profiled seconds, its operators
    and the Python between them)."""
    batches = [([cloud], [seed]) for cloud, seed in zip(clouds, seeds)] if singles else [(clouds, seeds)]
    with profile(activities=[ProfilerActivity.CPU]) as profiler:
        for batch_clouds, batch_seeds in batches:
            with record_function(PLAN_RANGE):
                plan_batch(batch_clouds, config, batch_seeds)
    table = {stage: {"ops": 0, "op_s": 0.0, "profiled_s": 0.0} for stage in PROFILED_STAGES}
    for event in profiler.events():
        if event.name == PLAN_RANGE:
            table[SEARCH]["profiled_s"] += event.cpu_time_total * 1e-6
        elif event.name.startswith(STAGE_RANGE_PREFIX):
            stage_s = event.cpu_time_total * 1e-6
            table[event.name[len(STAGE_RANGE_PREFIX):]]["profiled_s"] += stage_s
            table[SEARCH]["profiled_s"] -= stage_s if _stage_of(event) == SEARCH else 0.0
        elif _is_operator(event) and not (event.cpu_parent is not None and _is_operator(event.cpu_parent)):
            stage = _stage_of(event)
            if stage is not None:
                table[stage]["ops"] += 1
                table[stage]["op_s"] += event.cpu_time_total * 1e-6
    return table
