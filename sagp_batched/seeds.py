"""Every seed derived from the configured ones (``scene.seed_base``, ``planner.seed``, ``dataset.seed``).

A study trial and a dataset capture draw all their randomness from these derivations, so a record's
``seed`` and ``candidate_seed``, a run's provenance and a dataset's captures name the draws exactly;
changing one of them changes what earlier runs and datasets hold, so each stays as first published.
The benchmarks' fixed seeds (``benchmark.py``) are local choices, not derived, and stay there.
"""
from __future__ import annotations

from .config import Config


def scene_seed(config: Config, trial: int) -> int:
    """The scene's draws for ``trial``: the target's position and yaw, the distractors' count and poses."""
    return config.scene.seed_base + trial


def ik_restart_seed(config: Config, trial: int) -> int:
    """Execution's random IK restarts in the scene of ``trial``: the scene's own seed, since both have
    been drawn from it from the start and recorded attempts depend on it."""
    return scene_seed(config, trial)


def candidate_seed(config: Config, trial: int) -> int:
    """The planner's draws (contact pairs, occupancy subset) for study trial ``trial``: fixed per trial so
    every method ranks the same candidate set, and offset by ``planner.seed`` to redraw the candidates
    of the same scenes."""
    return config.planner.seed + scene_seed(config, trial)


def capture_trial(config: Config, pose_index: int) -> int:
    """The scene trial of dataset capture ``pose_index`` of an object: its placement is drawn from
    ``scene_seed(config, capture_trial(config, pose_index))``."""
    return config.dataset.seed + pose_index


def labelling_seed(config: Config, pose_index: int) -> int:
    """The grasp draws of dataset capture ``pose_index``: the planner's sampling and the pick of grasps
    within each verdict (``verdicts.classify_grasps``)."""
    return config.dataset.seed + pose_index
