"""One configuration type for the whole pipeline, filled from ``profiles/*.toml``.

Every number of the method lives here with the published value as default; a choice the method leaves
open carries a one-line reason. A profile is a TOML file whose tables mirror these dataclasses
(``[scene]``, ``[camera]``, ``[perception]``, ``[planner]``, ``[weights]``, ``[execution]``,
``[zones]``, ``[rating]``, ``[labelling]`` with ``[labelling.shake]``, ``[run]``, ``[dataset]``); command-line flags
override profile values through ``override``.
Each field declares the values it may hold (``setting``: bounds, shape, choices), checked whenever a
section is made, so a profile value and a flag are refused by the same check, by name, before any work.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any, ClassVar

# The checkout's top-level profiles/ folder, installed as this package by pyproject.toml.
PROFILES_PACKAGE = "sagp_batched.profiles"


class ConfigError(ValueError):
    """A profile or override names an unknown key or holds a value of the wrong type or out of range.

    ``setting`` is the ``section.field`` a range check refused, so a caller can name the flag that set it.
    """

    def __init__(self, message: str, setting: str | None = None):
        super().__init__(message)
        self.setting = setting


# Ten times the largest pair count benchmarked (500,000): a larger one is a typo, and two billion
# pairs exhaust memory in every trial.
MAX_PAIRS = 5_000_000
# Trials per (object, task), 5,000 times the published 20: a study plans all its units up front,
# and a billion of them exhaust memory before the first trial.
MAX_TRIALS = 100_000
# More trial processes than any one host or Ray cluster this study runs on has CPUs.
MAX_WORKERS = 1024
# Each view renders RGB, depth and segmentation buffers, ~12 bytes a pixel: ~200 MB a view at 4,096 px a side.
MAX_IMAGE_SIDE_PX = 4096
RUN_BACKENDS = ("local", "ray")
RATING_BACKENDS = ("prior", "transformers", "openai", "oracle")
_ALLOWED = "allowed"


@dataclass(frozen=True)
class Allowed:
    """The values a setting may hold. Every number, a tuple's included, must be finite and within the
    bounds given; ``shape`` fixes a tuple's entry counts level by level (None: any count); ``ordered``
    asks a (low, high) pair for low <= high; ``choices`` lists a string's known values."""

    at_least: float | None = None
    above: float | None = None
    at_most: float | None = None
    below: float | None = None
    shape: tuple[int | None, ...] = ()
    ordered: bool = False
    choices: tuple[str, ...] = ()
    non_empty: bool = False
    unique: bool = False

    def check(self, value: Any, setting: str) -> None:
        """Raises ``ConfigError`` naming ``setting`` (and the entry, for a tuple's) if ``value`` is not allowed."""
        if self.choices:
            if value not in self.choices:
                raise ConfigError(f"{setting}: unknown value {value!r} (known: {', '.join(self.choices)})", setting)
        elif isinstance(value, str):
            if self.non_empty and not value.strip():
                raise ConfigError(f"{setting} must not be empty", setting)
        elif isinstance(value, tuple):
            self._check_entries(value, setting, setting, self.shape)
        else:
            self._check_number(value, setting, setting)

    def _check_entries(self, entries: tuple, where: str, setting: str, shape: tuple[int | None, ...]) -> None:
        if shape and shape[0] is not None and len(entries) != shape[0]:
            raise ConfigError(f"{where} must hold {shape[0]} entries, got {len(entries)}: {list(entries)!r}", setting)
        if self.non_empty and not entries:
            raise ConfigError(f"{where} must list at least one entry, got an empty list", setting)
        if self.unique:
            repeated = next((entry for i, entry in enumerate(entries) if entry in entries[:i]), None)
            if repeated is not None:
                raise ConfigError(f"{where} lists {repeated!r} more than once", setting)
        for i, entry in enumerate(entries):
            if isinstance(entry, tuple):
                self._check_entries(entry, f"{where}[{i}]", setting, shape[1:])
            elif not isinstance(entry, str):
                self._check_number(entry, f"{where}[{i}]", setting)
        if self.ordered and entries[0] > entries[1]:
            raise ConfigError(f"{where} must be a (low, high) pair with low <= high, got {list(entries)!r}", setting)

    def _check_number(self, value: Any, where: str, setting: str) -> None:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ConfigError(f"{where} must be a number, got {value!r}", setting)
        within = (
            math.isfinite(value)
            and (self.at_least is None or value >= self.at_least)
            and (self.above is None or value > self.above)
            and (self.at_most is None or value <= self.at_most)
            and (self.below is None or value < self.below)
        )
        if not within:
            bounds = self.describe_bounds()
            wanted = bounds if math.isfinite(value) else " ".join(filter(None, ("a finite number", bounds)))
            raise ConfigError(f"{where} must be {wanted}, got {value!r}", setting)

    def describe_bounds(self) -> str:
        """The bounds in words ("between 1 and 100", "> 0"); empty when any finite number will do."""
        if self.at_least is not None and self.at_most is not None:
            return f"between {self.at_least:,} and {self.at_most:,}"
        lower = f">= {self.at_least:,}" if self.at_least is not None else f"> {self.above:,}" if self.above is not None else ""
        upper = f"<= {self.at_most:,}" if self.at_most is not None else f"< {self.below:,}" if self.below is not None else ""
        return " and ".join(filter(None, (lower, upper)))


