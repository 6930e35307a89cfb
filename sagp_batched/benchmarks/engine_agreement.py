"""Engine agreement: how far MuJoCo's hand-mode labels agree with PyBullet's on the same grasps, and what
each engine costs.

The grasps are planned all around each object as the ``floating`` dataset plans them (``label_fidelity``'s
planning); each is labelled by PyBullet once and by MuJoCo once per settings variant (overrides of
``[labelling.mujoco]``), in both protocols, the tabletop ones on the object settled where the study's scene
leaves it. Per variant: the share of grasps both engines simulated that they label alike and Cohen's kappa,
the designed grasps (held, dropped, two collisions) labelled as designed, and simulations and labels
per second per core (the process's CPU time). A label is ``perturbed_simulations`` simulations; sims/s
counts that many for every simulated label (a perturbed pose geometry rules out is counted too: a slight
overcount).
"""
from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, Sequence

from ..config import Config
from ..config.run import LABEL_PROTOCOLS
from ..datasets.labelling import label_object_grasps
from ..seeds import capture_trial
from ..world.objects import ObjectSet
from .designed_grasps import DESIGNED_OUTCOMES, designed_grasps
from .label_fidelity import held_agreement, plan_grasps

DEFAULT_OBJECTS = ("025_mug", "003_cracker_box", "005_tomato_soup_can", "006_mustard_bottle")
DESIGNED = len(DESIGNED_OUTCOMES)


def mujoco_variant(config: Config, overrides: dict[str, Any]) -> Config:
    """``config`` with ``[labelling.mujoco]`` overridden (checked as a profile's values are)."""
    return config.override("labelling", mujoco=overrides)


def _label_all(grasps: dict[str, tuple], config: Config, engine: str) -> tuple[dict[tuple[str, str], list], float]:
    """Every object's grasps labelled by ``engine`` in both protocols, and the CPU seconds it took: on a
    machine other work shares, the process's own time is what a core spends on it."""
    labels = {}
    start = time.process_time()
    for object_id, (spec, poses, widths, placements) in grasps.items():
        for protocol in LABEL_PROTOCOLS:
            labels[object_id, protocol] = label_object_grasps(spec, poses, widths, protocol, config, placement=placements[protocol], engine=engine)
    return labels, time.process_time() - start


def _speed(labels: dict[tuple[str, str], list], seconds: float, config: Config) -> dict[str, Any]:
    simulated = sum(label.simulated for group in labels.values() for label in group)
    simulations = simulated * config.labelling.perturbed_simulations
    return {"simulated_labels": simulated, "seconds": seconds, "labels_per_s_per_core": simulated / seconds if seconds > 0 else None,
            "simulations_per_s_per_core": simulations / seconds if seconds > 0 else None}


def _pooled(reference: dict[tuple[str, str], list], labels: dict[tuple[str, str], list]) -> dict[str, Any]:
    """Agreement on held over every object and protocol, and per protocol."""
    keys = sorted(reference)
    result = {"all": held_agreement([l for k in keys for l in reference[k]], [l for k in keys for l in labels[k]])}
    for protocol in LABEL_PROTOCOLS:
        mine = [k for k in keys if k[1] == protocol]
        result[protocol] = held_agreement([l for k in mine for l in reference[k]], [l for k in mine for l in labels[k]])
    return result


def _grasps_to_label(config: Config, objects: ObjectSet, object_ids: Sequence[str], n_grasps: int,
                     note: Callable[[str], None]) -> dict[str, tuple]:
    """Per object: its spec, planned grasps, their widths and the placement of each protocol."""
    from ..datasets.grasp_geometry import contact_widths, object_surface
    from ..datasets.labelling import FloatingPlacement, tabletop_placement
    from ..robot.description import robot_of

    grasps = {}
    for object_id, poses in plan_grasps(config, objects, object_ids, n_grasps).items():
        if isinstance(poses, str):
            note(f"{object_id}: skipped, {poses}")
            continue
        spec = objects.get(object_id)
        widths = contact_widths(object_surface(spec), poses, robot_of(config).gripper.open_width_m)
        placements = {"tabletop": tabletop_placement(spec, config, trial=capture_trial(config, 0)), "floating": FloatingPlacement(spec)}
        grasps[object_id] = (spec, poses, widths, placements)
    return grasps


