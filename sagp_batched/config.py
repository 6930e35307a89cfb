"""One configuration type for the whole pipeline, filled from ``profiles/*.toml``.

Every number of the method lives here with the published value as default; a choice the method leaves
open carries a one-line reason. A profile is a TOML file whose tables mirror these dataclasses
(``[scene]``, ``[camera]``, ``[perception]``, ``[planner]``, ``[weights]``, ``[execution]``,
``[zones]``, ``[rating]``, ``[labelling]`` with ``[labelling.shake]``, ``[run]``); command-line flags override profile values through ``override``.
"""
from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

# The checkout's top-level profiles/ folder, installed as this package by pyproject.toml.
PROFILES_PACKAGE = "sagp_batched.profiles"


class ConfigError(ValueError):
    """A profile or override names an unknown key or holds a value of the wrong type."""


# How planner.pair_sampling draws the method's contact pairs: uniformly, or antipodally guided.
PAIR_SAMPLING_MODES = ("uniform", "guided")


@dataclass
class SceneConfig:
    time_step_s: float = 1.0 / 240.0
    gravity_m_s2: float = -9.81
    table_size_m: tuple[float, float] = (1.2, 0.8)
    table_top_z_m: float = 0.625
    # Table centre in world x/y; the Panda stands at the table's near long edge, facing +x.
    table_center_xy_m: tuple[float, float] = (0.5, 0.0)
    robot_base_xyz_m: tuple[float, float, float] = (-0.05, 0.0, 0.625)
    # Comfortable Panda workspace for tabletop grasps: 0.4-0.65 m ahead, +-0.2 m sideways.
    object_x_range_m: tuple[float, float] = (0.45, 0.65)
    object_y_range_m: tuple[float, float] = (-0.2, 0.2)
    object_yaw_range_rad: tuple[float, float] = (-3.141592653589793, 3.141592653589793)
    settle_steps: int = 240
    seed_base: int = 42
    # PyBullet's default is 50; fixed explicitly so every Scene steps with identical solver settings.
    solver_iterations: int = 100
    # A plain box table gets a wood colour so RGB crops look like a tabletop scene.
    table_rgba: tuple[float, float, float, float] = (0.72, 0.58, 0.42, 1.0)
    # Arm turned to face -x (away from the table) with the elbow folded: clear of all cameras and objects.
    robot_home_joints: tuple[float, ...] = (-2.8, -0.6, 0.0, -2.6, 0.0, 2.0, 0.785)
    # Objects start this far above the table so they never begin interpenetrating it.
    drop_clearance_m: float = 0.002
    distractor_count_range: tuple[int, int] = (3, 4)
    # T3 "within 15 cm of the target": the gap between a distractor's footprint and the target's is at most this.
    distractor_max_distance_m: float = 0.15
    # Footprints (world AABBs in x/y) of placed objects stay at least this far apart.
    distractor_min_gap_m: float = 0.005
    distractor_placement_tries: int = 400


@dataclass
class CameraConfig:
    width_px: int = 640
    height_px: int = 480
    fov_deg: float = 60.0
    near_m: float = 0.01
    far_m: float = 3.0
    # Eye positions relative to the object's resting position; all three look at it.
    overhead_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.55)
    side_offsets_m: tuple[tuple[float, float, float], ...] = ((0.0, 0.45, 0.3), (0.0, -0.45, 0.3))
    # Looking straight down, the overhead image's "up" must be horizontal: +x puts the far table edge at the top.
    overhead_up_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)


# How perception orients normals: toward the camera that saw each point, or the published rule.
NORMAL_ORIENTATIONS = ("camera", "centroid")