def setting(default: Any, **allowed: Any) -> Any:
    """A config field defaulting to ``default`` whose values must be as ``Allowed(**allowed)`` says."""
    return field(default=default, metadata={_ALLOWED: Allowed(**allowed)})


class _Section:
    """A table of the config. Its fields declared with ``setting`` are checked whenever it is made (the
    defaults, a profile, a flag, ``dataclasses.replace``, a direct call), so all go through one check."""

    SECTION: ClassVar[str]

    def __post_init__(self) -> None:
        for declared in dataclasses.fields(self):  # type: ignore[arg-type]
            allowed = declared.metadata.get(_ALLOWED)
            if allowed is not None:
                allowed.check(getattr(self, declared.name), f"{self.SECTION}.{declared.name}")


# How planner.pair_sampling draws the method's contact pairs: uniformly, or antipodally guided.
PAIR_SAMPLING_MODES = ("uniform", "guided")


@dataclass
class SceneConfig(_Section):
    SECTION = "scene"

    time_step_s: float = setting(1.0 / 240.0, above=0)
    gravity_m_s2: float = setting(-9.81)
    table_size_m: tuple[float, float] = setting((1.2, 0.8), above=0, shape=(2,))
    table_top_z_m: float = setting(0.625, above=0)
    # Table centre in world x/y; the robot's base stands at its near long edge, facing +x.
    table_center_xy_m: tuple[float, float] = setting((0.5, 0.0), shape=(2,))
    # The robot (``sagp_batched/data/robots/<robot>.toml``): its URDF, joints, links, base pose,
    # home joints, tolerances and gripper boxes.
    robot: str = setting("panda", non_empty=True)
    # Comfortable Panda workspace for tabletop grasps: 0.4-0.65 m ahead, +-0.2 m sideways.
    object_x_range_m: tuple[float, float] = setting((0.45, 0.65), shape=(2,), ordered=True)
    object_y_range_m: tuple[float, float] = setting((-0.2, 0.2), shape=(2,), ordered=True)
    object_yaw_range_rad: tuple[float, float] = setting((-3.141592653589793, 3.141592653589793), shape=(2,), ordered=True)
    settle_steps: int = setting(240, at_least=0)
    seed_base: int = setting(42, at_least=0)
    # PyBullet's default is 50; fixed explicitly so every Scene steps with identical solver settings.
    solver_iterations: int = setting(100, at_least=1)
    # A plain box table gets a wood colour so RGB crops look like a tabletop scene.
    table_rgba: tuple[float, float, float, float] = setting((0.72, 0.58, 0.42, 1.0), at_least=0, at_most=1, shape=(4,))
    # Objects start this far above the table so they never begin interpenetrating it.
    drop_clearance_m: float = setting(0.002, at_least=0)
    distractor_count_range: tuple[int, int] = setting((3, 4), at_least=0, shape=(2,), ordered=True)
    # T3 "within 15 cm of the target": the gap between a distractor's footprint and the target's is at most this.
    distractor_max_distance_m: float = setting(0.15, above=0)
    # Footprints (world AABBs in x/y) of placed objects stay at least this far apart.
    distractor_min_gap_m: float = setting(0.005, at_least=0)
    distractor_placement_tries: int = setting(400, at_least=1)


