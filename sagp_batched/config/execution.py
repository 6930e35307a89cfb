"""The sections of what happens in simulation after planning: the arm's execution, the labelling shake and
floating hand, and the task thresholds a trial is judged by."""
from __future__ import annotations

from dataclasses import dataclass, field

from .settings import _Section, setting


@dataclass
class ExecutionConfig(_Section):
    SECTION = "execution"

    hold_steps: int = setting(80, at_least=0)
    settle_steps: int = setting(60, at_least=0)
    ik_iterations: int = setting(500, at_least=1)
    max_attempts: int = setting(3, at_least=1)
    success_height_above_table_m: float = setting(0.15, above=0)
    # Each waypoint of the motion is tracked for this many steps under position control.
    steps_per_waypoint: int = setting(20, at_least=1)
    close_steps: int = setting(120, at_least=1)
    # Panda hand: 70 N continuous grip force per the datasheet; enough for the 1.13 kg bleach bottle.
    gripper_force_n: float = setting(70.0, above=0)
    # The finger pads' friction factor: the pad-object coefficient is this times the object's (YCB URDFs: 0.9),
    # as both engines combine them.
    finger_lateral_friction: float = setting(1.5, at_least=0)
    # The pads' rubber (``execution.contact_model``): soft rubber (Shore ~50A, E ~2 MPa, nearly incompressible)
    # in a 2 mm layer; the patch, torsional friction, stiffness and damping of both engines follow from these,
    # the grip force and the pad's face measured from the gripper's hulls.
    pad_young_modulus_pa: float = setting(2.0e6, above=0)
    pad_poisson_ratio: float = setting(0.49, at_least=0, below=0.5)
    pad_thickness_m: float = setting(0.002, above=0)
    # Critically damped: the pad catches a free object without bouncing it.
    pad_damping_ratio: float = setting(1.0, above=0)
    arm_position_gain: float = setting(0.3, above=0, at_most=1)
    # PyBullet IK restarts from seeded random joints inside the limits when the given seeds fail.
    ik_random_restarts: int = setting(8, at_least=0)
    # A fingertip grazing the table on the way down (grasps on flat objects end millimetres above
    # it) is harmless; pressing on it harder than this during the descent counts as a collision.
    # libfranka's default contact reflex stops the real arm at 20 N; half that stays conservative.
    table_contact_max_force_n: float = setting(10.0, at_least=0)
    # The object moving more than this before the fingers close means the gripper knocked it.
    knock_tolerance_m: float = setting(0.01, at_least=0)
    # A failed attempt whose object rose at least this much during the lift "slipped" rather than "not_lifted".
    lifted_detect_height_m: float = setting(0.05, at_least=0)
    # Camera for record_frames: eye offset from the object's resting position.
    frame_camera_offset_m: tuple[float, float, float] = setting((0.55, 0.35, 0.35), shape=(3,))


@dataclass
class ShakeConfig(_Section):
    """The shake after the lift: the hand oscillates along, then about, each axis of the grasp frame
    (x = closing x approach, y = closing axis, z = approach) in turn, rotations about the grasp
    target. Each axis moves ``A (1 - cos 2 pi f t)`` for ``cycles`` cycles, ``A = peak / (2 pi f)^2``:
    it starts and ends at rest on the lifted pose and its acceleration peaks at the given value."""

    SECTION = "labelling.shake"

    #: Franka's Cartesian acceleration limit (13 m/s^2, 1.3 g): a shake a real Panda can do, a
    #: little harder than GraspDataGen's 1 g tugs.
    linear_peak_acceleration_m_s2: tuple[float, float, float] = setting((13.0, 13.0, 13.0), at_least=0, shape=(3,))
    #: Franka's rotational acceleration limit (25 rad/s^2): 1.3-2.5 m/s^2 more at a centre of mass
    #: 5-10 cm from the fingers, on top of the torque gravity puts on the grip.
    angular_peak_acceleration_rad_s2: tuple[float, float, float] = setting((25.0, 25.0, 25.0), at_least=0, shape=(3,))
    #: 5 Hz: the peaks above move the hand 2.6 cm and 2.9 deg, a cycle is 48 steps at 240 Hz. A
    #: higher frequency is cheaper but gentler, its smaller strokes let marginal pinches hold (a
    #: bleach bottle pinched by its cap that 5 Hz drops keeps its hold at 8 and 10 Hz).
    frequency_hz: float = setting(5.0, above=0, at_most=120)
    #: One cycle reverses each axis' acceleration twice, enough for a marginal grip to let go.
    cycles: int = setting(1, at_least=1, at_most=100)
    #: Along and about one axis in the same window: half the steps, but a weaker test (it dropped
    #: 4 of the 7 cap pinches the six windows drop).
    linear_with_angular: bool = False

    @property
    def duration_s(self) -> float:
        """Simulated time of the whole shake: ``cycles`` cycles for each axis with a non-zero peak."""
        linear, angular = self.linear_peak_acceleration_m_s2, self.angular_peak_acceleration_rad_s2
        if self.linear_with_angular:
            windows = sum(1 for axis in range(3) if linear[axis] > 0.0 or angular[axis] > 0.0)
        else:
            windows = sum(1 for peak in (*linear, *angular) if peak > 0.0)
        return windows * self.cycles / self.frequency_hz


