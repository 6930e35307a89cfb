"""Label fidelity: how far a hand-mode label can be trusted, object by object.

The same object-frame grasps (planned all around the object, as the ``floating`` dataset plans them) are
labelled several times by ``labelling.label_object_grasps``, and the benchmark asks of the labels what a
learner assumes of them:

- hull fidelity: the collision hulls simulation runs on against the mesh the grasps are tested on (an
  imported object's figures from its import; a set that ships its own hulls, measured here);
- resting-pose stability: the same grasps, the object settled in a second resting pose (or, with one, a
  second position and yaw on the table) should be labelled alike where both are simulated;
- re-simulation: labelling the same grasps again must give the same labels, and the share of grasps whose
  perturbed simulations all agreed says how far a label hangs on millimetres;
- protocol agreement: ``floating`` against ``tabletop`` for the grasps both simulate;
- designed grasps whose outcomes are known by construction (``designed_grasps``), in both protocols;
- labels per second per core in each protocol, and the share of grasps geometry decided unsimulated.

Only grasps both sides simulated are compared: a collision geometry decides at one placement (the hand
through the table) says nothing about the grasp's hold.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..config import Config
from ..description_files import UrdfGeometry, read_urdf_document, urdf_file_path
from ..grasps import GraspPoses
from ..seeds import capture_trial
from ..world.mesh_settings import MeshImportSettings
from ..world.objects import ObjectSet, ObjectSpec
from .designed_grasps import designed_grasps

# A few of the embedded YCB set: a cavity and a handle, a thin box, a cylinder.
DEFAULT_OBJECTS = ("025_mug", "003_cracker_box", "005_tomato_soup_can")


# -- hull fidelity ---------------------------------------------------------------------------------------
def _geometry_parts(geometry: UrdfGeometry, urdf_path: Path) -> list:
    import trimesh

    if geometry.shape == "mesh":
        loaded = trimesh.load(urdf_file_path(urdf_path, geometry.filename), force="mesh")
        loaded.apply_scale(list(geometry.scale))
        # A decomposition is written as one file of disjoint hulls: each connected body is one of them.
        return list(loaded.split(only_watertight=False))
    if geometry.shape == "box":
        return [trimesh.creation.box(list(geometry.size))]
    if geometry.shape == "cylinder":
        return [trimesh.creation.cylinder(*geometry.size)]
    if geometry.shape == "sphere":
        return [trimesh.creation.icosphere(radius=geometry.size[0])]
    return []


def collision_hulls_link(spec: ObjectSpec) -> list:
    """The object's collision hulls as ``trimesh.Trimesh`` convex hulls in its link frame: every ``<collision>`` of
    its URDF, a mesh split into its bodies, moved by the collision's origin and scale. A flat body holds no volume
    and is left out."""
    from scipy.spatial import QhullError

    urdf_path = Path(spec.urdf_path)
    hulls = []
    collisions = (collision for link in read_urdf_document(urdf_path).links for collision in link.collisions)
    for collision in collisions:
        for part in _geometry_parts(collision, urdf_path):
            part.apply_transform(collision.origin)
            try:
                hull = part.convex_hull
            except QhullError:
                continue
            if hull.volume > 0:
                hulls.append(hull)
    return hulls


def object_hull_fidelity(spec: ObjectSpec, settings: MeshImportSettings) -> dict[str, Any]:
    """The hulls' union volume over the mesh's and their furthest stray outside it, judged against ``settings``'
    bounds: an imported object's own figures, else measured on its visual mesh and URDF collision hulls."""
    record = spec.import_record
    if record is not None:
        return {"source": "import", **record.fidelity_summary()}
    from ..datasets.grasp_geometry import object_mesh_link
    from ..world.hull_fidelity import fidelity_issues, hull_fidelity

    hulls = collision_hulls_link(spec)
    if not hulls:
        return {"source": "measured", "volume_ratio": None, "max_distance_m": None, "hulls": 0, "ok": False,
                "issues": ["its URDF has no collision geometry with volume"]}
    fidelity = hull_fidelity(object_mesh_link(spec), hulls)
    issues = fidelity_issues(fidelity.volume_ratio, fidelity.max_hull_to_mesh_distance_m, fidelity.mesh_volume_from,
                             settings.max_hull_volume_ratio, settings.max_hull_distance_m)
    return {"source": "measured", "volume_ratio": fidelity.volume_ratio, "max_distance_m": fidelity.max_hull_to_mesh_distance_m,
            "hulls": len(hulls), "ok": not issues, "issues": issues}


# -- grasps and labels -------------------------------------------------------------------------------------
def planning_config(config: Config) -> Config:
    """``config`` planning as the ``floating`` dataset plans: one capture, grasps drawn from every direction."""
    dataset = dataclasses.replace(config.dataset, mode="hand", protocol="floating", captures_per_object=1)
    return dataclasses.replace(config, dataset=dataset)