@dataclass
class CameraConfig(_Section):
    SECTION = "camera"

    width_px: int = setting(640, at_least=1, at_most=MAX_IMAGE_SIDE_PX)
    height_px: int = setting(480, at_least=1, at_most=MAX_IMAGE_SIDE_PX)
    fov_deg: float = setting(60.0, above=0, below=180)
    near_m: float = setting(0.01, above=0)
    far_m: float = setting(3.0, above=0)
    # Eye positions relative to the object's resting position; all three look at it.
    overhead_offset_m: tuple[float, float, float] = setting((0.0, 0.0, 0.55), shape=(3,))
    side_offsets_m: tuple[tuple[float, float, float], ...] = setting(((0.0, 0.45, 0.3), (0.0, -0.45, 0.3)), shape=(None, 3))
    # Looking straight down, the overhead image's "up" must be horizontal: +x puts the far table edge at the top.
    overhead_up_axis: tuple[float, float, float] = setting((1.0, 0.0, 0.0), shape=(3,))


# How perception orients normals: toward the camera that saw each point, or the published rule.
NORMAL_ORIENTATIONS = ("camera", "centroid")


@dataclass
class PerceptionConfig(_Section):
    SECTION = "perception"

    normal_radius_m: float = setting(0.02, above=0)
    normal_max_neighbours: int = setting(30, at_least=3)
    # "camera" turns each normal toward the camera that saw its point: outward on every visible
    # surface, concave ones too (a handle's inner side, a mug's inner wall), where the published
    # "centroid" rule (away from the cloud centroid) points normals into the material and hides
    # the antipodal pairs across a handle.
    normal_orientation: str = setting("camera", choices=NORMAL_ORIENTATIONS)
    # Points whose normal is within ~6 deg of edge-on to their camera (|cos| < 0.1) take the
    # centroid rule: there the camera's side says nothing (8 of 1,122 sphere normals flipped).
    normal_grazing_cosine: float = setting(0.1, at_least=0, at_most=1)
    min_points: int = setting(150, at_least=1)
    crop_padding_fraction: float = setting(0.2, at_least=0)
    # Merged clouds from three 640x480 views hold ~10-40k points; a 3 mm voxel keeps the
    # geometry (contacts are sampled at 5 mm resolution at best) and bounds planning cost.
    voxel_size_m: float = setting(0.003, above=0)