@dataclass
class MuJoCoConfig(_Section):
    """The MuJoCo engine of hand-mode labels (``datasets.mujoco_hand``): how its world is stepped and how
    soft its contacts and the hand's carrier are. The protocol, the grip force, the friction and the
    hulls are the study's, as the PyBullet engine has them. The values were chosen by labelling the same
    240 planned grasps (4 YCB objects, both protocols) in both engines (``benchmarks.engine_agreement``);
    the figures below are that sweep's agreement with PyBullet, one setting changed at a time from these."""

    SECTION = "labelling.mujoco"

    #: MuJoCo steps per 240 Hz protocol step (0.69 ms each). A soft constraint's time constant is at least
    #: two steps, and the pads' (2 / (zeta omega) = 0.63 ms for the Panda's k on a finger's mass) is then
    #: held at 1.39 ms: at 4 steps (2.08 ms) the analytic cases still answer as on paper but slide 6.4-10.7 mm
    #: past their thresholds (an ideal grip 5.2 mm, here 4.9-5.0), and the close knocks a free object out
    #: of the fingers more often (engine agreement on the YCB set 93.4 % against 95.0 %).
    substeps: int = setting(6, at_least=1, at_most=100)
    #: Semi-implicit Euler integrates the finger servo's damping as a force within its clamp; the
    #: implicit integrators add it to the finger's mass, which then strikes a free object (implicitfast: 85 %).
    integrator: str = setting("euler", choices=("euler", "implicit", "implicitfast", "rk4"))
    #: Newton converges on these few contacts in one to a few iterations a step.
    solver: str = setting("newton", choices=("newton", "cg", "pgs"))
    #: Friction as a true cone; a pyramid's facets leave the grip weaker between them (pyramidal: 69 %).
    cone: str = setting("elliptic", choices=("elliptic", "pyramidal"))
    #: Friction a hundred times stiffer than the normal force: a pad's rubber grips without creeping, and
    #: MuJoCo's regularised friction creeps in proportion to 1 / impratio. At 10 a bar 20 % inside its
    #: torsion threshold turned 1.6 deg in the shake, at 1 19 deg (0.2 deg here; an ideal grip, none). A
    #: hand from a gripper's own MJCF keeps the impratio its model was tuned with (the Robotiqs': 10).
    impratio: float = setting(100.0, at_least=1)
    #: The solver's cap, far above the iterations these worlds take.
    iterations: int = setting(50, at_least=1, at_most=10_000)
    #: The cap of each Newton iteration's line search, likewise never reached.
    ls_iterations: int = setting(20, at_least=1, at_most=10_000)
    #: A no-slip pass stops what creep is left: 5 passes label alike (92 %) at 1.3 times the time.
    noslip_iterations: int = setting(0, at_least=0, at_most=10_000)
    #: The finger pads' contacts resist turning (torsional friction, ``execution.contact_model``); 6 would add
    #: rolling friction, which the pad model has none of.
    finger_condim: int = setting(4, choices=(4, 6))
    #: Several points a hull pair: labels alike (92 %), 1.8 times the time. A hand from a gripper's MJCF
    #: (the Robotiqs) always has them: its pads on underactuated linkages rock about a single point.
    multiccd: bool = False
    #: PyBullet wraps every convex hull it loads from a URDF in a 1 mm collision margin (the table's box
    #: has none): contacts form this far out, twice it between hand and object (MuJoCo adds two geoms'
    #: margins), and the hand meets and knocks what PyBullet's does on the way down (0: as many labels
    #: alike, 92 %, but it holds every tabletop grasp PyBullet drops: kappa 0.12 there, against 0.37).
    hull_margin_m: float = setting(0.001, at_least=0)
    #: Every other contact (palm, table) stiff and critically damped, as PyBullet's rigid contacts are.
    contact_solref: tuple[float, float] = setting((0.004, 1.0), shape=(2,))
    #: Impedance near 1 for the rigid contacts; the pads' (d, d) comes from the contact model and their
    #: (width, midpoint, power) from here.
    contact_solimp: tuple[float, float, float, float, float] = setting((0.95, 0.99, 0.001, 0.5, 2.0), shape=(5,))
    #: The weld that carries the hand, as stiff as the substeps integrate: the hand reaches 98 % of the
    #: shake's peaks, PyBullet's constraint (erp 0.8) 99.7 %.
    hand_weld_solref: tuple[float, float] = setting((0.004, 1.0), shape=(2,))
    #: Impedance close to 1, so the weld holds the hand as hard as its time constant allows.
    hand_weld_solimp: tuple[float, float, float, float, float] = setting((0.99, 0.999, 0.001, 0.5, 2.0), shape=(5,))
    #: PyBullet's motor pushes the full grip force on a blocked finger; here the servo's spring reaches
    #: it once the finger lags its set point by this much.
    finger_servo_saturation_m: float = setting(0.001, above=0)
    #: The servo critically damped, so a free finger follows its set point without overshoot.
    finger_servo_damping_ratio: float = setting(1.0, above=0)


