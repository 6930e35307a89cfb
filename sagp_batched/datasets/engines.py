"""The hand engines a label can be simulated by, looked up by name: each builds its world and steps it,
the protocols (``protocols``) decide the rest, so a label names both."""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..config import Config
from ..config.run import LABEL_ENGINES

if TYPE_CHECKING:
    from .protocols import HandEngine

ENGINES: tuple[str, ...] = LABEL_ENGINES


def check_engine(name: str) -> None:
    """Raises ``ValueError`` naming ``name`` where no engine has it."""
    if name not in ENGINES:
        raise ValueError(f"engine must be one of {', '.join(ENGINES)}, got {name!r}")


def hand_engine(name: str, config: Config) -> "HandEngine":
    """A new engine ``name`` ("pybullet" or "mujoco"), a context manager that frees its worlds on exit."""
    check_engine(name)
    if name == "mujoco":
        from .mujoco_hand import MuJoCoHand

        return MuJoCoHand(config)
    from .pybullet_hand import PyBulletHand

    return PyBulletHand(config)
