"""Executing grasps in PyBullet: the pick sequence and its judgement (``pick``), the joints an
attempt runs (``arm_joints``: the planner's path, checked in PyBullet, or PyBullet's own IK where
there is none), the poses' differences it records (``poses``) and the opt-in shake after the lift
(``shake``). What an attempt records is ``sagp_batched.attempt``."""
from ..lazy_exports import lazy_exports

# Imported on first use, so that the PyBullet-free parts (``poses``, ``shake``, ``held``) load without PyBullet.
_PUBLIC = {"checked_grasp": "pick", "execute_grasp": "pick", "execute_ranked": "pick"}

__all__ = sorted(_PUBLIC)
__getattr__ = lazy_exports(__name__, _PUBLIC)
