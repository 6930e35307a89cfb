"""Executing grasps in PyBullet: the pick sequence and its judgement (``pick``), the joints an
attempt runs (``arm_joints``: the planner's path, checked in PyBullet, or PyBullet's own IK where
there is none), the poses' differences it records (``poses``) and the opt-in shake after the lift
(``shake``). What an attempt records is ``sagp_batched.attempt``."""
from .pick import checked_grasp, execute_grasp, execute_ranked, object_held

__all__ = ["checked_grasp", "execute_grasp", "execute_ranked", "object_held"]