@dataclass
class PerceptionConfig:
    normal_radius_m: float = 0.02
    normal_max_neighbours: int = 30
    # "camera" turns each normal toward the camera that saw its point: outward on every visible
    # surface, concave ones too (a handle's inner side, a mug's inner wall), where the published
    # "centroid" rule (away from the cloud centroid) points normals into the material and hides
    # the antipodal pairs across a handle.
    normal_orientation: str = "camera"
    # Points whose normal is within ~6 deg of edge-on to their camera (|cos| < 0.1) take the
    # centroid rule: there the camera's side says nothing (8 of 1,122 sphere normals flipped).
    normal_grazing_cosine: float = 0.1
    min_points: int = 150
    crop_padding_fraction: float = 0.2
    # Merged clouds from three 640x480 views hold ~10-40k points; a 3 mm voxel keeps the
    # geometry (contacts are sampled at 5 mm resolution at best) and bounds planning cost.
    voxel_size_m: float = 0.003

    def __post_init__(self) -> None:
        if self.normal_orientation not in NORMAL_ORIENTATIONS:
            raise ConfigError(
                f"perception.normal_orientation: unknown rule {self.normal_orientation!r} (known: {', '.join(NORMAL_ORIENTATIONS)})"
            )


@dataclass
class PlannerConfig:
    n_pairs: int = 5000
    # The published method fixes how many pairs, not how they are drawn. "guided" (Dex-Net/GPD antipodal sampling)
    # gives ~7x more antipodal pairs (~25x more on a mug handle) and, with the gripper volume screened
    # lazily, keeps plans under 0.25 s on captured clouds; it lifted GO t1 GSR from 87.5 to 90.7 %
    # (the 10 cm coffee can only has usable chord pairs when sampling seeks them). "uniform" is the
    # literal reading, kept for comparison.
    pair_sampling: str = "guided"
    # Second-point proposals per guided pair: 64 doubles the handle pairs of 32 for ~20 ms per 5,000 pairs.
    pair_proposals: int = 64
    # (pair, proposal) combinations the guided sampler holds at once (~80 bytes each, ~80 MB).
    pair_proposal_chunk_elements: int = 1_048_576
    min_width_m: float = 0.005
    max_width_m: float = 0.08
    max_contact_angle_deg: float = 45.0
    n_approaches: int = 8
    occupancy_max_fraction: float = 0.12
    max_candidates: int = 200
    min_reach: float = 0.5
    # Grasp IK solves the Panda's closed form at this many joint-7 values evenly spread over its
    # range (plus the reference posture's), and at the finer count for targets that none of them
    # reaches (a narrow joint-7 window). On FK of 2,000 random in-limit configurations (1 thread)
    # 8 to 24 samples all solve 99.95 %; 16 run ~28,000 targets/s and 12 ~35,000/s, but with 12 the
    # motion check rejects 308 grasps instead of 273 (the sum under ik_limit_margin_rad). A 256
    # fine grid found the one target 128 misses (a 0.012 rad window between two joint limits).
    ik_q7_samples: int = 16
    ik_q7_fine_samples: int = 128
    seed: int = 0
    # The boxes of the published 12 % gripper-volume proxy, sized to the hulls PyBullet collides
    # the hand with (panda.urdf's meshes/collision/{hand,finger}.obj): from the grasp target the
    # finger hulls reach 0.0073 m beyond it, the hand hull's face is 0.039 m short of it and the
    # hull is 0.092 m deep, 0.063 m wide and 0.204 m across; a finger hull is 0.021 m wide, 0.026 m
    # thick at the hand and 0.014 m at the tip. Executability is checked on the hulls themselves
    # (``sagp_batched.hand``), not on these boxes. The fingers' open width is the robot's
    # (``sagp_batched/data/robots/panda.toml``).
    # Each open finger must clear its contact by this much to descend without brushing the object:
    # a 7.9 cm pair under an 8 cm jaw passes the published width filter but hits the fingers in practice.
    jaw_clearance_m: float = 0.005
    finger_width_m: float = 0.021
    # A box needs one thickness: the hull's at mid-length of the 0.046 m that shows below the hand.
    finger_thickness_m: float = 0.02
    finger_length_m: float = 0.046
    fingertip_offset_m: float = 0.007
    palm_width_m: float = 0.065
    palm_span_m: float = 0.204
    palm_depth_m: float = 0.092
    # Cloud points within this of a contact plane belong to the grasped surface (3 mm voxels + normal noise).
    contact_clearance_m: float = 0.004
    # The occupancy fraction is estimated on a seeded subset of at most this many object points
    # (obstacle points thinned at the same rate): standard error ~1 % at the 12 % limit, 2-5x faster.
    occupancy_max_points: int = 1024
    # (candidate, approach, point) triples the occupancy check holds at once: chunks of ~3 MB of
    # float32 coordinates stay in cache and measured 2x faster than 4M-element chunks.
    occupancy_chunk_elements: int = 262_144
    # Damped-least-squares steps for closed-form answers that float32 forward kinematics puts
    # outside the tolerance: none at 5 mm, ~1 % at a 1 um tolerance, which 3 steps bring inside.
    ik_polish_iterations: int = 3
    # Grasp solutions at least this far from every joint limit (or as far as the preferred posture
    # is) are chosen before nearer ones: the motion check's path IK clamps at the limits. Summed
    # over 3 seeds of the cracker box, soup can and mug at 5,000 pairs, motion-check rejections
    # were 460 without a margin and 273 at 0.4 rad (0.2: 358, 0.3: 323, 0.6: 392, measured before
    # the 0.01 rad rounding allowance); the iterative solver this replaced had 234 motion and
    # 1,182 grasp-IK rejections, against 473 grasp-IK rejections now.
    ik_limit_margin_rad: float = 0.4
    # The whole executed motion (pre-grasp, descent, lift) is solved from the grasp solution by
    # damped least squares: waypoints lie at most 20 cm from the grasp; on captured YCB grasps 4
    # steps bring every waypoint within 0.01 mm (3 steps: 0.5 mm, 2 steps miss 15 %).
    path_ik_iterations: int = 5
    # Damping of the damped-least-squares steps of path IK and grasp polish (rad-scale): keeps
    # steps bounded near singular wrist poses.
    ik_damping: float = 0.01
    # The hand's collision hulls (derived from the robot URDF) swept along the descent must keep
    # this far from every object and obstacle point: the cloud's 3 mm voxels put the true surface
    # up to ~2 mm from its points.
    hand_clearance_margin_m: float = 0.003
    # The swept-hand check tests one cloud point per cell of this size (object and obstacles):
    # every surface patch keeps points no farther apart than the 2 cm finger is wide, thin rims
    # included, at a third of the cost of the full 3 mm cloud.
    hand_check_voxel_m: float = 0.006
    # Height the fingers' hulls must keep above the table at the grasp and pre-grasp: soft finger
    # contacts pressing 0.3 mm into the table already push with the 10 N execution calls a
    # collision, and the position-controlled descent overshoots by about a millimetre.
    finger_table_clearance_m: float = 0.002
    # Height every other link (hand, wrist, forearm, elbow) must keep above the table at every
    # waypoint of the motion: PyBullet reports contacts within its 4 mm collision margin.
    arm_table_clearance_m: float = 0.005
    # Links of the arm checked against the table along the motion (links 0-2 stand above the base).
    arm_table_links: tuple[str, ...] = ("panda_link3", "panda_link4", "panda_link5", "panda_link6", "panda_link7", "panda_hand")
    # Cell of the coarse subset of those points probed first (those nearest each swept hand): a
    # 2 cm cell still leaves points on every part the hand could strike, and most blocked grasps
    # hit one of them.
    hand_screen_voxel_m: float = 0.02
    # (candidate, hull, direction, point) elements the swept-hand check holds at once.
    hand_check_chunk_elements: int = 4_194_304

    def __post_init__(self) -> None:
        # Checked here, at load, so a misspelt profile fails before a study starts rather than in every trial.
        if self.pair_sampling not in PAIR_SAMPLING_MODES:
            raise ConfigError(
                f"planner.pair_sampling: unknown mode {self.pair_sampling!r} (known: {', '.join(PAIR_SAMPLING_MODES)})"
            )
        if self.pair_proposals < 1:
            raise ConfigError(f"planner.pair_proposals must be >= 1, got {self.pair_proposals}")


