"""Grasps whose outcome is known on paper, from the contact model (``execution.contact_model``), labelled by
each engine in each protocol.

Every case is a top-down pinch of an object lying on the table in its link frame (x along its length, z up;
in the floating protocol gravity pulls along the same -z): the grasp's z (approach) is vertical, its y (the
closing axis) and x horizontal. Gravity g and the protocol's peaks act on the object in separate windows: the
lift (``lift_peak_m_s2``, up), the shake along the grasp's x, y and z (``[labelling.shake]``, one axis at a time)
and about them. Two pads each press with the grip force F and friction mu = the pad's factor times the
object's; a linkage's pads, which move along the approach as they close, press with N = F / (1 + mu k d_z)
where the grip's force on the object points along d (k the pads' path slope at the object's width:
``coulomb_slip.PinchGrip``, from the gripper's kinematics; N = F for fingers that slide). A case holds on paper
iff, in every window (``window_loads``),

* sliding: the force the pads' friction must carry in their plane is within ``2 mu N``: ``m (g + a_z)`` along
  the vertical (the largest of the lift's and the shake's z peaks; ``m (a_z - g)`` the other way), ``m sqrt(g^2 +
  a_x^2)`` along x and down, ``m (g + alpha d)`` while turning about the grasp target (d the centre of mass's
  distance from it along x); along the closing axis both pads keep pressing (their drives are force-limited,
  so the object lags the hand rather than loading one pad), which leaves the limit as it is;
* torsion: the torque about the closing axis (the pads' normal) is within the two pads' torsional limits
  (mu N times the torsional radius of the surface the pads press on at the grip force, ``contact_model.patch``:
  exact on a flat face, whose pressure stays uniform): ``m (g + a_z) d``, ``m (g d + a_x h)`` in the x window
  (h its height above them), ``m g d + (I + m r^2) alpha`` while turning about the closing axis (r = |(d, h)|).

Past a threshold an ideal grip does not let go: it lets the object slide (or turn) while the load exceeds
its limit, near the peak, and grips it again as the load falls (``coulomb_slip``: 5.2 mm of slide for a
mass 20 % past the sliding threshold, 1.5 deg of turn for a bar 20 % past the torsion threshold, none
below). So each case's paper answer is that motion over the shake, and an engine answers as the paper does
where it keeps the object in the hand and its motion over the shake (the slide for the mass cases, the turn
for the bar) is nearer the paper's for this case than for the same object on the other side of the
threshold. The threshold answer (whether the grip carries the peak) is reported beside it.

Rotations about the grasp's x and z load the pads by their pressure's spread and by a couple across the
object's width, a few per cent of the limits at these sizes, and are left out. The cases, each either side of
its threshold (``MARGIN``): a box pinched at its centre of mass (mass), a bar pinched ``d`` from it (distance; its
mass keeps sliding at ``BAR_SLIDING_SHARE`` of its limit, so torsion decides), a cylinder pinched across its
axis (its curved side) and along it (its flat ends) (mass).
"""
from __future__ import annotations

import json
import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sagp_batched_kernels.grasp_frames import grasp_rotations

from ..config import Config
from ..config.run import LABEL_PROTOCOLS
from ..datasets.engines import ENGINES
from ..execution.contact_model import ContactSurface, RubberPad, engine_pad, patch
from ..grasps import GraspPoses
from ..robot.description import RobotDescription, robot_of
from ..robot.gripper_description import PAD_FACE_DEPTH_M
from ..robot.hand import load_hand_geometry
from ..world.mesh_settings import MeshImportSettings
from .coulomb_slip import PaperMotion, PinchGrip, coulomb_motion
from .designed_grasps import FINGERTIP_TABLE_CLEARANCE_M

