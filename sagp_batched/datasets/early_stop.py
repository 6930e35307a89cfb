"""When a simulation of a grasp may stop early: its open-loop motions (the lift, the shake) are followed
from one check to the next (``chunks``, ``chunk_ends``), and at each check ``FallWatch`` asks whether
the object has fallen away from the hand, so that nothing later could change the label.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..execution.poses import relative_pose

if TYPE_CHECKING:
    from .protocols import HandEngine


def chunks(steps: int, check_steps: int) -> list[int]:
    """``steps`` cut into runs of ``check_steps`` (the last shorter): the steps between two checks."""
    return [min(check_steps, steps - done) for done in range(0, steps, check_steps)]


def chunk_ends(steps: int, checkpoints: set[int], check_steps: int) -> list[int]:
    """The steps (1-based) a motion of ``steps`` stops at to be checked: its ``checkpoints`` and every ``check_steps``-th."""
    return sorted(checkpoints | set(range(check_steps, steps + 1, check_steps)) | {steps})


class FallWatch:
    """Whether the object has fallen away from the hand: out of contact with every part of it, its
    centre of mass further than ``distance_m`` from where the hand held it (in the hand's frame, as the
    close left it) and no higher than at the check before, at two checks in a row. From there it falls
    freely (or lies on the table): no later step of the lift or the shake, whose strokes are shorter
    than ``distance_m``, brings it back between the fingers, so the grasp is dropped whatever follows.
    ``distance_m`` 0: never (every simulation runs to its end)."""

    def __init__(self, engine: HandEngine, distance_m: float):
        self.engine, self.distance_m = engine, distance_m
        self.held_at = np.asarray(relative_pose(engine.hand_pose(), engine.object_pose())[0])
        self.previous_z: float | None = None
        self.apart_before = False

    def seen(self) -> bool:
        """Whether the object has fallen away by now, this check and the one before it (read from the engine's last step)."""
        if self.distance_m <= 0.0:
            return False
        body = self.engine.object_pose()
        z, previous_z = float(body[0][2]), self.previous_z
        self.previous_z = z
        apart = (previous_z is not None and z <= previous_z and not self.engine.hand_touching()
                 and np.linalg.norm(np.asarray(relative_pose(self.engine.hand_pose(), body)[0]) - self.held_at) > self.distance_m)
        seen, self.apart_before = apart and self.apart_before, apart
        return seen