@dataclass
class ScoreWeights:
    geom: float = 0.3
    reach: float = 0.1
    afford: float = 0.3
    avoid: float = 0.2
    task: float = 0.1


GEOMETRY_ONLY_WEIGHTS = ScoreWeights(geom=1.0, reach=0.0, afford=0.0, avoid=0.0, task=0.0)


@dataclass
class ExecutionConfig:
    pregrasp_offset_m: float = 0.10
    lift_height_m: float = 0.20
    hold_steps: int = 80
    settle_steps: int = 60
    ik_iterations: int = 500
    max_attempts: int = 3
    success_height_above_table_m: float = 0.15
    # Straight-line descent from the pre-grasp: IK waypoints, each tracked for steps_per_waypoint steps.
    descent_waypoints: int = 8
    lift_waypoints: int = 10
    steps_per_waypoint: int = 20
    close_steps: int = 120
    # Panda hand: 70 N continuous grip force per the datasheet; enough for the 1.13 kg bleach bottle.
    gripper_force_n: float = 70.0
    # Rubber-like finger pads; PyBullet multiplies this with the object's friction (YCB URDFs: 0.9).
    finger_lateral_friction: float = 1.5
    # Torsional friction of the pads resists tall objects swinging about the closing axis during the lift.
    finger_spinning_friction: float = 0.05
    arm_position_gain: float = 0.3
    # PyBullet IK restarts from seeded random joints inside the limits when the given seeds fail.
    ik_random_restarts: int = 8
    # Neighbouring waypoints are ~1-2 cm apart; a larger joint jump means IK switched branch mid-path.
    max_waypoint_joint_step_rad: float = 0.3
    # A fingertip grazing the table on the way down (grasps on flat objects end millimetres above
    # it) is harmless; pressing on it harder than this during the descent counts as a collision.
    # libfranka's default contact reflex stops the real arm at 20 N; half that stays conservative.
    table_contact_max_force_n: float = 10.0
    # The object moving more than this before the fingers close means the gripper knocked it.
    knock_tolerance_m: float = 0.01
    # A failed attempt whose object rose at least this much during the lift "slipped" rather than "not_lifted".
    lifted_detect_height_m: float = 0.05
    # Camera for record_frames: eye offset from the object's resting position.
    frame_camera_offset_m: tuple[float, float, float] = (0.55, 0.35, 0.35)