@dataclass
class PlannerConfig(_Section):
    SECTION = "planner"

    n_pairs: int = setting(5000, at_least=1, at_most=MAX_PAIRS)
    # The published method fixes how many pairs, not how they are drawn. "guided" (Dex-Net/GPD antipodal sampling)
    # gives ~7x more antipodal pairs (~25x more on a mug handle) and, with the gripper volume screened
    # lazily, keeps plans under 0.25 s on captured clouds; it lifted GO t1 GSR from 87.5 to 90.7 %
    # (the 10 cm coffee can only has usable chord pairs when sampling seeks them). "uniform" is the
    # literal reading, kept for comparison.
    pair_sampling: str = setting("guided", choices=PAIR_SAMPLING_MODES)
    # Second-point proposals per guided pair: 64 doubles the handle pairs of 32 for ~20 ms per 5,000 pairs.
    pair_proposals: int = setting(64, at_least=1)
    # (pair, proposal) combinations the guided sampler holds at once (~80 bytes each, ~80 MB).
    pair_proposal_chunk_elements: int = setting(1_048_576, at_least=1)
    min_width_m: float = setting(0.005, at_least=0)
    max_width_m: float = setting(0.08, above=0)
    max_contact_angle_deg: float = setting(45.0, at_least=0, at_most=90)
    n_approaches: int = setting(8, at_least=1)
    occupancy_max_fraction: float = setting(0.12, at_least=0, at_most=1)
    max_candidates: int = setting(200, at_least=1)
    min_reach: float = setting(0.5, at_least=0, at_most=1)
    seed: int = setting(0, at_least=0)
    # Each open finger must clear its contact by this much to descend without brushing the object:
    # a 7.9 cm pair under an 8 cm jaw passes the published width filter but hits the fingers in practice.
    jaw_clearance_m: float = setting(0.005, at_least=0)
    # Cloud points within this of a contact plane belong to the grasped surface (3 mm voxels + normal noise).
    contact_clearance_m: float = setting(0.004, at_least=0)
    # The occupancy fraction is estimated on a seeded subset of at most this many object points
    # (obstacle points thinned at the same rate): standard error ~1 % at the 12 % limit, 2-5x faster.
    occupancy_max_points: int = setting(1024, at_least=1)
    # (candidate, approach, point) triples the occupancy check holds at once: chunks of ~3 MB of
    # float32 coordinates stay in cache and measured 2x faster than 4M-element chunks.
    occupancy_chunk_elements: int = setting(262_144, at_least=1)
    # The hand's collision hulls (derived from the robot URDF) swept along the descent must keep
    # this far from every object and obstacle point: the cloud's 3 mm voxels put the true surface
    # up to ~2 mm from its points.
    hand_clearance_margin_m: float = setting(0.003, at_least=0)
    # The swept-hand check tests one cloud point per cell of this size (object and obstacles):
    # every surface patch keeps points no farther apart than the 2 cm finger is wide, thin rims
    # included, at a third of the cost of the full 3 mm cloud.
    hand_check_voxel_m: float = setting(0.006, above=0)
    # Height the fingers' hulls must keep above the table at the grasp and pre-grasp: soft finger
    # contacts pressing 0.3 mm into the table already push with the 10 N execution calls a
    # collision, and the position-controlled descent overshoots by about a millimetre.
    finger_table_clearance_m: float = setting(0.002, at_least=0)
    # Height every other link (hand, wrist, forearm, elbow) must keep above the table at every
    # waypoint of the motion: PyBullet reports contacts within its 4 mm collision margin.
    arm_table_clearance_m: float = setting(0.005, at_least=0)
    # Cell of the coarse subset of those points probed first (those nearest each swept hand): a
    # 2 cm cell still leaves points on every part the hand could strike, and most blocked grasps
    # hit one of them.
    hand_screen_voxel_m: float = setting(0.02, above=0)
    # (candidate, hull, direction, point) elements the swept-hand check holds at once.
    hand_check_chunk_elements: int = setting(4_194_304, at_least=1)


