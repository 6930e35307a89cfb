"""A fixed set of planned grasps, and what a change to the labelling does to their labels.

The set is planned once (``plan_grasps``: all around each object, as the ``floating`` dataset plans)
and saved, so every labelling of it labels the same poses whatever the planner later does. Labelling it
(``label_fixed_set``) in an engine and protocol gives one record per grasp and the CPU seconds it took;
``changed_labels`` counts the grasps two labellings label differently: held or dropped, and the failure
(reason and phase) of the dropped ones.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from ..config import Config
from ..grasps import GraspPoses
from ..world.objects import ObjectSet
from .label_fidelity import plan_grasps

# Boxes, cans, bottles, a mug, a banana and a drill: the shapes whose labels the engines find hardest and easiest.
FIXED_SET_OBJECTS = ("025_mug", "003_cracker_box", "005_tomato_soup_can", "006_mustard_bottle", "021_bleach_cleanser", "011_banana",
                     "035_power_drill", "010_potted_meat_can")

def build_fixed_set(config: Config, objects: ObjectSet, object_ids: Sequence[str], grasps_per_object: int, path: Path) -> dict[str, int]:
    """Plan ``grasps_per_object`` grasps on each object and save them (object-frame poses) to ``path``
    (.npz); per object, how many were planned (an object whose capture gives none is left out)."""
    planned = {object_id: poses for object_id, poses in plan_grasps(config, objects, object_ids, grasps_per_object).items()
               if not isinstance(poses, str)}
    if not planned:
        raise ValueError(f"no grasp planned on any of {', '.join(object_ids)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, object_ids=np.array([object_id for object_id, poses in planned.items() for _ in range(len(poses))]),
             positions=np.concatenate([poses.position.numpy() for poses in planned.values()]),
             rotations=np.concatenate([poses.rotation.numpy() for poses in planned.values()]))
    return {object_id: len(poses) for object_id, poses in planned.items()}


def load_fixed_set(path: Path) -> dict[str, GraspPoses]:
    """Per object, in the saved order, its object-frame grasps from ``build_fixed_set``'s file."""
    try:
        saved = np.load(path)
        object_ids, positions, rotations = saved["object_ids"], saved["positions"], saved["rotations"]
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"{path} is not a fixed grasp set: {exc}") from exc
    return {str(object_id): GraspPoses(torch.as_tensor(positions[object_ids == object_id]), torch.as_tensor(rotations[object_ids == object_id]), "object")
            for object_id in dict.fromkeys(object_ids.tolist())}


def label_fixed_set(config: Config, objects: ObjectSet, grasp_set: dict[str, GraspPoses], engine: str,
                    protocol: str = "floating") -> tuple[list[dict[str, Any]], float]:
    """One record per grasp of the set, labelled by ``engine`` in ``protocol``, and the CPU seconds the
    labelling took (the process's own time: other work shares the machine)."""
    from ..datasets.labelling import label_object_grasps

    records = []
    start = time.process_time()
    for object_id, poses in grasp_set.items():
        for label in label_object_grasps(objects.get(object_id), poses, None, protocol, config, engine=engine):
            records.append({"object": object_id, "held": label.held, "failure_reason": label.failure_reason, "failed_at": label.failed_at,
                            "simulated": label.simulated, "held_fraction": label.held_fraction,
                            "shaking_linear_m": label.object_motion_during_shaking_linear,
                            "shaking_angular_rad": label.object_motion_during_shaking_angular})
    return records, time.process_time() - start


def changed_labels(reference: Sequence[dict[str, Any]], labels: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """How many grasps ``labels`` labels otherwise than ``reference`` (the same set, in order): held
    or dropped (each way), and among those both drop, the failure's reason or phase."""
    if len(reference) != len(labels) or any(a["object"] != b["object"] for a, b in zip(reference, labels)):
        raise ValueError("the two labellings are not of the same grasp set")
    pairs = list(zip(reference, labels))
    return {
        "grasps": len(pairs),
        "simulated": sum(a["simulated"] for a, _ in pairs),
        "held_changed": sum(a["held"] != b["held"] for a, b in pairs),
        "now_held": sum(b["held"] and not a["held"] for a, b in pairs),
        "now_dropped": sum(a["held"] and not b["held"] for a, b in pairs),
        "failure_changed": sum((a["failure_reason"], a["failed_at"]) != (b["failure_reason"], b["failed_at"])
                               for a, b in pairs if not a["held"] and not b["held"]),
    }