# How zones.protrusion_rule finds protrusions: "body" measures points from the vertical axis
# against the body's radius; "centroid" is the published rule (distance from the centroid).
PROTRUSION_RULES = ("body", "centroid")


@dataclass
class ZonesConfig:
    # The published centroid rule turns at most the tip of the YCB mug's handle and none of the
    # pitcher's into a protrusion; measured from the upright body's axis (vertical, through the
    # centre of a circle fitted to the body's wall), points beyond 1.3x its radius were all handle
    # points, ~60 % of the mug's handle and 0.7-0.85 of the pitcher's.
    protrusion_rule: str = "body"
    body_radius_factor: float = 1.3
    # The body rule needs a round wall (the axis distance means nothing on a box): median
    # |distance - radius| / radius measured 0.04-0.08 on captured cans, mug and pitcher, 0.16-0.27
    # on the boxes and oval bottles, which keep the centroid rule.
    body_max_roundness_error: float = 0.12
    # A cloud at least this tall relative to its widest horizontal extent stands upright; lower
    # ones lie on the table. Lying flat (a drill, a marker), distance from the vertical axis is
    # distance along the object, so the body rule applies to upright clouds only.
    body_min_height_ratio: float = 0.5
    # A lying cloud whose horizontal spread is this elongated (sqrt of its principal variances'
    # ratio) is split into thirds along its length instead of layers of its thickness, so a handle
    # end, a middle and a working end are zones a rating can tell apart; its ends are what sticks
    # out, so no protrusions are sought. Measured on the YCB meshes lying in their resting poses:
    # banana 3.2, marker 6.3, scissors 2.3, drill 1.5, clamp 1.4 against round or square
    # footprints (bowl, tuna can 1.0, gelatin and pudding boxes 1.2); on captured clouds (12
    # poses) clamp 1.36-1.47, drill 1.40-1.61, bowl 1.02-1.05, tuna can 1.14, while the small
    # boxes' partial views spread over 1.0-1.42, so they are split either way, harmlessly: their
    # ends are alike. False keeps the published vertical thirds on every cloud.
    length_split: bool = True
    length_split_min_elongation: float = 1.3
    protrusion_distance_factor: float = 1.5
    dbscan_eps_m: float = 0.01
    dbscan_min_samples: int = 10
    min_protrusion_points: int = 20
    # World references that name the zones: the robot stands at -x facing +x, so the object's
    # "front" is the side facing the robot and its "left" is the robot's left (+y).
    up_world: tuple[float, float, float] = (0.0, 0.0, 1.0)
    left_world: tuple[float, float, float] = (0.0, 1.0, 0.0)
    front_world: tuple[float, float, float] = (-1.0, 0.0, 0.0)
    # Fewer points than DBSCAN's own core size cannot hold a stable covariance either.
    min_points: int = 10
    # Eigenvalue ratios (to the largest) under which the cloud counts as a line or a plane.
    collinear_eigen_ratio: float = 1e-3
    flat_eigen_ratio: float = 1e-3
    # Extents under 1 mm are below the 3 mm voxel: such an axis cannot be split into parts.
    min_split_extent_m: float = 0.001
    # Principal axes whose variances differ by under 10% are one principal plane (a mug is about as
    # tall as wide); the direction in it nearest the world reference is taken, not eigh's noisy pick.
    isotropy_tolerance: float = 0.1

    def __post_init__(self) -> None:
        if self.protrusion_rule not in PROTRUSION_RULES:
            raise ConfigError(f"zones.protrusion_rule: unknown rule {self.protrusion_rule!r} (known: {', '.join(PROTRUSION_RULES)})")


