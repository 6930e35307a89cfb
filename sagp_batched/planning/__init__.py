"""The batched antipodal grasp planner, stage by stage: the random draws (``sampling``), the
candidates and the screens that need no IK (``screens``), the motion check (``motion_check``), the
search for each candidate's first executable approach (``search``, with verdicts computed ahead in
``lookahead``), and ``plan`` / ``plan_batch`` (``planner``)."""
from .gripper import gripper_geometry, hand_geometry, jaw_width_limit, widest_pair_m
from .motion_check import MotionCheck, check_motions, motion_checker
from .planner import PlanCounts, PlanResult, PlanStageTimes, plan, plan_batch
from .sampling import SampledInputs, sample_inputs
from .screens import ScreenedCandidates, screen_candidates
from .search import CandidateSearch, CandidateStatus, SearchTuning

__all__ = [
    "CandidateSearch", "CandidateStatus", "MotionCheck", "PlanCounts", "PlanResult", "PlanStageTimes", "SampledInputs",
    "ScreenedCandidates", "SearchTuning", "check_motions", "motion_checker", "gripper_geometry", "hand_geometry", "jaw_width_limit", "widest_pair_m", "plan",
    "plan_batch", "sample_inputs", "screen_candidates",
]
