"""The motion a grasp is executed with: one section that the planner checks and execution runs."""
from __future__ import annotations

from dataclasses import dataclass

from .settings import _Section, setting


@dataclass
class MotionConfig(_Section):
    """Pre-grasp, straight descent onto the grasp, close, straight lift (``sagp_batched.robot.motion``):
    the planner solves and checks every waypoint of it, the arm and the floating hand follow it."""

    SECTION = "motion"

    pregrasp_offset_m: float = setting(0.10, above=0)
    lift_height_m: float = setting(0.20, above=0)
    # IK waypoints of the straight descent from the pre-grasp (the grasp itself not counted) and of the lift.
    descent_waypoints: int = setting(8, at_least=1)
    lift_waypoints: int = setting(10, at_least=1)
    # Neighbouring waypoints are ~1-2 cm apart; a larger joint jump means IK switched branch mid-path.
    max_waypoint_joint_step_rad: float = setting(0.3, above=0)