@dataclass
class RatingConfig:
    backend: str = "prior"
    model: str = "Qwen/Qwen2.5-VL-3B-Instruct"
    endpoint: str = "http://127.0.0.1:8000/v1"
    api_key_env: str = "OPENAI_API_KEY"
    timeout_s: float = 60.0
    max_retries: int = 2
    cache_dir: str = "~/.cache/sagp_batched/ratings"
    # Hugging Face loads stay on disk unless a profile asks for the hub (no hub on lab machines).
    local_files_only: bool = True
    # A zone-rating JSON answer is ~150 tokens; twice that leaves room without letting a
    # runaway model generate for minutes.
    max_new_tokens: int = 384
    # Exponential backoff between HTTP retries: 0.5 s, 1 s, ...
    retry_backoff_s: float = 0.5
    # Cache on by default so a study asks each (object, task) once.
    use_cache: bool = True
    # Published S_task: approach within 30 deg of the prescribed direction.
    approach_tolerance_deg: float = 30.0
    # "Keep upright" without a number means the functional task's (t2) 15 deg tolerance.
    upright_max_tilt_deg: float = 15.0
    # Tilt predictor: finger friction holds a CoM up to this far (m) off the grasp axis; beyond it the
    # object swings about the closing axis until its CoM hangs below the axis.
    friction_hold_offset_m: float = 0.02
    # VLM-Direct: the published top-20 candidates, drawn on a crop scaled up so 20 numbered markers stay legible.
    vd_num_candidates: int = 20
    vd_image_min_side_px: int = 448
    vd_marker_radius_px: int = 9
    # Set-of-mark prompting: a model cannot tell "protrusion_2" from "middle" by a text description
    # alone; the zones drawn on the image as labelled dots show which part is which. False sends the
    # plain crop (and the unmarked prompt, a separate cache key).
    zone_marks: bool = True
    # Dots small enough that the object stays visible under them; labels as legible as VD's markers.
    zone_mark_dot_radius_px: int = 2
    zone_label_font_px: int = 13