@dataclass
class IKConfig(_Section):
    """The batched IK's settings: they, with the robot, make one ``PandaIK`` (built once and shared)."""

    SECTION = "ik"

    # Grasp IK solves the Panda's closed form at this many joint-7 values evenly spread over its
    # range (plus the reference posture's), and at the finer count for targets that none of them
    # reaches (a narrow joint-7 window). On FK of 2,000 random in-limit configurations (1 thread)
    # 8 to 24 samples all solve 99.95 %; 16 run ~28,000 targets/s and 12 ~35,000/s, but with 12 the
    # motion check rejects 308 grasps instead of 273 (the sum under limit_margin_rad). A 256
    # fine grid found the one target 128 misses (a 0.012 rad window between two joint limits).
    q7_samples: int = setting(16, at_least=1)
    q7_fine_samples: int = setting(128, at_least=1)
    # Damped-least-squares steps for closed-form answers that float32 forward kinematics puts
    # outside the tolerance: none at 5 mm, ~1 % at a 1 um tolerance, which 3 steps bring inside.
    polish_iterations: int = setting(3, at_least=0)
    # Grasp solutions at least this far from every joint limit (or as far as the preferred posture
    # is) are chosen before nearer ones: the motion check's path IK clamps at the limits. Summed
    # over 3 seeds of the cracker box, soup can and mug at 5,000 pairs, motion-check rejections
    # were 460 without a margin and 273 at 0.4 rad (0.2: 358, 0.3: 323, 0.6: 392, measured before
    # the 0.01 rad rounding allowance); the iterative solver this replaced had 234 motion and
    # 1,182 grasp-IK rejections, against 473 grasp-IK rejections now.
    limit_margin_rad: float = setting(0.4, at_least=0)
    # The whole executed motion (pre-grasp, descent, lift) is solved from the grasp solution by
    # damped least squares: waypoints lie at most 20 cm from the grasp; on captured YCB grasps 4
    # steps bring every waypoint within 0.01 mm (3 steps: 0.5 mm, 2 steps miss 15 %).
    path_iterations: int = setting(5, at_least=0)
    # Damping of the damped-least-squares steps of path IK and grasp polish (rad-scale): keeps
    # steps bounded near singular wrist poses.
    damping: float = setting(0.01, above=0)


@dataclass
class ScoreWeights(_Section):
    SECTION = "weights"

    geom: float = setting(0.3, at_least=0)
    reach: float = setting(0.1, at_least=0)
    afford: float = setting(0.3, at_least=0)
    avoid: float = setting(0.2, at_least=0)
    task: float = setting(0.1, at_least=0)


GEOMETRY_ONLY_WEIGHTS = ScoreWeights(geom=1.0, reach=0.0, afford=0.0, avoid=0.0, task=0.0)


@dataclass
class ExecutionConfig(_Section):
    SECTION = "execution"

    pregrasp_offset_m: float = setting(0.10, above=0)
    lift_height_m: float = setting(0.20, above=0)
    hold_steps: int = setting(80, at_least=0)
    settle_steps: int = setting(60, at_least=0)
    ik_iterations: int = setting(500, at_least=1)
    max_attempts: int = setting(3, at_least=1)
    success_height_above_table_m: float = setting(0.15, above=0)
    # Straight-line descent from the pre-grasp: IK waypoints, each tracked for steps_per_waypoint steps.
    descent_waypoints: int = setting(8, at_least=1)
    lift_waypoints: int = setting(10, at_least=1)
    steps_per_waypoint: int = setting(20, at_least=1)
    close_steps: int = setting(120, at_least=1)
    # Panda hand: 70 N continuous grip force per the datasheet; enough for the 1.13 kg bleach bottle.
    gripper_force_n: float = setting(70.0, above=0)
    # Rubber-like finger pads; PyBullet multiplies this with the object's friction (YCB URDFs: 0.9).
    finger_lateral_friction: float = setting(1.5, at_least=0)
    # Torsional friction of the pads resists tall objects swinging about the closing axis during the lift.
    finger_spinning_friction: float = setting(0.05, at_least=0)
    arm_position_gain: float = setting(0.3, above=0, at_most=1)
    # PyBullet IK restarts from seeded random joints inside the limits when the given seeds fail.
    ik_random_restarts: int = setting(8, at_least=0)
    # Neighbouring waypoints are ~1-2 cm apart; a larger joint jump means IK switched branch mid-path.
    max_waypoint_joint_step_rad: float = setting(0.3, above=0)
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


