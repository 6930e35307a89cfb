"""The run's sections: which units a study runs and where (``[run]``), and how a grasp dataset picks its grasps."""
from __future__ import annotations

import os
from dataclasses import dataclass

from .settings import ConfigError, _Section, setting


def available_cores() -> int:
    """The CPUs this process may run on: its affinity mask where the platform has one (a container's or a
    ``taskset``'s share of the machine), else every CPU the machine has; at most ``MAX_WORKERS``."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # macOS and Windows have no affinity call
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_WORKERS))


# Trials per (object, task), 5,000 times the published 20: a study plans all its units up front,
# and a billion of them exhaust memory before the first trial.
MAX_TRIALS = 100_000
# More trial processes than any one host or Ray cluster this study runs on has CPUs.
MAX_WORKERS = 1024
RUN_BACKENDS = ("local", "ray")
# The engines a hand-mode label can be simulated by (``datasets.engines``).
LABEL_ENGINES = ("pybullet", "mujoco")
# The protocols a hand-mode label can follow (``datasets.protocols.PROTOCOLS``, by these names).
LABEL_PROTOCOLS = ("tabletop", "floating")


@dataclass
class RunConfig(_Section):
    SECTION = "run"

    objects: tuple[str, ...] = setting(("all",), non_empty=True, unique=True)
    tasks: tuple[str, ...] = setting(("t1", "t2", "t3"), non_empty=True, unique=True)
    methods: tuple[str, ...] = setting(("go", "sagp", "vd"), non_empty=True, unique=True)
    n_trials: int = setting(20, at_least=1, at_most=MAX_TRIALS)
    objects_dir: str | None = None
    out: str = setting("runs/latest", non_empty=True)
    # Trial (or labelling) processes: by default one a core this process may use. Records and labels
    # do not depend on the count, so the default only decides how fast a run is.
    workers: int = setting(default_factory=available_cores, at_least=1, at_most=MAX_WORKERS)
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
    # What a hand-mode label simulates (``datasets.protocols``): "tabletop", the object where it
    # settled on the table and the hand approaching from the pre-grasp; "floating", ACRONYM's: the
    # object alone, the hand closing at the grasp, grasps sampled around the whole object.
    protocol: str = setting("tabletop", choices=LABEL_PROTOCOLS)
    # The engines every hand-mode grasp is labelled in: with more than one, the dataset's label is
    # held in all of them (a label one simulator gives and another does not is the simulator's), and
    # each engine's own is kept beside it. PyBullet is the study's execution engine.
    engines: tuple[str, ...] = setting(("pybullet",), non_empty=True, unique=True)
    # Share of each object's grasps, at most, taken from each verdict geometry alone fails
    # (``protocols.LabelProtocol.geometry_verdicts``: the hand through the table, or in the object's points).
    geometry_verdict_fraction: float = setting(0.05, at_least=0, at_most=1)
    # Share of a floating dataset's grasps that are clear grasps moved toward failure
    # (``boundary_grasps``): the picked grasps alone hold 88-98 %, and a learner needs the
    # negatives beside them.
    boundary_fraction: float = setting(0.3, at_least=0, at_most=1)
    # A boundary variant withdrawn along its approach by a depth in this range: the Panda's pads
    # reach 7 mm past the grasp centre, so the object ends at the fingertips or past them.
    boundary_withdrawal_m: tuple[float, float] = setting((0.006, 0.02), at_least=0, shape=(2,), ordered=True)
    # Or turned by an angle in this range about an axis across the closing axis: from well inside
    # a unit friction cone (45 deg) to past it.
    boundary_turn_deg: tuple[float, float] = setting((15.0, 50.0), at_least=0, at_most=90, shape=(2,), ordered=True)
    # A capture samples this many antipodal pairs a grasp it is asked for, at least min_pairs and at
    # most planner.n_pairs: its covering poses (pose suppression) and every check's work grow with the
    # pairs, and a few thousand cover an object many times over for tens of grasps (2,000 pairs gave
    # 1,600-2,900 covering poses a YCB capture, 15 picked), while thousands of grasps need the full pool.
    pairs_per_grasp: int = setting(100, at_least=1)
    min_pairs: int = setting(1000, at_least=1)
    # Each capture places the object at a fresh seeded position and yaw on the table (and, for an
    # object with several stable resting poses, in the next of them); its grasps share one plan.
    captures_per_object: int = setting(2, at_least=1, at_most=100)
    # Where those captures give fewer grasps than asked (each new capture leaves out the grasps the
    # earlier ones took, within nms_translation_m / nms_rotation_deg), more are planned, up to this many
    # in all, until the count is reached or a capture finds under a tenth of those still missing: the
    # object's surface gives few more distinct grasps, and the report says so.
    max_captures_per_object: int = setting(8, at_least=1, at_most=100)
    # Grasps a worker simulates as one piece of work: one object's grasps spread over every worker
    # in pieces this size (labels do not depend on it).
    grasps_per_chunk: int = setting(50, at_least=1, at_most=100_000)
    seed: int = setting(1000, at_least=0)
    # Share of objects GraspGen's valid.txt lists, chosen by a hash of the object id.
    valid_fraction: float = setting(0.2, at_least=0, at_most=1)

    def __post_init__(self) -> None:
        super().__post_init__()
        unknown = [engine for engine in self.engines if engine not in LABEL_ENGINES]
        if unknown:
            raise ConfigError(f"dataset.engines: unknown engine {unknown[0]!r} (known: {', '.join(LABEL_ENGINES)})", "dataset.engines")
        if self.mode == "arm" and self.engines != ("pybullet",):
            raise ConfigError("dataset.engines: arm mode executes the study's motion in PyBullet alone; "
                              "other engines label hand mode (--mode hand)", "dataset.engines")
        if self.mode == "arm" and self.protocol != "tabletop":
            raise ConfigError(f"dataset.protocol '{self.protocol}' labels with the hand alone: use dataset.mode 'hand' (--mode hand)")