@dataclass
class ShakeConfig:
    """The shake after the lift: the hand oscillates along, then about, each axis of the grasp frame
    (x = closing x approach, y = closing axis, z = approach) in turn, rotations about the grasp
    target. Each axis moves ``A (1 - cos 2 pi f t)`` for ``cycles`` cycles, ``A = peak / (2 pi f)^2``:
    it starts and ends at rest on the lifted pose and its acceleration peaks at the given value."""

    #: Franka's Cartesian acceleration limit (13 m/s^2, 1.3 g): a shake a real Panda can do, a
    #: little harder than GraspDataGen's 1 g tugs.
    linear_peak_acceleration_m_s2: tuple[float, float, float] = (13.0, 13.0, 13.0)
    #: Franka's rotational acceleration limit (25 rad/s^2): 1.3-2.5 m/s^2 more at a centre of mass
    #: 5-10 cm from the fingers, on top of the torque gravity puts on the grip.
    angular_peak_acceleration_rad_s2: tuple[float, float, float] = (25.0, 25.0, 25.0)
    #: 5 Hz: the peaks above move the hand 2.6 cm and 2.9 deg, a cycle is 48 steps at 240 Hz. A
    #: higher frequency is cheaper but gentler, its smaller strokes let marginal pinches hold (a
    #: bleach bottle pinched by its cap that 5 Hz drops keeps its hold at 8 and 10 Hz).
    frequency_hz: float = 5.0
    #: One cycle reverses each axis' acceleration twice, enough for a marginal grip to let go.
    cycles: int = 1
    #: Along and about one axis in the same window: half the steps, but a weaker test (it dropped
    #: 4 of the 7 cap pinches the six windows drop).
    linear_with_angular: bool = False

    def __post_init__(self) -> None:
        for name in ("linear_peak_acceleration_m_s2", "angular_peak_acceleration_rad_s2"):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != 3 or any(v < 0.0 for v in values):
                raise ConfigError(f"labelling.shake.{name} must be 3 non-negative numbers (x, y, z), got {getattr(self, name)!r}")
            setattr(self, name, values)
        if self.frequency_hz <= 0.0:
            raise ConfigError(f"labelling.shake.frequency_hz must be > 0, got {self.frequency_hz}")
        if self.cycles < 1:
            raise ConfigError(f"labelling.shake.cycles must be >= 1, got {self.cycles}")

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
class LabellingConfig:
    """Grasp labels from simulation: the shake both modes end with, and the floating hand's motion.

    Hand mode (``sagp_batched.labelling``) uses the study's pre-grasp offset, lift height, grip
    force, finger friction, collision thresholds and success test from ``[execution]``; how long
    the floating hand takes for each phase is set here."""

    shake: ShakeConfig = field(default_factory=ShakeConfig)
    #: The object is put down at its settled pose in a fresh world: a few steps let its contacts
    #: with the table form before the hand moves.
    hand_settle_steps: int = 12
    #: Pre-grasp to grasp (10 cm) on a half-cosine in 0.2 s: peak speed 0.8 m/s, at rest at the grasp.
    hand_approach_steps: int = 48
    #: The study's fingers close 10 % of their remaining travel a step, onto a 5 mm object in 26
    #: steps; 48 (0.2 s) leave the grip time to settle, and agree with the arm as often as the
    #: study's 120 close steps do.
    hand_close_steps: int = 48
    #: The 20 cm lift on a half-cosine in 0.3 s: peak acceleration 11 m/s^2, below the shake's.
    hand_lift_steps: int = 72
    #: Held still for 0.1 s after the lift, then judged before the shake starts.
    hand_hold_steps: int = 24
    #: Error reduction of the fixed constraint that carries the hand (PyBullet's ``erp``, set in the
    #: hand's world): PyBullet's 0.2 lets the hand trail its target by ~4 steps, short of the
    #: shake's peaks by a tenth; 0.8 follows within a step.
    hand_constraint_erp: float = 0.8
    #: Force the fixed constraint that carries the hand may apply: many times what moving hand
    #: (1 kg) and object (up to 1.1 kg) at the shake's accelerations takes.
    hand_constraint_max_force_n: float = 1000.0
    #: Where the floating hand's URDF (built from the robot's, with absolute mesh paths) is written.
    hand_urdf_cache_dir: str = "~/.cache/sagp_batched/hand"

    def __post_init__(self) -> None:
        for name in ("hand_approach_steps", "hand_close_steps", "hand_lift_steps"):
            if getattr(self, name) < 1:
                raise ConfigError(f"labelling.{name} must be >= 1, got {getattr(self, name)}")


@dataclass
class TaskConfig:
    # Published task definitions: t2 keeps the object within 15 deg of its resting orientation
    # (also the OP metric's threshold), t3 moves no distractor more than 5 cm.
    orientation_tolerance_deg: float = 15.0
    distractor_tolerance_m: float = 0.05