# How zones.protrusion_rule finds protrusions: "body" measures points from the vertical axis
# against the body's radius; "centroid" is the published rule (distance from the centroid).
PROTRUSION_RULES = ("body", "centroid")


@dataclass
class ZonesConfig(_Section):
    SECTION = "zones"

    # The published centroid rule turns at most the tip of the YCB mug's handle and none of the
    # pitcher's into a protrusion; measured from the upright body's axis (vertical, through the
    # centre of a circle fitted to the body's wall), points beyond 1.3x its radius were all handle
    # points, ~60 % of the mug's handle and 0.7-0.85 of the pitcher's.
    protrusion_rule: str = setting("body", choices=PROTRUSION_RULES)
    body_radius_factor: float = setting(1.3, above=0)
    # The body rule needs a round wall (the axis distance means nothing on a box): median
    # |distance - radius| / radius measured 0.04-0.08 on captured cans, mug and pitcher, 0.16-0.27
    # on the boxes and oval bottles, which keep the centroid rule.
    body_max_roundness_error: float = setting(0.12, at_least=0)
    # A cloud at least this tall relative to its widest horizontal extent stands upright; lower
    # ones lie on the table. Lying flat (a drill, a marker), distance from the vertical axis is
    # distance along the object, so the body rule applies to upright clouds only.
    body_min_height_ratio: float = setting(0.5, above=0)
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
    length_split_min_elongation: float = setting(1.3, at_least=1)
    protrusion_distance_factor: float = setting(1.5, above=0)
    dbscan_eps_m: float = setting(0.01, above=0)
    dbscan_min_samples: int = setting(10, at_least=1)
    min_protrusion_points: int = setting(20, at_least=1)
    # World references that name the zones: the robot stands at -x facing +x, so the object's
    # "front" is the side facing the robot and its "left" is the robot's left (+y).
    up_world: tuple[float, float, float] = setting((0.0, 0.0, 1.0), shape=(3,))
    left_world: tuple[float, float, float] = setting((0.0, 1.0, 0.0), shape=(3,))
    front_world: tuple[float, float, float] = setting((-1.0, 0.0, 0.0), shape=(3,))
    # Fewer points than DBSCAN's own core size cannot hold a stable covariance either.
    min_points: int = setting(10, at_least=1)
    # Eigenvalue ratios (to the largest) under which the cloud counts as a line or a plane.
    collinear_eigen_ratio: float = setting(1e-3, at_least=0, at_most=1)
    flat_eigen_ratio: float = setting(1e-3, at_least=0, at_most=1)
    # Extents under 1 mm are below the 3 mm voxel: such an axis cannot be split into parts.
    min_split_extent_m: float = setting(0.001, at_least=0)
    # Principal axes whose variances differ by under 10% are one principal plane (a mug is about as
    # tall as wide); the direction in it nearest the world reference is taken, not eigh's noisy pick.
    isotropy_tolerance: float = setting(0.1, at_least=0)


