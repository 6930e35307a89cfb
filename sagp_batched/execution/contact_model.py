"""One contact model of a rubber finger pad, and each engine's contact parameters computed from it.

The pad is a thin rubber layer (Young's modulus E, Poisson's ratio nu, thickness t) on a rigid finger, its
face the size the gripper's hulls give it (``pad_face_m``), pressed on the object with the grip force F.

Patch. A half-space (Hertz) patch on a surface of radius R would be ``a = (3 F R / 4 E*)^(1/3)``, E* = E /
(1 - nu^2): for 10-140 N on a bottle (R ~ 4 cm) and soft rubber that is 6-15 mm, several times a pad's
1-3 mm layer, where the half-space assumption fails: the rigid finger behind the layer carries the load,
and the layer presses like a bed of springs (a Winkler foundation) of modulus ``K = E / t`` per unit area (a
textured pad bulges freely between its ribs, so the uniaxial modulus, not the confined one). The pressure at
a point of the face is then ``K (delta - gap)`` where the object's surface comes within ``gap`` of the pad's
plane, ``delta`` the layer's compression at the deepest point, found so the pressures sum to F; the patch
is where the pressure is positive, capped by the pad's face and by the object's face where that is smaller
(``ContactSurface``). On a flat face the pressure is uniform over the overlap; on a sphere of radius R it is
a paraboloid of radius ``a = (4 F R / pi K)^(1/4)``; on a cylinder a strip along its axis.

Friction. The pad-object coefficient mu is the pad's (``[execution] finger_lateral_friction``) times the
object's, as both engines combine them. A patch resists sliding up to ``mu F`` and turning about its normal
up to ``mu * integral(p |r| dA)`` (Coulomb friction at every point of the patch): ``(2/3) mu a F`` for a uniform
disc, ``(8/15) mu a F`` for the paraboloid. The torsional radius is that torque over ``mu F``. Rolling: an
elastic pad resists a rolling object only by the hysteresis of its rubber, which the model leaves out; a flat
face that would roll over an edge is held by where the pressure sits, which the engines' multi-point
contacts give by geometry. So rolling friction is zero.

Stiffness and damping. The layer under the whole face is a spring ``k = E A / t`` (A the face's area) with a
stated damping ratio zeta on the two bodies' reduced mass m: ``c = 2 zeta sqrt(k m)``.

Engines. Neither engine shapes a patch: both turn a contact into a few points with a normal force each,
so the torsional limit they are given is the model's for the pad pressed flat on a face it covers (the
face's uniform pressure), the pad's own value whatever it touches (``EnginePad``), and the points are kept
where that pressure's resultant acts, the face's centre, by crowning each pad's simulated hull as high as
the layer compresses pressed flat at the grip force (``datasets.collision_urdf.crowned_hull``):

* PyBullet (``pybullet_pad_dynamics``) combines a pad's and an object's friction per contact point as
  ``lateral = f_pad f_obj``, ``spinning = s_pad f_obj + s_obj f_pad``, ``rolling = r_pad f_obj + r_obj f_pad``
  (btManifoldResult), and its multibody solver bounds each of a manifold's points' spinning impulse by the
  combined spinning friction times that point's normal impulse, so a manifold resists ``spinning * N`` in
  all. The pad's spinning friction is solved from that sum so the contact's is the model's (the object's own,
  0.001 m in the YCB URDFs, cancelled); its rolling friction is zero, and the object's own rolling friction
  times the pad's factor (0.0015 m for YCB) stays, as PyBullet takes no negative friction to cancel it. Its spring and damper are ``contactStiffness`` and
  ``contactDamping`` (Bullet's ERP and CFM from k and c each step).
* MuJoCo (``mujoco_pad_contact``) takes the pad geom's friction as the contact's (it has the higher
  ``priority`` and carries the product with the object's): sliding mu, torsional mu times the torsional
  radius, rolling 0 (``condim`` 4). ``solref`` is mass-normalised: MuJoCo asks a contact for the reference
  acceleration ``-b v - k' r`` with ``b = 2 / (d timeconst)``, ``k' = 1 / (d timeconst^2 dampratio^2)`` (impedance
  d the same at every depth: a linear spring), and blends it with the unconstrained acceleration a0 by d. A
  force held on the contact (the grip: ``m a0``, m the bodies' reduced mass) then compresses it
  ``r = (1 - d) a0 / (d k')``: a static stiffness ``m / (d (1 - d) timeconst^2 dampratio^2)``. That is the model's
  k where ``d (1 - d) = m / (k timeconst^2 zeta^2)``, which has a solution for ``timeconst >= 2 / (zeta w)``, w =
  sqrt(k / m); the time constant is the larger of that and the two steps MuJoCo integrates stably, the
  dampratio the model's zeta, and d the root nearer 1 (the contact that yields least in between). A hand
  built from a gripper's MJCF (the Robotiqs) keeps its pads' own solref and solimp: its linkage closes through
  soft equality constraints (5 ms), and pads as stiff as the model (d 0.997 on the 2F-140's 30 x 70 mm pads)
  press twice the grip force through it, or, at 4-5 ms, chatter off the object; the MJCF's pads are what its
  linkage was fitted with. Their friction and torsion are the model's.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..robot.gripper_description import PAD_FACE_DEPTH_M

# Points a side of the grid the pressure is integrated on: the torsional radius of a square face to 0.1 %.
GRID_POINTS = 121
# MuJoCo integrates a soft constraint stably down to a time constant of two of its steps (its ``refsafe``).
MUJOCO_MIN_STEPS_PER_TIME_CONSTANT = 2.0


class ContactModelError(ValueError):
    """A contact model's input out of its physical range."""