@dataclass
class RunConfig:
    objects: tuple[str, ...] = ("all",)
    tasks: tuple[str, ...] = ("t1", "t2", "t3")
    methods: tuple[str, ...] = ("go", "sagp", "vd")
    n_trials: int = 20
    objects_dir: str | None = None
    out: str = "runs/latest"
    workers: int = 1
    backend: str = "local"
    ray_address: str | None = None
    trial_timeout_s: float = 300.0
    export_grasps: bool = False
    save_frames: bool = False
    gui: bool = False
    # On resume, trials whose record is an error run again unless this keeps them.
    keep_errors: bool = False


@dataclass
class Config:
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    weights: ScoreWeights = field(default_factory=ScoreWeights)
    execution: ExecutionConfig = field(default_factory=ExecutionConfig)
    zones: ZonesConfig = field(default_factory=ZonesConfig)
    rating: RatingConfig = field(default_factory=RatingConfig)
    labelling: LabellingConfig = field(default_factory=LabellingConfig)
    tasks: TaskConfig = field(default_factory=TaskConfig)
    run: RunConfig = field(default_factory=RunConfig)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def override(self, section: str, **values: Any) -> "Config":
        """A copy with ``values`` replacing fields of ``section``; ``None`` values are ignored."""
        return _merge(self, {section: {k: v for k, v in values.items() if v is not None}}, "")


def _coerce(value: Any, template: Any, where: str) -> Any:
    if isinstance(template, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if isinstance(template, (int, float)) and not isinstance(template, bool):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        if isinstance(template, int) and not float(value).is_integer():
            raise ConfigError(f"{where}: expected a whole number, got {value!r}")
        return type(template)(value)
    if isinstance(template, tuple):
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        return tuple(tuple(v) if isinstance(v, list) else v for v in value)
    if isinstance(template, str) and not isinstance(value, str):
        raise ConfigError(f"{where}: expected a string, got {value!r}")
    return value


def _merge(obj: Any, updates: dict[str, Any], prefix: str) -> Any:
    known = {f.name: f for f in dataclasses.fields(obj)}
    changes = {}
    for key, value in updates.items():
        where = f"{prefix}{key}"
        if key not in known:
            raise ConfigError(f"unknown setting '{where}' (known: {', '.join(sorted(known))})")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ConfigError(f"'{where}' must be a table")
            changes[key] = _merge(current, value, f"{where}.")
        elif current is None:
            changes[key] = value
        else:
            changes[key] = _coerce(value, current, where)
    return dataclasses.replace(obj, **changes)


def named_profiles() -> dict[str, Traversable]:
    """The profiles that ship inside the package (``profiles/NAME.toml`` in the checkout), by name."""
    try:
        folder = resources.files(PROFILES_PACKAGE)
    except ModuleNotFoundError as exc:
        raise ConfigError(f"the package's named profiles ({PROFILES_PACKAGE}) are not installed: "
                          "reinstall the package (pip install -e .)") from exc
    return {entry.name.removesuffix(".toml"): entry for entry in folder.iterdir() if entry.name.endswith(".toml")}


def resolve_profile_path(name_or_path: str | Path) -> Traversable:
    """A profile given by name (``paper``, ``ci``, ``datagen``) or by a path to a TOML file."""
    candidate = Path(name_or_path).expanduser()
    given_as_path = candidate.suffix == ".toml" or candidate.exists()
    if given_as_path and candidate.is_file():
        return candidate
    profiles = named_profiles()
    if not given_as_path and str(name_or_path) in profiles:
        return profiles[str(name_or_path)]
    missing = f"no TOML file at {candidate}" if given_as_path else "no such named profile"
    raise ConfigError(f"profile '{name_or_path}' not found: {missing} (named profiles: {', '.join(sorted(profiles))})")


def load_config(profile: str | Path | None = None, overrides: dict[str, dict[str, Any]] | None = None) -> Config:
    """Defaults, then the profile's tables, then ``overrides`` ({section: {field: value}})."""
    config = Config()
    if profile is not None:
        path = resolve_profile_path(profile)
        try:
            data = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"profile {path} is not valid TOML: {exc}") from exc
        config = _merge(config, data, "")
    if overrides:
        config = _merge(config, {s: {k: v for k, v in d.items() if v is not None} for s, d in overrides.items()}, "")
    return config
