"""Gripper agreement: the same grasps labelled with each gripper, and how far the grippers' labels agree.

The grasps are planned all around each object as the ``floating`` dataset plans them (``label_fidelity``'s
planning), for the gripper with the narrowest opening among those compared, so every one of them can close on
each grasp's contacts; each gripper then holds its own grasp target at the same poses and closes with the
configured grip force, in the ``floating`` protocol and one engine. Per gripper: the share of the grasps it
simulated that it held (a grasp its open hand already intersects is a collision, decided by geometry, and left
out); per pair of grippers: agreement and Cohen's kappa on the grasps both simulated.
"""
from __future__ import annotations

import itertools
from typing import Any, Callable, Sequence

from ..config import Config
from ..datasets.grasp_geometry import contact_widths, object_surface
from ..datasets.labelling import FloatingPlacement, label_object_grasps
from ..robot.gripper_description import load_gripper
from ..world.objects import ObjectSet
from .label_fidelity import held_agreement, plan_grasps


def gripper_agreement(config: Config, objects: ObjectSet, object_ids: Sequence[str], n_grasps: int, grippers: Sequence[str],
                      engine: str = "mujoco", note: Callable[[str], None] = print) -> dict[str, Any]:
    """``n_grasps`` grasps of each of ``object_ids``, planned for the narrowest of ``grippers``, labelled with each of them."""
    narrowest = min(grippers, key=lambda name: load_gripper(name).open_width_m)
    planned = plan_grasps(config.override("planner", gripper=narrowest), objects, object_ids, n_grasps)
    labels: dict[str, list] = {name: [] for name in grippers}
    labelled_objects = []
    for object_id, poses in planned.items():
        if isinstance(poses, str):
            note(f"{object_id}: skipped, {poses}")
            continue
        spec = objects.get(object_id)
        labelled_objects.append(object_id)
        for name in grippers:
            gripper_config = config.override("planner", gripper=name)
            widths = contact_widths(object_surface(spec), poses, load_gripper(name).open_width_m)
            labels[name] += label_object_grasps(spec, poses, widths, "floating", gripper_config, placement=FloatingPlacement(spec), engine=engine)
        note(f"{object_id}: labelled with {', '.join(grippers)}")
    per_gripper = {}
    for name, group in labels.items():
        simulated = [label for label in group if label.simulated]
        held = sum(label.held for label in simulated)
        per_gripper[name] = {"grasps": len(group), "simulated": len(simulated), "held": held,
                             "held_share": held / len(simulated) if simulated else None,
                             "collisions": len(group) - len(simulated)}
    pairs = {f"{a}/{b}": held_agreement(labels[a], labels[b]) for a, b in itertools.combinations(grippers, 2)}
    return {"objects": labelled_objects, "grasps_per_object": n_grasps, "planned_for": narrowest, "engine": engine,
            "protocol": "floating", "grippers": per_gripper, "pairs": pairs}


def gripper_agreement_markdown(report: dict[str, Any]) -> str:
    """The report as two markdown tables: each gripper's held share, each pair's agreement."""
    lines = [
        "# Gripper agreement", "",
        f"Objects: {', '.join(report['objects'])}; {report['grasps_per_object']} grasps each, planned for {report['planned_for']}; "
        f"{report['protocol']} protocol in {report['engine']}.", "",
        "| gripper | grasps | simulated | held | held share | collisions (geometry) |", "|---|---:|---:|---:|---:|---:|",
    ]
    for name, row in report["grippers"].items():
        share = "-" if row["held_share"] is None else f"{100 * row['held_share']:.1f} %"
        lines.append(f"| {name} | {row['grasps']} | {row['simulated']} | {row['held']} | {share} | {row['collisions']} |")
    lines += ["", "| grippers | both simulated | agreement | kappa |", "|---|---:|---:|---:|"]
    for pair, row in report["pairs"].items():
        share = "-" if row["agreement"] is None else f"{100 * row['agreement']:.1f} %"
        kappa = "-" if row["kappa"] is None else f"{row['kappa']:.2f}"
        lines.append(f"| {pair} | {row['n']} | {share} | {kappa} |")
    return "\n".join(lines) + "\n"