@dataclass(frozen=True)
class RubberPad:
    """A finger pad: its rubber layer and its face (width across the finger, length along the approach)."""

    young_modulus_pa: float
    poisson_ratio: float
    thickness_m: float
    face_m: tuple[float, float]
    damping_ratio: float

    def __post_init__(self) -> None:
        if not self.young_modulus_pa > 0 or not self.thickness_m > 0 or not self.damping_ratio > 0:
            raise ContactModelError(f"a pad needs a positive Young's modulus, thickness and damping ratio, got "
                                    f"{self.young_modulus_pa} Pa, {self.thickness_m} m, {self.damping_ratio}")
        if not 0.0 <= self.poisson_ratio < 0.5:
            raise ContactModelError(f"a pad's Poisson's ratio is in [0, 0.5), got {self.poisson_ratio}")
        if len(self.face_m) != 2 or not min(self.face_m) > 0:
            raise ContactModelError(f"a pad's face is two positive lengths (m), got {self.face_m}")

    @property
    def foundation_modulus_pa_m(self) -> float:
        """K: the pressure per metre of the layer's compression."""
        return self.young_modulus_pa / self.thickness_m

    @property
    def stiffness_n_m(self) -> float:
        """k = E A / t: the whole face pressed flat."""
        return self.foundation_modulus_pa_m * self.face_m[0] * self.face_m[1]

    def damping_n_s_m(self, mass_kg: float) -> float:
        """c = 2 zeta sqrt(k m) for the reduced mass ``mass_kg`` of the two bodies in contact."""
        if not mass_kg > 0:
            raise ContactModelError(f"the mass a pad's contact moves must be positive, got {mass_kg} kg")
        return 2.0 * self.damping_ratio * math.sqrt(self.stiffness_n_m * mass_kg)

    def hertz_radius_m(self, force_n: float, curvature_radius_m: float) -> float:
        """The half-space (Hertz) patch radius on a sphere of ``curvature_radius_m``: where it exceeds the layer's
        thickness, the layer model (``patch``) applies."""
        plane_strain_modulus = self.young_modulus_pa / (1.0 - self.poisson_ratio**2)
        return (3.0 * force_n * curvature_radius_m / (4.0 * plane_strain_modulus)) ** (1.0 / 3.0)


@dataclass(frozen=True)
class ContactSurface:
    """The object's surface under the pad, in the pad face's frame (x across its width, z along its length):
    ``curvature_radius_m`` None for a flat face, else a sphere's radius, or a cylinder's with ``cylinder_axis``
    "width" or "length" the face direction its axis lies along; ``face_half_m`` the object's flat face where it
    is smaller than the pad's (half-extents across x and z), ``face_radius_m`` a round one (a cylinder's end)."""

    curvature_radius_m: float | None = None
    cylinder_axis: str | None = None
    face_half_m: tuple[float, float] | None = None
    face_radius_m: float | None = None

    def __post_init__(self) -> None:
        if self.curvature_radius_m is not None and not self.curvature_radius_m > 0:
            raise ContactModelError(f"a surface's curvature radius must be positive (None: flat), got {self.curvature_radius_m}")
        if self.cylinder_axis not in (None, "width", "length"):
            raise ContactModelError(f"a cylinder's axis lies along the pad's 'width' or 'length', got {self.cylinder_axis!r}")