# Each case at its threshold times (1 - MARGIN) and (1 + MARGIN).
MARGIN = 0.2
# The object's friction coefficient (the pads' factor multiplies it): a painted or plastic surface.
OBJECT_FRICTION = 0.3
# The bar's mass uses this share of the pads' sliding limit at the worst acceleration.
BAR_SLIDING_SHARE = 0.15
# Clearances (m): the box and bar this much taller than the pad's face reaches above the grasp target; the
# objects this much narrower than the opening; a resting face this much wider than the object is tall.
PAD_COVER_M, OPENING_SPARE_M, RESTING_SPARE_M = 0.002, 0.012, 0.006
BAR_LENGTH_M, BOX_LENGTH_M = 0.30, 0.10
# A bar is made longer where the pads past its torsion threshold would reach within this of its end.
BAR_END_SPARE_M = 0.01
DOWN = np.array([0.0, 0.0, -1.0])
# A light grip, so the masses at the thresholds are those of hand-sized objects of common densities (the box
# 0.4 kg in 110 cm^3 with the Panda); the gripper's least force where that is more.
ANALYTIC_GRIP_FORCE_N = 10.0
# The lift in 0.6 s: its peak (2.7 m/s^2) a fifth of the shake's, which alone then decides every case.
ANALYTIC_LIFT_STEPS = 144


@dataclass(frozen=True)
class Case:
    """One analytic grasp: the object (a trimesh box or cylinder's dimensions and its mass), the grasp target and
    closing axis in its link frame, the surface the pads press on, and the paper's answers with their numbers:
    whether the grip carries the worst load (``paper_held``) and the ideal grip's motion over the shake
    (``paper_motion``), of which ``measure`` ("slide" or "turn") decides, and that motion for the same object
    on the other side of the threshold (``counterpart_motion``)."""

    name: str
    shape: str  # "box" (extents x, y, z) or "cylinder" (radius, length; axis along x)
    dimensions_m: tuple[float, ...]
    mass_kg: float
    target_m: tuple[float, float, float]
    closing_axis: tuple[float, float, float]
    surface: ContactSurface
    paper_held: bool
    paper_motion: PaperMotion
    measure: str
    counterpart_motion: PaperMotion
    paper: dict[str, float] = field(default_factory=dict)


def analytic_config(config: Config) -> Config:
    """``config`` as the cases label with it: the grip force ``ANALYTIC_GRIP_FORCE_N`` (or the gripper's least),
    one simulation a label (the pose is exact) and the lift slowed to
    ``ANALYTIC_LIFT_STEPS``, so that the shake decides: an object that turns in the grip turns while the label
    measures its motion in the hand."""
    low, _ = robot_of(config).gripper.grip_force_range_n
    config = config.override("execution", gripper_force_n=max(ANALYTIC_GRIP_FORCE_N, low))
    return config.override("labelling", perturbed_simulations=1, hand_lift_steps=ANALYTIC_LIFT_STEPS)


def lift_peak_m_s2(config: Config) -> float:
    """The floating hand's lift, ``lift_height_m`` on a half-cosine in ``hand_lift_steps``: peak (pi / T)^2 h / 2."""
    duration = config.labelling.hand_lift_steps * config.scene.time_step_s
    return (math.pi / duration) ** 2 * config.motion.lift_height_m / 2.0


def window_loads(config: Config, mass_kg: float, inertia_kg_m2: float, offset_x_m: float, height_m: float) -> list[tuple[np.ndarray, float]]:
    """Per window of the lift and the shake, the worst loads on the pads of an object of ``mass_kg`` and moment of
    inertia ``inertia_kg_m2`` about its centre of mass (about the closing axis), its centre of mass ``offset_x_m``
    from the pads along the grasp's x and ``height_m`` above them: the force the grip must give the object in the
    pads' plane (grasp x, grasp z: the approach, down here, so holding it up is negative) and the torque about the
    closing axis."""
    shake = config.labelling.shake
    if shake.linear_with_angular:
        raise ValueError("the analytic cases take the shake one axis at a time ([labelling.shake] linear_with_angular = false)")
    g = abs(config.scene.gravity_m_s2)
    (a_x, _, a_z), (_, alpha_y, _) = shake.linear_peak_acceleration_m_s2, shake.angular_peak_acceleration_rad_s2
    vertical = g + max(a_z, lift_peak_m_s2(config))
    d, h = abs(offset_x_m), abs(height_m)
    turning = (inertia_kg_m2 + mass_kg * (d**2 + h**2)) * alpha_y
    return [(np.array([0.0, -mass_kg * vertical]), mass_kg * vertical * d),
            (np.array([0.0, mass_kg * (a_z - g)]), mass_kg * abs(a_z - g) * d),
            (np.array([mass_kg * a_x, -mass_kg * g]), mass_kg * (g * d + a_x * h)),
            (np.array([mass_kg * alpha_y * h, -mass_kg * (g + alpha_y * d)]), mass_kg * g * d + turning)]


