"""How far an ideal Coulomb grip lets a pinched object slide and turn in the hand over the protocol's lift
and shake: the paper answer the analytic cases' engines are measured against (``analytic_grasps``).

A threshold says whether the grip's friction can carry the worst load; past it, an ideal grip lets the object
slide only while the load exceeds its limit, near each peak, and grips it again as the load falls, so a
case above its threshold slides a few millimetres rather than falling. This integrates that: the object
rigid, pinched at a point ``lever_m`` from its centre of mass along the grasp's x, the hand following its
planned lift and shake exactly, and the grip (``PinchGrip``) carrying any force in the pads' plane up to its
sliding limit and any torque about the closing axis up to its torsional limit, each checked on its own as the
thresholds are. Sliding and turning stop where the relative motion would reverse under a load within the limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from ..config import Config
from ..datasets.protocols import half_cosine
from ..execution.shake import shake_profile


@dataclass(frozen=True)
class PaperMotion:
    """The object's motion in an ideal grip over the shake: its slide in the pads' plane (m) and its turn about
    the closing axis (rad), from the shake's start to its end, as the protocols measure an engine's."""

    slide_m: float
    turn_rad: float


@dataclass(frozen=True)
class PinchGrip:
    """Two mirrored pads, each pressed on the object with ``force_n`` by a force-limited drive, with friction
    ``friction``, each moving ``path_slope`` along the approach (away from the palm) per unit it closes
    (``GripperDescription.pad_path_slope``: 0 for fingers that slide, a linkage swings its pads on arcs).

    A force f that the object puts on a pad along the approach does f times the slope of work per unit the
    pad closes, so with the drive's force fixed the pad presses N = F + slope f (virtual work). Where the grip
    gives the object a force G in the pads' plane, half from each pad, f = -G_z / 2; at the friction's limit
    G = 2 mu N along a unit direction d, so N = F / (1 + mu slope d_z): the limit depends on the direction,
    and a linkage grips harder the more the object pulls its pads along their path. Beyond
    mu slope d_z = -1 the grip would lock itself; the cases never ask that."""

    force_n: float
    friction: float
    path_slope: float = 0.0

    def normal_force_n(self, direction: np.ndarray) -> float:
        """Each pad's normal force while the grip's force on the object points along the unit ``direction`` (its
        last component along the approach); the grip force where the grip gives none (a zero direction)."""
        return self.force_n / (1.0 + self.friction * self.path_slope * float(direction[-1]))

    def sliding_limit_n(self, direction: np.ndarray) -> float:
        """The most force the two pads' friction gives the object along the unit ``direction`` in their plane."""
        return 2.0 * self.friction * self.normal_force_n(direction)


def hand_path(config: Config, grasp_rotation: np.ndarray) -> tuple[np.ndarray, Rotation, int]:
    """The grasp target's planned world positions (T, 3) and orientations at every step of the lift (a half-cosine
    up ``lift_height_m`` in ``hand_lift_steps``) and the shake around the lifted pose, and the shake's first step."""
    steps, height = config.labelling.hand_lift_steps, config.motion.lift_height_m
    lift = np.zeros((steps, 3))
    lift[:, 2] = [height * half_cosine(step / steps) for step in range(1, steps + 1)]
    profile = shake_profile(config.labelling.shake, config.scene.time_step_s)
    start = Rotation.from_matrix(grasp_rotation)
    shake = lift[-1] + start.apply(profile.offsets[:, :3])
    rotations = Rotation.concatenate([start] * (steps + 1) + [start * Rotation.from_rotvec(profile.offsets[:, 3:])])
    positions = np.concatenate([np.zeros((1, 3)), lift, shake])
    return positions, rotations, steps + 1