@dataclass
class RatingConfig(_Section):
    SECTION = "rating"

    backend: str = setting("prior", choices=RATING_BACKENDS)
    model: str = "Qwen/Qwen2.5-VL-3B-Instruct"
    endpoint: str = "http://127.0.0.1:8000/v1"
    api_key_env: str = "OPENAI_API_KEY"
    timeout_s: float = setting(60.0, above=0)
    max_retries: int = setting(2, at_least=0)
    cache_dir: str = "~/.cache/sagp_batched/ratings"
    # Hugging Face loads stay on disk unless a profile asks for the hub (no hub on lab machines).
    local_files_only: bool = True
    # A zone-rating JSON answer is ~150 tokens; twice that leaves room without letting a
    # runaway model generate for minutes.
    max_new_tokens: int = setting(384, at_least=1)
    # Exponential backoff between HTTP retries: 0.5 s, 1 s, ...
    retry_backoff_s: float = setting(0.5, at_least=0)
    # Cache on by default so a study asks each (object, task) once.
    use_cache: bool = True
    # Published S_task: approach within 30 deg of the prescribed direction.
    approach_tolerance_deg: float = setting(30.0, at_least=0, at_most=180)
    # "Keep upright" without a number means the functional task's (t2) 15 deg tolerance.
    upright_max_tilt_deg: float = setting(15.0, at_least=0, at_most=180)
    # Tilt predictor: finger friction holds a CoM up to this far (m) off the grasp axis; beyond it the
    # object swings about the closing axis until its CoM hangs below the axis.
    friction_hold_offset_m: float = setting(0.02, at_least=0)
    # VLM-Direct: the published top-20 candidates, drawn on a crop scaled up so 20 numbered markers stay legible.
    vd_num_candidates: int = setting(20, at_least=1)
    vd_image_min_side_px: int = setting(448, at_least=1)
    vd_marker_radius_px: int = setting(9, at_least=1)
    # Set-of-mark prompting: a model cannot tell "protrusion_2" from "middle" by a text description
    # alone; the zones drawn on the image as labelled dots show which part is which. False sends the
    # plain crop (and the unmarked prompt, a separate cache key).
    zone_marks: bool = True
    # Dots small enough that the object stays visible under them; labels as legible as VD's markers.
    zone_mark_dot_radius_px: int = setting(2, at_least=1)
    zone_label_font_px: int = setting(13, at_least=1)


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
class LabellingConfig(_Section):
    """Grasp labels from simulation: the shake both modes end with, and the floating hand's motion.

    Hand mode (``sagp_batched.labelling``) uses the study's pre-grasp offset, lift height, grip
    force, finger friction, collision thresholds and success test from ``[execution]``; how long
    the floating hand takes for each phase is set here."""

    SECTION = "labelling"

    shake: ShakeConfig = field(default_factory=ShakeConfig)
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
    #: Error reduction of the fixed constraint that carries the hand (PyBullet's ``erp``, set in the
    #: hand's world): PyBullet's 0.2 lets the hand trail its target by ~4 steps, short of the
    #: shake's peaks by a tenth; 0.8 follows within a step.
    hand_constraint_erp: float = setting(0.8, above=0, at_most=1)
    #: Force the fixed constraint that carries the hand may apply: many times what moving hand
    #: (1 kg) and object (up to 1.1 kg) at the shake's accelerations takes.
    hand_constraint_max_force_n: float = setting(1000.0, above=0)
    #: Where the floating hand's URDF and the objects' collision-only URDFs (absolute mesh paths) are written.
    hand_urdf_cache_dir: str = setting("~/.cache/sagp_batched/hand", non_empty=True)


@dataclass
class TaskConfig(_Section):
    SECTION = "tasks"

    # Published task definitions: t2 keeps the object within 15 deg of its resting orientation
    # (also the OP metric's threshold), t3 moves no distractor more than 5 cm.
    orientation_tolerance_deg: float = setting(15.0, at_least=0, at_most=180)
    distractor_tolerance_m: float = setting(0.05, at_least=0)


@dataclass
class RunConfig(_Section):
    SECTION = "run"

    objects: tuple[str, ...] = setting(("all",), non_empty=True, unique=True)
    tasks: tuple[str, ...] = setting(("t1", "t2", "t3"), non_empty=True, unique=True)
    methods: tuple[str, ...] = setting(("go", "sagp", "vd"), non_empty=True, unique=True)
    n_trials: int = setting(20, at_least=1, at_most=MAX_TRIALS)
    objects_dir: str | None = None
    out: str = setting("runs/latest", non_empty=True)
    workers: int = setting(1, at_least=1, at_most=MAX_WORKERS)
    backend: str = setting("local", choices=RUN_BACKENDS)
    ray_address: str | None = None
    trial_timeout_s: float = setting(300.0, above=0)
    export_grasps: bool = False
    save_frames: bool = False
    gui: bool = False
    # On resume, trials whose record is an error run again unless this keeps them.
    keep_errors: bool = False