@dataclass(frozen=True)
class Patch:
    """The pressed patch: its area, radius (of the disc of that area), the layer's compression and the
    torsional radius: the torque the patch resists about its normal over mu times the normal force."""

    area_m2: float
    radius_m: float
    compression_m: float
    torsional_radius_m: float


# The grid integration costs ~2 ms and every attempt and world asks for the same few pads and forces.
@functools.lru_cache(maxsize=64)
def patch(pad: RubberPad, force_n: float, surface: ContactSurface = ContactSurface()) -> Patch:
    """The patch ``pad`` presses on ``surface`` with ``force_n``: the layer's pressure ``K (delta - gap)``,
    ``delta`` such that it sums to the force, integrated on a grid over the pad's face."""
    if not force_n > 0:
        raise ContactModelError(f"a pad's normal force must be positive, got {force_n} N")
    half_width, half_length = pad.face_m[0] / 2.0, pad.face_m[1] / 2.0
    step_x, step_z = 2.0 * half_width / GRID_POINTS, 2.0 * half_length / GRID_POINTS
    x, z = np.meshgrid(np.linspace(step_x / 2 - half_width, half_width - step_x / 2, GRID_POINTS),
                       np.linspace(step_z / 2 - half_length, half_length - step_z / 2, GRID_POINTS))
    cell = step_x * step_z
    touching = np.ones_like(x, dtype=bool)
    if surface.face_half_m is not None:
        touching &= (np.abs(x) <= surface.face_half_m[0]) & (np.abs(z) <= surface.face_half_m[1])
    if surface.face_radius_m is not None:
        touching &= np.hypot(x, z) <= surface.face_radius_m
    if not touching.any():
        raise ContactModelError(f"the object's face {surface} does not meet the pad's face {pad.face_m}")
    radius = surface.curvature_radius_m
    if radius is None:
        gap = np.zeros_like(x)
    elif surface.cylinder_axis == "length":
        gap = x**2 / (2.0 * radius)
    elif surface.cylinder_axis == "width":
        gap = z**2 / (2.0 * radius)
    else:
        gap = (x**2 + z**2) / (2.0 * radius)
    gap = np.where(touching, gap, np.inf)
    modulus = pad.foundation_modulus_pa_m

    def load(compression: float) -> float:
        return float(modulus * np.clip(compression - gap, 0.0, None).sum() * cell)

    low, high = 0.0, force_n / (modulus * cell) + float(gap[touching].max())
    for _ in range(100):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if load(middle) < force_n else (low, middle)
    compression = 0.5 * (low + high)
    pressure = modulus * np.clip(compression - gap, 0.0, None)
    pressed = pressure > 0.0
    area = float(pressed.sum() * cell)
    torsional_radius = float((pressure * np.hypot(x, z)).sum() / pressure.sum())
    return Patch(area_m2=area, radius_m=math.sqrt(area / math.pi), compression_m=compression, torsional_radius_m=torsional_radius)


def pad_torsional_limit_n_m(pad: RubberPad, force_n: float, friction: float, surface: ContactSurface = ContactSurface()) -> float:
    """The torque one pad resists about its normal: mu times the integral of pressure times lever."""
    return friction * force_n * patch(pad, force_n, surface).torsional_radius_m


@dataclass(frozen=True)
class EnginePad:
    """What both engines take from the model: the pad's friction factor (the object's multiplies it), the
    torsional radius of its face pressed flat at the grip force, rolling none, its spring and damping ratio, and
    the crown of its simulated hull: the layer's compression pressed flat at the grip force."""

    pad: RubberPad
    friction_factor: float
    torsional_radius_m: float
    crown_m: float

    @classmethod
    def of(cls, pad: RubberPad, grip_force_n: float, friction_factor: float) -> "EnginePad":
        if not friction_factor >= 0:
            raise ContactModelError(f"a pad's friction factor must be >= 0, got {friction_factor}")
        flat = patch(pad, grip_force_n)
        return cls(pad, friction_factor, flat.torsional_radius_m, flat.compression_m)


