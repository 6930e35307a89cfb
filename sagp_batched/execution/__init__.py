"""Executing grasps in PyBullet: the pick sequence and its judgement (``pick``), the joints an
attempt runs (``arm_joints``: the planner's path, checked in PyBullet, or PyBullet's own IK where
there is none), the poses' differences it records (``poses``) and the opt-in shake after the lift
(``shake``). What an attempt records is ``sagp_batched.attempt``."""
from typing import TYPE_CHECKING

from ..lazy_exports import lazy_exports

# Imported on first use, so that the PyBullet-free parts (``poses``, ``shake``, ``held``) load without PyBullet.
if TYPE_CHECKING:
    from .pick import checked_grasp, execute_grasp, execute_ranked

__all__ = [
    "checked_grasp", "execute_grasp", "execute_ranked",
]
__getattr__ = lazy_exports(__name__, __file__)