@dataclass
class DatasetConfig(_Section):
    """How a labelled grasp dataset picks its grasps (``verdicts.classify_grasps``)."""

    SECTION = "dataset"

    # Grasps closer than this and turned less than nms_rotation_deg count as one: the dataset's
    # grasps are chosen to differ by at least that much (graspnetAPI's pose-space suppression).
    nms_translation_m: float = setting(0.01, at_least=0)
    nms_rotation_deg: float = setting(20.0, at_least=0, at_most=180)
    # Share of each object's labelled grasps the planner calls feasible; the rest are drawn evenly
    # from its rejection verdicts (table, volume, swept hand, grasp IK, motion): the negatives and
    # the planner's calibration.
    feasible_fraction: float = setting(0.5, at_least=0, at_most=1)
    grasps_per_object: int = setting(500, at_least=1, at_most=100_000)
    # "hand": the Panda hand alone moved along the approach (cheap, the arm's reach aside);
    # "arm": the Panda executes the planned joint path, as the study does.
    mode: str = setting("hand", choices=("hand", "arm"))
    # Each capture places the object at a fresh seeded position and yaw on the table (and, for an
    # object with several stable resting poses, in the next of them); its grasps share one plan.
    captures_per_object: int = setting(2, at_least=1, at_most=100)
    # Grasps a worker simulates as one piece of work: one object's grasps spread over every worker
    # in pieces this size (labels do not depend on it).
    grasps_per_chunk: int = setting(50, at_least=1, at_most=100_000)
    seed: int = setting(1000, at_least=0)
    # Share of objects GraspGen's valid.txt lists, chosen by a hash of the object id.
    valid_fraction: float = setting(0.2, at_least=0, at_most=1)


@dataclass
class Config:
    scene: SceneConfig = field(default_factory=SceneConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    ik: IKConfig = field(default_factory=IKConfig)
    weights: ScoreWeights = field(default_factory=ScoreWeights)
    execution: ExecutionConfig = field(default_factory=ExecutionConfig)
    zones: ZonesConfig = field(default_factory=ZonesConfig)
    rating: RatingConfig = field(default_factory=RatingConfig)
    labelling: LabellingConfig = field(default_factory=LabellingConfig)
    tasks: TaskConfig = field(default_factory=TaskConfig)
    run: RunConfig = field(default_factory=RunConfig)
    dataset: DatasetConfig = field(default_factory=DatasetConfig)

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
        # Entries take the type of the default's entries: [1, 2] for a pair of floats is (1.0, 2.0), ["a"] for one is refused.
        if not template:
            return tuple(value)
        return tuple(_coerce(entry, template[0], f"{where}[{i}]") for i, entry in enumerate(value))
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
            # The settings that default to None (run.objects_dir, run.ray_address) name a path or an address.
            if not isinstance(value, str):
                raise ConfigError(f"{where}: expected a string, got {value!r}")
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
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except UnicodeDecodeError as exc:
            raise ConfigError(f"profile {path} is not UTF-8 text (byte {exc.start}: {exc.object[exc.start:exc.end]!r})") from exc
        except OSError as exc:
            raise ConfigError(f"cannot read profile {path}: {exc.strerror or exc}") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"profile {path} is not valid TOML: {exc}") from exc
        try:
            config = _merge(config, data, "")
        except ConfigError as exc:
            raise ConfigError(f"profile {path}: {exc}", exc.setting) from exc
    if overrides:
        config = _merge(config, {s: {k: v for k, v in d.items() if v is not None} for s, d in overrides.items()}, "")
    from .robot import load_robot  # the robot module reads config types: imported here, not at the top

    load_robot(config.scene.robot)  # a robot no file describes is refused before any work
    return config