def engine_agreement(config: Config, objects: ObjectSet, object_ids: Sequence[str], n_grasps: int,
                     variants: Sequence[dict[str, Any]] = ({},), note: Callable[[str], None] = print) -> dict[str, Any]:
    """PyBullet's labels and each MuJoCo variant's (``[labelling.mujoco]`` overrides of ``config``) on
    ``n_grasps`` planned grasps of each of ``object_ids``, compared, with each engine's speed and designed grasps."""
    grasps = _grasps_to_label(config, objects, object_ids, n_grasps, note)
    reference, seconds = _label_all(grasps, config, "pybullet")
    note(f"pybullet: {seconds:.1f} s")
    report: dict[str, Any] = {
        "objects": list(grasps), "grasps_per_object": n_grasps, "perturbed_simulations": config.labelling.perturbed_simulations,
        "pybullet": {"speed": _speed(reference, seconds, config), "designed": _designed_correct(config, "pybullet"),
                     "held": {f"{k[0]}/{k[1]}": sum(l.held for l in v) for k, v in reference.items()}},
        "variants": [],
    }
    for overrides in variants:
        variant = mujoco_variant(config, overrides)
        labels, seconds = _label_all(grasps, variant, "mujoco")
        row = {"overrides": overrides, "settings": dataclasses.asdict(variant.labelling.mujoco), "agreement": _pooled(reference, labels),
               "designed": _designed_correct(variant, "mujoco"), "speed": _speed(labels, seconds, variant)}
        report["variants"].append(row)
        note(f"mujoco {overrides}: {variant_cells(row)}")
    return report


def _designed_correct(config: Config, engine: str) -> dict[str, int]:
    return {protocol: result["correct"] for protocol, result in designed_grasps(config, engine=engine).items()}


def variant_cells(row: dict[str, Any]) -> str:
    """One variant's figures in one line: agreement, kappa, designed grasps correct, sims/s."""
    agreement, designed, speed = row["agreement"]["all"], row["designed"], row["speed"]
    kappa = "-" if agreement["kappa"] is None else f"{agreement['kappa']:.2f}"
    share = "-" if agreement["agreement"] is None else f"{100 * agreement['agreement']:.1f} %"
    return (f"agreement {share} ({agreement['agree']}/{agreement['n']}), kappa {kappa}, designed "
            f"{designed['tabletop']}/{DESIGNED} tabletop {designed['floating']}/{DESIGNED} floating, {speed['simulations_per_s_per_core']:.1f} sims/s")


def agreement_markdown(report: dict[str, Any]) -> str:
    """The report as a markdown table, one row a MuJoCo variant, PyBullet's figures above it."""
    pybullet = report["pybullet"]
    lines = [
        "# Engine agreement", "",
        f"Objects: {', '.join(report['objects'])}; {report['grasps_per_object']} grasps each, both protocols; "
        f"{report['perturbed_simulations']} simulation(s) a label.", "",
        f"PyBullet: designed grasps {pybullet['designed']['tabletop']}/{DESIGNED} tabletop, {pybullet['designed']['floating']}/{DESIGNED} floating; "
        f"{pybullet['speed']['simulations_per_s_per_core']:.1f} sims/s, {pybullet['speed']['labels_per_s_per_core']:.1f} labels/s per core.", "",
        "| MuJoCo settings (over the profile's) | agreement (tabletop / floating) | kappa | designed (tabletop / floating) | sims/s | labels/s |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for row in report["variants"]:
        agreement, speed = row["agreement"], row["speed"]
        shares = " / ".join("-" if agreement[p]["agreement"] is None else f"{100 * agreement[p]['agreement']:.0f} %" for p in LABEL_PROTOCOLS)
        kappa = "-" if agreement["all"]["kappa"] is None else f"{agreement['all']['kappa']:.2f}"
        overrides = ", ".join(f"{key}={value}" for key, value in row["overrides"].items()) or "profile"
        lines.append(f"| {overrides} | {100 * agreement['all']['agreement']:.1f} % ({shares}) | {kappa} | "
                     f"{row['designed']['tabletop']}/{DESIGNED} / {row['designed']['floating']}/{DESIGNED} | {speed['simulations_per_s_per_core']:.1f} | "
                     f"{speed['labels_per_s_per_core']:.1f} |")
    return "\n".join(lines) + "\n"
