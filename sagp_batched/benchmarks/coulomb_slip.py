"""How far an ideal Coulomb grip lets a pinched object slide and turn in the hand over the protocol's lift
and shake: the paper answer the analytic cases' engines are measured against (``analytic_grasps``).

A threshold says whether the grip's friction can carry the worst load; past it, an ideal grip lets the object
slide only while the load exceeds its limit, near each peak, and grips it again as the load falls, so a
case above its threshold slides a few millimetres rather than falling. This integrates that: the object
rigid, pinched at a point ``lever_m`` from its centre of mass along the grasp's x, the hand following its
planned lift and shake exactly, and the grip carrying any force in the pads' plane up to ``sliding_limit_n``
and any torque about the closing axis up to ``torsion_limit_n_m``, each checked on its own as the thresholds
are. Sliding and turning stop where the relative motion would reverse under a load within the limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

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
                   sliding_limit_n: float, torsion_limit_n_m: float) -> PaperMotion:
    """The ideal grip's slide and turn over the shake for an object of ``mass_kg``, moment of inertia
    ``inertia_kg_m2`` about its centre of mass (about the closing axis), pinched ``lever_m`` from it."""
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
        slide, slide_velocity = _slide_step(slide, slide_velocity, force[[0, 2]], sliding_limit_n, mass_kg, dt)
        (turn,), (turn_rate,) = _slide_step(np.array([turn]), np.array([turn_rate]), np.array([torque]), torsion_limit_n_m,
                                            pivot_inertia, dt)
    start_slide, start_turn = at_shake
    return PaperMotion(float(np.linalg.norm(slide - start_slide)), abs(turn - start_turn))


def _slide_step(position: np.ndarray, velocity: np.ndarray, needed: np.ndarray, limit: float, inertia: float,
                dt: float) -> tuple[np.ndarray, np.ndarray]:
    """One step of a Coulomb contact in one or two dimensions: the grip gives ``needed`` while within ``limit``
    and the object is not moving relative to it; otherwise ``limit`` against the relative motion (or along
    ``needed`` as it starts), the object's relative acceleration (grip - needed) / ``inertia``. Motion that
    would reverse within the limit stops: the grip holds again."""
    speed, load = float(np.linalg.norm(velocity)), float(np.linalg.norm(needed))
    if speed == 0.0 and load <= limit:
        return position, velocity
    direction = -velocity / speed if speed > 0.0 else needed / load
    new_velocity = velocity + (limit * direction - needed) / inertia * dt
    if speed > 0.0 and float(np.dot(new_velocity, velocity)) <= 0.0 and load <= limit:
        new_velocity = np.zeros_like(velocity)
    return position + new_velocity * dt, new_velocity