def carried(grip: PinchGrip, torsional_radius_m: float, windows: list[tuple[np.ndarray, float]]) -> dict[str, float]:
    """The window that loads the pads' sliding friction most against its limit, and the one that loads their torsion
    most: {sliding_n, sliding_limit_n, torque_n_m, torsion_limit_n_m}."""
    sliding, torsion = [], []
    for force, torque in windows:
        load = float(np.linalg.norm(force))
        direction = force / load if load > 0.0 else np.zeros(2)
        sliding.append((load, grip.sliding_limit_n(direction)))
        torsion.append((torque, 2.0 * grip.friction * grip.normal_force_n(direction) * torsional_radius_m))
    (load, limit), (torque, torsion_limit) = (max(pairs, key=lambda pair: pair[0] / pair[1]) for pairs in (sliding, torsion))
    return {"sliding_n": load, "sliding_limit_n": limit, "torque_n_m": torque, "torsion_limit_n_m": torsion_limit}


def _pad_geometry(robot: RobotDescription) -> tuple[float, float]:
    """(how far the pad's face reaches above the grasp target, how far the fingertips reach below it), m."""
    hand, pads = load_hand_geometry(robot), robot.gripper.pad_links
    vertices = np.asarray(hand.vertices(pads[:1]))
    inward = np.abs(vertices[:, 1])
    face = vertices[inward <= inward.min() + PAD_FACE_DEPTH_M]
    return float(-face[:, 2].min()), float(np.asarray(hand.vertices(pads))[:, 2].max())


