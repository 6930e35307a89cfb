"""Whether a grasp held its object, and why not: one test for the study's arm (``pick``) and for every
label engine (``datasets.protocols``), each feeding it what it measured."""
from __future__ import annotations

from ..config import ExecutionConfig


def object_held(fingers_touching: bool, com_height_above_table_m: float | None, execution: ExecutionConfig) -> bool:
    """Every finger on the object and, where there is a table, its centre of mass
    ``success_height_above_table_m`` above it (``com_height_above_table_m`` None: no table)."""
    high_enough = com_height_above_table_m is None or com_height_above_table_m >= execution.success_height_above_table_m
    return high_enough and fingers_touching


def lift_failure(highest_rise_m: float, fingers_touching_after_close: bool, execution: ExecutionConfig) -> tuple[str, str]:
    """(reason, phase) of a grasp not held after the lift: "slipped" when the object rose at least
    ``lifted_detect_height_m`` before it fell, else "not_lifted"; in the lift when the fingers
    held it after closing, else already in the close."""
    phase = "lift" if fingers_touching_after_close else "close"
    return ("slipped" if highest_rise_m >= execution.lifted_detect_height_m else "not_lifted"), phase