def reduced_mass_kg(first_kg: float, second_kg: float) -> float:
    """The mass a contact between two free bodies moves: ``m1 m2 / (m1 + m2)``."""
    if not (first_kg > 0 and second_kg > 0):
        raise ContactModelError(f"both bodies of a contact need a positive mass, got {first_kg} and {second_kg} kg")
    return first_kg * second_kg / (first_kg + second_kg)


def pybullet_pad_dynamics(engine: EnginePad, object_surface: tuple[float, float, float], mass_kg: float) -> dict[str, float]:
    """``pybullet.changeDynamics`` keywords for a pad touching an object of (lateral, spinning, rolling) friction
    ``object_surface``: the combined spinning friction mu times the torsional radius. The pad adds no rolling
    friction; PyBullet refuses a negative one, so the object's own (``rolling * finger_lateral_friction``) stays."""
    lateral, spinning, _ = object_surface
    if not lateral > 0:
        raise ContactModelError(f"the object's lateral friction must be positive for a pad to grip it, got {lateral}")
    pad_friction = engine.friction_factor
    return {
        "lateralFriction": pad_friction,
        "spinningFriction": max(0.0, pad_friction * (engine.torsional_radius_m - spinning / lateral)),
        "rollingFriction": 0.0,
        "contactStiffness": engine.pad.stiffness_n_m,
        "contactDamping": engine.pad.damping_n_s_m(mass_kg),
    }


def mujoco_pad_contact(engine: EnginePad, object_surface: tuple[float, float, float], mass_kg: float, timestep_s: float,
                       solimp_shape: tuple[float, float, float]) -> tuple[list[float], tuple[float, float], tuple[float, ...]]:
    """(friction, solref, solimp) of a MuJoCo pad geom touching an object of ``object_surface``, ``mass_kg`` the
    two bodies' reduced mass, ``timestep_s`` MuJoCo's step; ``solimp_shape`` (width, midpoint, power) of the
    impedance, which is the same d at every depth."""
    if not timestep_s > 0:
        raise ContactModelError(f"MuJoCo's step must be positive, got {timestep_s} s")
    pad = engine.pad
    friction = engine.friction_factor * object_surface[0]
    zeta = pad.damping_ratio
    natural_frequency = math.sqrt(pad.stiffness_n_m / mass_kg)
    time_constant = max(2.0 / (zeta * natural_frequency), MUJOCO_MIN_STEPS_PER_TIME_CONSTANT * timestep_s)
    stiffness_ratio = pad.stiffness_n_m * time_constant**2 * zeta**2 / mass_kg  # 1 / (d (1 - d)), >= 4
    # At the uncapped time constant the ratio is 4 exactly, which rounding can put a hair below.
    impedance = 0.5 * (1.0 + math.sqrt(max(0.0, 1.0 - 4.0 / stiffness_ratio)))
    return [friction, friction * engine.torsional_radius_m, 0.0], (time_constant, zeta), (impedance, impedance, *solimp_shape)


def pad_face_m(robot) -> tuple[float, float]:
    """(width, length) of the gripper's pad face from its hulls with the hand open: the extent, across the
    finger (x) and along the approach (z), of the pad hull's vertices within ``PAD_FACE_DEPTH_M`` of its side
    nearest the closing plane."""
    from ..robot.hand import load_hand_geometry

    vertices = np.asarray(load_hand_geometry(robot).vertices(robot.gripper.pad_links[:1]))
    inward = np.abs(vertices[:, 1])
    face = vertices[inward <= inward.min() + PAD_FACE_DEPTH_M]
    return float(np.ptp(face[:, 0])), float(np.ptp(face[:, 2]))


def engine_pad(execution, robot) -> EnginePad:
    """The model of ``robot``'s pads at ``execution``'s grip force, rubber and friction factor."""
    pad = RubberPad(execution.pad_young_modulus_pa, execution.pad_poisson_ratio, execution.pad_thickness_m, pad_face_m(robot),
                    execution.pad_damping_ratio)
    return EnginePad.of(pad, execution.gripper_force_n, execution.finger_lateral_friction)