def analytic_cases(config: Config) -> list[Case]:
    """The cases for ``config``'s gripper, grip force and pad model, each either side of its threshold."""
    robot = robot_of(config)
    engine = engine_pad(config.execution, robot)
    pad, force = engine.pad, config.execution.gripper_force_n
    mu = engine.friction_factor * OBJECT_FRICTION
    pad_top, fingertip = _pad_geometry(robot)
    target_height = fingertip + FINGERTIP_TABLE_CLEARANCE_M  # the fingertips clear the table below
    opening = robot.gripper.open_width_m
    cases: list[Case] = []

    def grip_across(width_m: float) -> PinchGrip:
        """The pads' grip on an object ``width_m`` wide along the closing axis, where they stand."""
        return PinchGrip(force, mu, robot.gripper.pad_path_slope(width_m))

    # The box and the bar: tall enough that the pad's face is on their side, resting on a face wider than tall.
    height = 2.0 * max(target_height, pad_top + PAD_COVER_M)
    width = min(height + RESTING_SPARE_M, opening - OPENING_SPARE_M)
    box = (BOX_LENGTH_M, width, height)
    box_inertia = (box[0] ** 2 + box[2] ** 2) / 12.0  # per kg, about the closing axis (y)
    flat = ContactSurface()
    cases += _either_side(config, pad, grip_across(width), "box at its centre of mass", "box", box, (0.0, 0.0, height / 2), (0.0, 1.0, 0.0),
                          flat, "mass", lambda m: (m, window_loads(config, m, m * box_inertia, 0.0, 0.0)), box_inertia)

    # The bar's mass slides at BAR_SLIDING_SHARE of the limit in the vertical window, the worst for sliding.
    vertical_force, _ = window_loads(config, 1.0, 0.0, 0.0, 0.0)[0]
    vertical = float(np.linalg.norm(vertical_force))
    bar_mass = BAR_SLIDING_SHARE * grip_across(width).sliding_limit_n(vertical_force / vertical) / vertical
    length = BAR_LENGTH_M
    while True:  # long enough that the pads stay on it past the threshold (a longer one turns harder in the shake: nearer)
        bar = (length, width, height)
        bar_inertia = (bar[0] ** 2 + bar[2] ** 2) / 12.0
        bar_cases = _either_side(config, pad, grip_across(width), "bar", "box", bar, (0.0, 0.0, height / 2), (0.0, 1.0, 0.0), flat,
                                 "distance", lambda d: (bar_mass, window_loads(config, bar_mass, bar_mass * bar_inertia, d, 0.0)), bar_inertia)
        reach = max(case.target_m[0] for case in bar_cases) + pad.face_m[0] / 2.0
        if reach <= length / 2.0:
            break
        length = 2.0 * (reach + BAR_END_SPARE_M)
    cases += bar_cases

    # The cylinders lie along x; across: pinched on their curved side at the axis' height, their axis along the
    # pad's width; along: pinched on their flat ends, which are narrower than the pad's face where it is small.
    radius = min(max(target_height, 0.015), (opening - OPENING_SPARE_M) / 2.0)
    across = (radius, 4.0 * radius + 0.02)
    across_inertia = (3.0 * radius**2 + across[1] ** 2) / 12.0
    curved = ContactSurface(curvature_radius_m=radius, cylinder_axis="width")
    cases += _either_side(config, pad, grip_across(2.0 * radius), "cylinder across its axis", "cylinder", across, (0.0, 0.0, radius),
                          (0.0, 1.0, 0.0), curved, "mass", lambda m: (m, window_loads(config, m, m * across_inertia, 0.0, 0.0)), across_inertia)
    along = (radius, min(opening - OPENING_SPARE_M, 2.0 * radius + 2.0 * RESTING_SPARE_M + 0.01))
    ends = ContactSurface(face_radius_m=radius)
    along_inertia = radius**2 / 2.0  # about its own axis, which is the closing axis
    cases += _either_side(config, pad, grip_across(along[1]), "cylinder along its axis", "cylinder", along, (0.0, 0.0, radius),
                          (1.0, 0.0, 0.0), ends, "mass", lambda m: (m, window_loads(config, m, m * along_inertia, 0.0, 0.0)), along_inertia)
    return cases


def _either_side(config: Config, pad: RubberPad, grip: PinchGrip, name: str, shape: str, dimensions: tuple[float, ...],
                 target: tuple[float, float, float], closing: tuple[float, float, float], surface: ContactSurface, vary: str, loads,
                 inertia_per_kg: float) -> list[Case]:
    """The case either side of the threshold of the mass or the distance (``vary``) for ``pad`` gripping with
    ``grip``; ``loads(value)`` the mass and its ``window_loads``; ``inertia_per_kg`` the object's moment of inertia
    about the closing axis per kg of its mass."""
    pressed = patch(pad, grip.force_n, surface)

    def carried_at(value: float) -> dict[str, float]:
        return carried(grip, pressed.torsional_radius_m, loads(value)[1])

    measure, limit = ("sliding_n", "sliding_limit_n") if vary == "mass" else ("torque_n_m", "torsion_limit_n_m")

    def load_over_limit(value: float) -> float:
        worst = carried_at(value)
        return worst[measure] / worst[limit]

    threshold = _threshold(load_over_limit, dimensions[0] / 2.0 if vary == "distance" else None, f"{name}'s {vary}")
    cases, sides = [], []
    rotation = grasp_rotations(torch.tensor(closing, dtype=torch.float64), torch.tensor(DOWN)).numpy()
    for factor in (1.0 - MARGIN, 1.0 + MARGIN):
        value = threshold * factor
        mass, _ = loads(value)
        at = target if vary == "mass" else (value, target[1], target[2])
        motion = coulomb_motion(config, rotation, mass, mass * inertia_per_kg, at[0], grip, pressed.torsional_radius_m)
        sides.append((factor, value, mass, carried_at(value), at, motion))
    for (factor, value, mass, paper, at, motion), other in zip(sides, reversed(sides)):
        held = paper["sliding_n"] <= paper["sliding_limit_n"] and paper["torque_n_m"] <= paper["torsion_limit_n_m"]
        paper = {vary: value, "threshold": threshold, **paper, "pad_path_slope": grip.path_slope, "patch_radius_m": pressed.radius_m}
        cases.append(Case(f"{name} {vary} x{factor:.1f}", shape, dimensions, mass, at, closing, surface, held, motion,
                          "slide" if vary == "mass" else "turn", other[-1], paper))
    return cases