@dataclass
class LabellingConfig(_Section):
    """Grasp labels from simulation: the shake both modes end with, and the floating hand's motion.

    Hand mode (``sagp_batched.datasets.labelling``) follows the study's motion (``[motion]``: pre-grasp
    offset, lift height) and uses its grip force, finger friction, collision thresholds and success
    test from ``[execution]``; how long the floating hand takes for each phase is set here, and the MuJoCo
    engine's own settings in ``[labelling.mujoco]``."""

    SECTION = "labelling"

    shake: ShakeConfig = field(default_factory=ShakeConfig)
    mujoco: MuJoCoConfig = field(default_factory=MuJoCoConfig)
    #: The object is put down at its settled pose in a fresh world: a few steps let its contacts
    #: with the table form before the hand moves.
    hand_settle_steps: int = setting(12, at_least=0, at_most=10_000)
    #: Pre-grasp to grasp (10 cm) on a half-cosine in 0.2 s: peak speed 0.8 m/s, at rest at the grasp.
    hand_approach_steps: int = setting(48, at_least=1, at_most=10_000)
    #: The study's fingers close 10 % of their remaining travel a step, onto a 5 mm object in 26
    #: steps; 48 (0.2 s) leave the grip time to settle, and agree with the arm as often as the
    #: study's 120 close steps do.
    hand_close_steps: int = setting(48, at_least=1, at_most=10_000)
    #: The 20 cm lift on a half-cosine in 0.3 s: peak acceleration 11 m/s^2, below the shake's.
    hand_lift_steps: int = setting(72, at_least=1, at_most=10_000)
    #: Held still for 0.1 s after the lift, then judged before the shake starts.
    hand_hold_steps: int = setting(24, at_least=0, at_most=10_000)
    #: PyBullet's solver stops iterating once its residual falls below this (Bullet's default).
    pybullet_solver_residual_threshold: float = setting(1e-7, above=0)
    #: A slide hand's world iterates PyBullet's solver ``[scene] solver_iterations`` times an object of this
    #: mass or more, and in proportion for a lighter one (up to ``pybullet_max_solver_iterations``): Gauss-Seidel
    #: needs more sweeps the lighter the body between two pads pressing hard. At 100 sweeps PyBullet dropped 9 of
    #: 20 grasps of a 4 g marker (ACRONYM's 150 kg/m^3) that a 70 N grip holds with 5,000 times its weight in
    #: friction, and held every one at 20 g; 200 sweeps held them at 4 g (this rule gives 500 there).
    pybullet_full_iterations_mass_kg: float = setting(0.02, above=0)
    pybullet_max_solver_iterations: int = setting(1000, at_least=1)
    #: Error reduction of the fixed constraint that carries the hand (PyBullet's ``erp``, set in the
    #: hand's world): PyBullet's 0.2 lets the hand trail its target by ~4 steps, short of the
    #: shake's peaks by a tenth; 0.8 follows within a step.
    hand_constraint_erp: float = setting(0.8, above=0, at_most=1)
    #: Force the fixed constraint that carries the hand may apply: many times what moving hand
    #: (1 kg) and object (up to 1.1 kg) at the shake's accelerations takes.
    hand_constraint_max_force_n: float = setting(1000.0, above=0)
    #: Where the floating hand's URDF and the objects' collision-only URDFs (absolute mesh paths) are written.
    hand_urdf_cache_dir: str = setting("~/.cache/sagp_batched/hand", non_empty=True)
    #: An open hand reaching this far into the object's mesh or below the table at the grasp pose is
    #: a collision decided by geometry: deeper than the contact margins simulation allows, shallower
    #: than any grasp the simulation could still close.
    geometry_tolerance_m: float = setting(0.001, at_least=0)
    #: Simulations per label, the grasp's own pose and perturbed copies: a label should not hang on
    #: a millimetre. 1 simulates the pose alone.
    perturbed_simulations: int = setting(5, at_least=1, at_most=100)
    #: How far each perturbed copy is moved and turned about the grasp centre: the pose error of a
    #: calibrated arm and camera.
    perturbation_translation_m: float = setting(0.002, at_least=0)
    perturbation_rotation_deg: float = setting(2.0, at_least=0, at_most=90)
    #: The perturbed copies are simulated only where the grasp's own simulation left a thin margin
    #: (``labelling.thin_margin``): held, but the object slipped or turned in the fingers during the
    #: shake by more than these, or let go in the shake. A grasp held firmly, or dropped before the
    #: shake, is labelled by its own simulation. False: every grasp gets its copies. On 504 planned
    #: grasps (8 YCB objects, floating) 6 (MuJoCo) and 10 (PyBullet) labels change, grasps 1-2 of whose
    #: copies held, at half the time; drawing the copies anew changes 12 and 14. Every copy is tested by
    #: geometry: a grasp most of whose copies put the open hand in the object is dropped in every engine.
    perturb_only_thin_margins: bool = True
    thin_margin_slip_m: float = setting(0.005, at_least=0)
    thin_margin_rotation_deg: float = setting(5.0, at_least=0, at_most=180)
    #: A simulation stops once the object has fallen this far from where the hand held it, out of
    #: contact with the hand and not rising, at two checks ``early_stop_check_steps`` apart
    #: (``early_stop.FallWatch``): twice the shake's 2.6 cm stroke, which cannot bring it back. 0: never.
    early_stop_distance_m: float = setting(0.05, at_least=0)
    early_stop_check_steps: int = setting(12, at_least=1, at_most=10_000)
    #: A simulation has diverged (``protocols.speed_past_bound``) where the object moves relative to
    #: the hand faster than this plus what gravity adds over the simulated time: the hand's motions
    #: (0.8 m/s approach, 1 m/s lift, the shake's peaks) and a closing finger give an object a few
    #: m/s at most, so past 10 m/s the solver, not the protocol, is moving it.
    divergence_speed_m_s: float = setting(10.0, above=0)
    #: A simulation that diverged is run once more with each step divided into this many more
    #: (each engine's substeps, the hand's target moved through them); where it diverges again the grasp is untested.
    divergence_step_division: int = setting(4, at_least=2, at_most=64)


@dataclass
class TaskConfig(_Section):
    SECTION = "tasks"

    # Published task definitions: t2 keeps the object within 15 deg of its resting orientation
    # (also the OP metric's threshold), t3 moves no distractor more than 5 cm.
    orientation_tolerance_deg: float = setting(15.0, at_least=0, at_most=180)
    distractor_tolerance_m: float = setting(0.05, at_least=0)