def plan_grasps(config: Config, objects: ObjectSet, object_ids: Sequence[str], n_grasps: int) -> dict[str, GraspPoses | str]:
    """Per object, ``n_grasps`` object-frame grasps planned all around it, or why its capture gave none."""
    from ..datasets.object_labeller import ObjectLabeller

    labeller = ObjectLabeller(planning_config(config), objects)
    planned: dict[str, GraspPoses | str] = {}
    try:
        for object_id in object_ids:
            plan = labeller.plan_object(object_id, n_grasps)
            if not plan.poses:
                planned[object_id] = "; ".join(plan.skipped_poses) or "no grasp planned"
                continue
            pose = plan.poses[0]
            planned[object_id] = pose.candidates.transform(pose.object_from_world, "object").poses()
    finally:
        labeller.close()
    return planned


def _timed_labels(spec: ObjectSpec, poses: GraspPoses, widths: np.ndarray, protocol: str, config: Config, placement) -> tuple[list, float]:
    from ..datasets.labelling import label_object_grasps

    start = time.perf_counter()
    labels = label_object_grasps(spec, poses, widths, protocol, config, placement=placement)
    return labels, time.perf_counter() - start


def _second_capture(spec: ObjectSpec, config: Config) -> tuple[int, int, str]:
    """Trial and resting pose of the dataset's second capture: the next resting pose where the object lists
    several, else only a fresh position and yaw."""
    trial = capture_trial(config, 1)
    if len(spec.resting_poses) >= 2:
        return trial, 1, "resting poses 0 and 1"
    return trial, 0, f"trials {capture_trial(config, 0)} and {trial} (one resting pose)"


def held_agreement(first: Sequence, second: Sequence) -> dict[str, Any]:
    """How often two labellings of the same grasps agree on held, over the grasps both simulated and tested
    (a diverged simulation, ``GraspLabel.untested``, is no label)."""
    from ..datasets.agreement import cohen_kappa

    both = [(a.held, b.held) for a, b in zip(first, second) if a.simulated and b.simulated and not a.untested and not b.untested]
    a_held = np.array([a for a, _ in both], dtype=bool)
    b_held = np.array([b for _, b in both], dtype=bool)
    agree = int((a_held == b_held).sum())
    return {"n": len(both), "agree": agree, "agreement": agree / len(both) if both else None,
            "kappa": cohen_kappa(a_held, b_held), "held": [int(a_held.sum()), int(b_held.sum())]}


def _unanimous(labels: Sequence) -> dict[str, Any]:
    """Of the simulated grasps, how many had every perturbed simulation agree (None where each was simulated once)."""
    fractions = [label.held_fraction for label in labels if label.simulated]
    if not fractions or any(f is None for f in fractions):
        return {"n": len(fractions), "unanimous": None, "share": None}
    unanimous = sum(f in (0.0, 1.0) for f in fractions)
    return {"n": len(fractions), "unanimous": unanimous, "share": unanimous / len(fractions)}


def _speed(labels: Sequence, seconds: float) -> dict[str, Any]:
    simulated = sum(label.simulated for label in labels)
    return {"grasps": len(labels), "simulated": simulated, "seconds": seconds,
            "labels_per_s_per_core": simulated / seconds if simulated and seconds > 0 else None,
            "geometry_share": (len(labels) - simulated) / len(labels) if labels else None}


def object_label_fidelity(spec: ObjectSpec, poses: GraspPoses, config: Config) -> dict[str, Any]:
    """Resting-pose and re-simulation stability, protocol agreement and speed of ``poses`` (object frame) on ``spec``."""
    from ..datasets.grasp_geometry import contact_widths, object_surface
    from ..datasets.labelling import FloatingPlacement, tabletop_placement
    from ..robot.description import robot_of

    # Measured once, outside the timed labelling: the widths only check a grasp, the hand closes fully.
    widths = contact_widths(object_surface(spec), poses, robot_of(config).gripper.open_width_m)
    first = tabletop_placement(spec, config, resting_pose=0, trial=capture_trial(config, 0))
    trial, resting_pose, placements = _second_capture(spec, config)
    second = tabletop_placement(spec, config, resting_pose=resting_pose, trial=trial)
    tabletop, tabletop_s = _timed_labels(spec, poses, widths, "tabletop", config, first)
    again, _ = _timed_labels(spec, poses, widths, "tabletop", config, first)
    moved, _ = _timed_labels(spec, poses, widths, "tabletop", config, second)
    floating, floating_s = _timed_labels(spec, poses, widths, "floating", config, FloatingPlacement(spec))
    return {
        "grasps": len(poses),
        "resting_stability": {"placements": placements, **held_agreement(tabletop, moved)},
        "resimulation": {"grasps": len(poses), "differing": sum(a != b for a, b in zip(tabletop, again)),
                         "held_differing": sum(a.held != b.held for a, b in zip(tabletop, again)),
                         "unanimous": {"tabletop": _unanimous(tabletop), "floating": _unanimous(floating)}},
        "protocol_agreement": held_agreement(tabletop, floating),
        "speed": {"tabletop": _speed(tabletop, tabletop_s), "floating": _speed(floating, floating_s)},
    }