def _threshold(ratio, upper: float | None, what: str) -> float:
    """Where ``ratio(value)``, a load over its limit that grows with the value, reaches 1: in closed form for a mass
    (loads and, through a linkage, limits grow in proportion to it: ``upper`` None), else by bisection on
    (0, ``upper``)."""
    if upper is None:
        return 1.0 / ratio(1.0)
    low, high = 0.0, upper
    if ratio(low) >= 1.0 or ratio(high) <= 1.0:
        raise ValueError(f"the {what} threshold is not within (0, {upper:g})")
    for _ in range(60):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if ratio(middle) < 1.0 else (low, middle)
    return 0.5 * (low + high)


def _mesh(case: Case):
    import trimesh

    if case.shape == "box":
        return trimesh.creation.box(case.dimensions_m)
    radius, length = case.dimensions_m
    cylinder = trimesh.creation.cylinder(radius=radius, height=length, sections=64)
    cylinder.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0.0, 1.0, 0.0]))  # axis along x
    return cylinder


def analytic_grasps(config: Config, engines: tuple[str, ...] = ENGINES, protocols: tuple[str, ...] = LABEL_PROTOCOLS,
                    cache_dir: Path | None = None, note=print, cases: list[Case] | None = None) -> dict[str, Any]:
    """Every analytic case (or ``cases``, made by ``analytic_cases``) labelled by each engine in each protocol,
    against its paper answer."""
    from ..datasets.labelling import label_object_grasps
    from ..world.objects import load_object_set

    config = analytic_config(config)
    cases = analytic_cases(config) if cases is None else cases
    rows = []
    with tempfile.TemporaryDirectory(prefix="sagp_analytic_") as folder:
        entries = {}
        for index, case in enumerate(cases):
            object_id = f"case{index}"
            _mesh(case).export(Path(folder) / f"{object_id}.obj")
            entries[object_id] = {"mass_kg": case.mass_kg, "friction": OBJECT_FRICTION}
        (Path(folder) / "objects.json").write_text(json.dumps(entries))
        objects = load_object_set(folder, MeshImportSettings(max_grasp_width_m=1.0, cache_dir=cache_dir))
        for index, case in enumerate(cases):
            spec = objects.get(f"case{index}")
            rotation = grasp_rotations(torch.tensor(case.closing_axis, dtype=torch.float64), torch.tensor(DOWN))
            poses = GraspPoses(torch.tensor([case.target_m], dtype=torch.float64), rotation[None].clone(), "object")
            outcomes = {}
            for engine in engines:
                for protocol in protocols:
                    label = label_object_grasps(spec, poses, None, protocol, config, engine=engine)[0]
                    outcome = {"held": label.held, "failure": label.failure_reason, "failed_at": label.failed_at,
                               "turn_deg": math.degrees(label.object_motion_during_shaking_angular or 0.0),
                               "slip_mm": 1000.0 * (label.object_motion_during_shaking_linear or 0.0)}
                    outcomes[f"{engine}/{protocol}"] = {**outcome, "as_on_paper": as_on_paper(case, outcome)}
            row = {"case": case.name, "paper_held": case.paper_held, "mass_kg": case.mass_kg, "extents_m": list(spec.extents_m),
                   "paper": case.paper, "measure": case.measure, "paper_slide_mm": 1000.0 * case.paper_motion.slide_m,
                   "paper_turn_deg": math.degrees(case.paper_motion.turn_rad), "outcomes": outcomes,
                   "agree": sum(outcome["as_on_paper"] for outcome in outcomes.values()), "of": len(outcomes)}
            note(analytic_line(row))
            rows.append(row)
    return {"gripper": config.planner.gripper, "grip_force_n": config.execution.gripper_force_n,
            "friction": engine_pad(config.execution, robot_of(config)).friction_factor * OBJECT_FRICTION, "cases": rows,
            "agree": sum(row["agree"] for row in rows), "of": sum(row["of"] for row in rows)}