def coulomb_motion(config: Config, grasp_rotation: np.ndarray, mass_kg: float, inertia_kg_m2: float, lever_m: float,
                   grip: PinchGrip, torsional_radius_m: float) -> PaperMotion:
    """The ideal grip's slide and turn over the shake for an object of ``mass_kg``, moment of inertia
    ``inertia_kg_m2`` about its centre of mass (about the closing axis), pinched ``lever_m`` from it. Each pad
    resists turning with mu N times ``torsional_radius_m`` (``contact_model.Patch``), N the pad's normal force
    at that step (``PinchGrip.normal_force_n``)."""
    dt = config.scene.time_step_s
    positions, rotations, shake_start = hand_path(config, grasp_rotation)
    gravity = np.array([0.0, 0.0, config.scene.gravity_m_s2])
    # The hand's linear and angular velocity and acceleration at each step, in the world, by central differences.
    velocity = np.gradient(positions, dt, axis=0)
    acceleration = np.gradient(velocity, dt, axis=0)
    spin = (rotations[1:] * rotations[:-1].inv()).as_rotvec() / dt
    spin = np.concatenate([spin[:1], spin])
    spin_rate = np.gradient(spin, dt, axis=0)
    slide, slide_velocity = np.zeros(2), np.zeros(2)  # in the pads' plane: the grasp's x and z
    turn, turn_rate = 0.0, 0.0
    pivot_inertia = inertia_kg_m2 + mass_kg * lever_m**2
    at_shake = (np.zeros(2), 0.0)
    for step in range(len(positions)):
        if step == shake_start:
            at_shake = (slide.copy(), turn)
        hand = rotations[step].as_matrix()
        # Where the centre of mass sits in the hand: the lever turned by the turn so far about the closing axis (y).
        arm_in_hand = np.array([lever_m * math.cos(turn), 0.0, -lever_m * math.sin(turn)])
        arm = hand @ arm_in_hand
        omega, alpha = spin[step], spin_rate[step]
        point_acceleration = acceleration[step] + np.cross(alpha, arm) + np.cross(omega, np.cross(omega, arm))
        # The force and torque the grip must give for the object to move with the hand, in the hand's frame.
        force = hand.T @ (mass_kg * (point_acceleration - gravity))
        torque = float(np.cross(arm_in_hand, force)[1] + inertia_kg_m2 * (hand.T @ alpha)[1])
        slide, slide_velocity, grip_direction = _slide_step(slide, slide_velocity, force[[0, 2]], grip.sliding_limit_n, mass_kg, dt)
        torsion_limit = 2.0 * grip.friction * grip.normal_force_n(grip_direction) * torsional_radius_m
        (turn,), (turn_rate,), _ = _slide_step(np.array([turn]), np.array([turn_rate]), np.array([torque]), lambda _: torsion_limit,
                                               pivot_inertia, dt)
    start_slide, start_turn = at_shake
    return PaperMotion(float(np.linalg.norm(slide - start_slide)), abs(turn - start_turn))


def _slide_step(position: np.ndarray, velocity: np.ndarray, needed: np.ndarray, limit: Callable[[np.ndarray], float], inertia: float,
                dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step of a Coulomb contact in one or two dimensions: the grip gives ``needed`` while within its limit
    along it and the object is not moving relative to it; otherwise its limit against the relative motion (or
    along ``needed`` as it starts), the object's relative acceleration (grip - needed) / ``inertia``. Motion that
    would reverse within the limit stops: the grip holds again. ``limit(direction)``: the most the grip gives along
    a unit direction. Returns the new position and velocity and the unit direction the grip's force took (zero
    where it gave none)."""
    speed, load = float(np.linalg.norm(velocity)), float(np.linalg.norm(needed))
    along_needed = needed / load if load > 0.0 else np.zeros_like(needed)
    if speed == 0.0 and load <= limit(along_needed):
        return position, velocity, along_needed
    direction = -velocity / speed if speed > 0.0 else along_needed
    new_velocity = velocity + (limit(direction) * direction - needed) / inertia * dt
    if speed > 0.0 and float(np.dot(new_velocity, velocity)) <= 0.0 and load <= limit(along_needed):
        return position, np.zeros_like(velocity), along_needed
    return position + new_velocity * dt, new_velocity, direction