# -- the benchmark -----------------------------------------------------------------------------------------
def label_fidelity(config: Config, objects: ObjectSet, object_ids: Sequence[str], n_grasps: int, settings: MeshImportSettings,
                   note: Callable[[str], None] = print) -> dict[str, Any]:
    """Every figure of the module for ``object_ids``, ``n_grasps`` planned grasps each, and the designed box."""
    rows = []
    planned = plan_grasps(config, objects, object_ids, n_grasps)
    for object_id in object_ids:
        spec = objects.get(object_id)
        row: dict[str, Any] = {"object": object_id, "hull_fidelity": object_hull_fidelity(spec, settings)}
        poses = planned[object_id]
        if isinstance(poses, str):
            row["skipped"] = poses
        else:
            row.update(object_label_fidelity(spec, poses, config))
        rows.append(row)
        note(f"{object_id}: done")
    return {"objects": rows, "designed": designed_grasps(config, settings.cache_dir),
            "settings": {"grasps_per_object": n_grasps, "perturbed_simulations": config.labelling.perturbed_simulations,
                         "max_hull_volume_ratio": settings.max_hull_volume_ratio, "max_hull_distance_m": settings.max_hull_distance_m}}


# -- the report --------------------------------------------------------------------------------------------
def _share(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.0f} %"


def _rate(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def _pooled(rows: list[dict[str, Any]], section: str) -> tuple[int, int]:
    return sum(row[section]["agree"] for row in rows), sum(row[section]["n"] for row in rows)


def _hull_cells(hull: dict[str, Any]) -> list[str]:
    ratio = "-" if hull["volume_ratio"] is None else f"{hull['volume_ratio']:.2f}"
    stray = "-" if hull["max_distance_m"] is None else f"{hull['max_distance_m'] * 1000:.1f}"
    return [f"{ratio} ({hull['source']})", stray, "ok" if hull["ok"] else "**past bound**"]


def _object_cells(row: dict[str, Any]) -> list[str]:
    from ..statistics import count_and_rate

    if "skipped" in row:
        return [f"skipped: {row['skipped']}"] + ["-"] * 7
    unanimous = row["resimulation"]["unanimous"]
    speed = row["speed"]
    kappa = row["protocol_agreement"]["kappa"]
    return [
        str(row["grasps"]),
        count_and_rate(row["resting_stability"]["agree"], row["resting_stability"]["n"]),
        f"{row['resimulation']['differing']}/{row['resimulation']['grasps']}",
        f"{_share(unanimous['tabletop']['share'])} / {_share(unanimous['floating']['share'])}",
        count_and_rate(row["protocol_agreement"]["agree"], row["protocol_agreement"]["n"]),
        "-" if kappa is None else f"{kappa:.2f}",
        f"{_share(speed['tabletop']['geometry_share'])} / {_share(speed['floating']['geometry_share'])}",
        f"{_rate(speed['tabletop']['labels_per_s_per_core'])} / {_rate(speed['floating']['labels_per_s_per_core'])}",
    ]


def fidelity_markdown(report: dict[str, Any]) -> str:
    """The benchmark's figures as a markdown table, one row an object, with the pooled agreements and the designed grasps."""
    from ..statistics import count_and_rate

    settings, rows = report["settings"], report["objects"]
    lines = [
        "# Label fidelity", "",
        "| object | hulls / mesh volume | hull stray (mm) | hulls | grasps | resting-pose agreement | re-simulation differing "
        "| unanimous (tabletop / floating) | floating vs tabletop | kappa | geometry-decided (tabletop / floating) "
        "| labels/s per core (tabletop / floating) |",
        "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        lines.append("| " + " | ".join([row["object"], *_hull_cells(row["hull_fidelity"]), *_object_cells(row)]) + " |")
    done = [row for row in rows if "skipped" not in row]
    if len(done) > 1:
        lines.append(f"| all | | | | {sum(r['grasps'] for r in done)} | {count_and_rate(*_pooled(done, 'resting_stability'))} "
                     f"| {sum(r['resimulation']['differing'] for r in done)}/{sum(r['grasps'] for r in done)} | "
                     f"| {count_and_rate(*_pooled(done, 'protocol_agreement'))} | | | |")
    designed = report["designed"]
    lines += [
        "", "Designed grasps (across a box: held; beside it: dropped; the palm in it and across a ball too wide for the opening: collisions): "
        + ", ".join(f"{protocol} {result['correct']}/{result['of']}" for protocol, result in designed.items()) + ".",
        "", f"Grasps: {settings['grasps_per_object']} an object, planned all around it (the floating dataset's planning), "
        f"each label {settings['perturbed_simulations']} simulation(s). Agreements count the grasps both labellings simulated; "
        "the resting-pose one compares the dataset's first two captures on the table. Hull bounds: volume ratio "
        f"{settings['max_hull_volume_ratio']:.2f}, stray {settings['max_hull_distance_m'] * 1000:.1f} mm.",
    ]
    lines += [f"- {row['object']}: {issue}" for row in rows for issue in row["hull_fidelity"]["issues"]]
    return "\n".join(lines) + "\n"