def as_on_paper(case: Case, outcome: dict[str, Any]) -> bool:
    """Whether an engine's ``outcome`` answers ``case`` as the ideal grip does: the object kept in the hand, its
    motion over the shake (``case.measure``) nearer the paper's for this case than for its counterpart."""
    if not outcome["held"]:
        return False
    if case.measure == "slide":
        measured, here, there = outcome["slip_mm"] / 1000.0, case.paper_motion.slide_m, case.counterpart_motion.slide_m
    else:
        measured, here, there = math.radians(outcome["turn_deg"]), case.paper_motion.turn_rad, case.counterpart_motion.turn_rad
    return abs(measured - here) < abs(measured - there)


def _paper_motion(row: dict[str, Any]) -> str:
    return f"slides {row['paper_slide_mm']:.1f} mm" if row["measure"] == "slide" else f"turns {row['paper_turn_deg']:.1f} deg"


def _engine_motion(outcome: dict[str, Any]) -> str:
    if not outcome["held"]:
        return f"dropped ({outcome['failure']} at {outcome['failed_at']})"
    return f"slid {outcome['slip_mm']:.1f} mm, turned {outcome['turn_deg']:.1f} deg"


def analytic_line(row: dict[str, Any]) -> str:
    outcomes = " ".join(f"{key}: {_engine_motion(o)}" + ("" if o["as_on_paper"] else " (!)") for key, o in row["outcomes"].items())
    return f"{row['case']:<38} paper {_paper_motion(row):<16} {outcomes}"


def analytic_markdown(report: dict[str, Any]) -> str:
    keys = list(report["cases"][0]["outcomes"]) if report["cases"] else []
    lines = [f"# Analytic grasps ({report['gripper']}, grip force {report['grip_force_n']:g} N, mu {report['friction']:.2f})", "",
             f"{report['agree']} of {report['of']} outcomes as on paper: the object kept in the hand and moved over the shake "
             "nearer the ideal grip's motion for this case than for its counterpart across the threshold. The paper's answers: "
             "whether the grip carries the worst load, and the motion an ideal Coulomb grip allows over the shake. Each "
             "engine's cell: the object's slide and turn in the hand over the shake, or where it was dropped.", "",
             "| case | mass (kg) | load / limit (sliding, torsion) | pad path slope | grip carries the peak | paper motion | "
             + " | ".join(keys) + " |",
             "|---|---:|---|---:|---|---|" + "---|" * len(keys)]
    for row in report["cases"]:
        paper = row["paper"]
        loads = f"{paper['sliding_n']:.2f}/{paper['sliding_limit_n']:.2f} N, {paper['torque_n_m']:.4f}/{paper['torsion_limit_n_m']:.4f} N m"
        cells = [_engine_motion(o) + ("" if o["as_on_paper"] else " **x**") for o in row["outcomes"].values()]
        lines.append(f"| {row['case']} | {row['mass_kg']:.3f} | {loads} | {paper['pad_path_slope']:.2f} | "
                     f"{'yes' if row['paper_held'] else 'no'} | {_paper_motion(row)} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
