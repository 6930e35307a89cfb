"""The planner's sections: the contact-pair search and its screens, the batched IK, and the score weights."""
from __future__ import annotations

import re
from dataclasses import dataclass

from .settings import ConfigError, _Section, setting
from .world import GRIPPERS

# Ten times the largest pair count benchmarked (500,000): a larger one is a typo, and two billion
# pairs exhaust memory in every trial.
MAX_PAIRS = 5_000_000
# How planner.pair_sampling draws the method's contact pairs: uniformly, or antipodally guided.
PAIR_SAMPLING_MODES = ("uniform", "guided")
# How a plan searches its candidates for each one's first executable approach: in rounds sized by
# the survival seen so far (few wasted checks, many small calls), or in blocks of a few fixed sizes
# (every verdict of a block at once, a few call shapes). The same grasps either way.
PLANNER_SEARCHES = ("lookahead", "blocks")
# The torch devices a plan may run on: the CPU, or a CUDA device (``cuda`` is the current one).
PLANNER_DEVICE_PATTERN = re.compile(r"cpu|cuda(:\d+)?")


@dataclass
class PlannerConfig(_Section):
    SECTION = "planner"

    # The gripper planned for (``sagp_batched/data/grippers/<gripper>.toml``); the arm's IK and motion checks
    # apply only to the one the robot carries.
    gripper: str = setting("franka_panda", choices=GRIPPERS)
    n_pairs: int = setting(5000, at_least=1, at_most=MAX_PAIRS)
    # The published method fixes how many pairs, not how they are drawn. "guided" (Dex-Net/GPD antipodal sampling)
    # gives ~7x more antipodal pairs (~25x more on a mug handle) and, with the gripper volume screened
    # lazily, costs plans little on captured clouds; it lifts GO t1 GSR from 87.5 to 90.7 %
    # (the 10 cm coffee can only has usable chord pairs when sampling seeks them). "uniform" is the
    # literal reading, kept for comparison.
    pair_sampling: str = setting("guided", choices=PAIR_SAMPLING_MODES)
    # Second-point proposals per guided pair: 64 doubles the handle pairs of 32 at little cost.
    pair_proposals: int = setting(64, at_least=1)
    min_width_m: float = setting(0.005, at_least=0)
    # The widest contact pair drawn; 0: the gripper's opening (``planner.gripper``).
    max_width_m: float = setting(0.0, at_least=0)
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
    # (obstacle points thinned at the same rate): standard error ~1 % at the 12 % limit, counting a
    # fraction of a dense cloud's points.
    occupancy_max_points: int = setting(1024, at_least=1)
    # The hand's collision hulls (derived from the robot URDF) swept along the descent must keep
    # this far from every object and obstacle point: the cloud's 3 mm voxels put the true surface
    # up to ~2 mm from its points.
    hand_clearance_margin_m: float = setting(0.003, at_least=0)
    # The swept-hand check tests one cloud point per cell of this size (object and obstacles):
    # every surface patch keeps points no farther apart than the 2 cm finger is wide, thin rims
    # included, with far fewer points than the full 3 mm cloud.
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
    #: Compile the screens' long element-wise chains (the gripper volume's and the swept hand's
    #: bounds) with torch.compile (inductor): the same verdicts. Off by default: see the README's
    #: planner benchmark for what it costs and buys on a CPU.
    compile: bool = False
    #: ``lookahead`` or ``blocks`` (``PLANNER_SEARCHES``): which search finds each candidate's first
    #: executable approach; both give the same grasps and counts.
    search: str = setting("lookahead", choices=PLANNER_SEARCHES)
    #: Where the plan's tensors live: ``cpu`` or ``cuda`` (``cuda:N``). Clouds are moved there and the
    #: results come back to the clouds' own device; the random draws stay on a CPU generator, so a
    #: seed draws the same pairs on every device.
    device: str = setting("cpu", non_empty=True)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not PLANNER_DEVICE_PATTERN.fullmatch(self.device):
            raise ConfigError(f"planner.device: unknown device {self.device!r} (known: cpu, cuda, cuda:N)", "planner.device")


@dataclass
class MemoryConfig(_Section):
    """How many elements the planner's batched kernels hold at once. These bound memory and set
    speed only: every plan is the same at any value. They are upper bounds: a kernel works in
    smaller blocks of its own where those suit the cache (its ``*_BLOCK_ELEMENTS`` constants)."""

    SECTION = "memory"

    # (pair, proposal) combinations the guided sampler holds at once (~80 bytes each, ~80 MB).
    pair_proposal_chunk_elements: int = setting(1_048_576, at_least=1)
    # (candidate, approach, point) triples the occupancy check holds at once: chunks of ~3 MB of
    # float32 coordinates stay in the cache.
    occupancy_chunk_elements: int = setting(262_144, at_least=1)
    # (candidate, hull, direction, point) elements the swept-hand check holds at once.
    hand_check_chunk_elements: int = setting(4_194_304, at_least=1)


@dataclass
class IKConfig(_Section):
    """The batched IK's settings: they, with the robot, make one ``PandaIK`` (built once and shared)."""

    SECTION = "ik"

    # Grasp IK solves the Panda's closed form at this many joint-7 values evenly spread over its
    # range (plus the reference posture's), and at the finer count for targets that none of them
    # reaches (a narrow joint-7 window). On FK of 2,000 random in-limit configurations 8 to 24
    # samples all solve 99.95 %; fewer samples solve faster, but with 12 the motion check rejects
    # 308 grasps instead of 273 (the sum under limit_margin_rad). A 256 fine grid finds the one
    # target 128 misses (a 0.012 rad window between two joint limits).
    q7_samples: int = setting(16, at_least=1)
    q7_fine_samples: int = setting(128, at_least=1)
    # Damped-least-squares steps for closed-form answers that float32 forward kinematics puts
    # outside the tolerance: none at 5 mm, ~1 % at a 1 um tolerance, which 3 steps bring inside.
    polish_iterations: int = setting(3, at_least=0)
    # Grasp solutions at least this far from every joint limit (or as far as the preferred posture
    # is) are chosen before nearer ones: the motion check's path IK clamps at the limits. Summed
    # over 3 seeds of the cracker box, soup can and mug at 5,000 pairs, motion-check rejections
    # are fewest at 0.4 rad: 273, against 460 without a margin (0.2: 358, 0.3: 323, 0.6: 392).
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
