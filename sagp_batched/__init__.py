"""sagp-batched: vectorised semantic affordance-guided grasp planning.

The public API: build a scene, perceive, plan, zone, rate, score, execute::

    from sagp_batched import Scene, capture, load_config, load_object_set, plan
    config = load_config("paper")
    scene = Scene(config)
    scene.reset(load_object_set("../shared/ycb").get("025_mug"), trial=0)
    grasps = plan(capture(scene, config), config, seed=0).candidates   # GraspCandidates, ranked by S_geom
    attempt = execute_grasp(scene, config, grasps[0])      # grasps[0] is the best Grasp
"""
from typing import TYPE_CHECKING

from .lazy_exports import lazy_exports

# Imported on first use (``lazy_exports``), so that importing one part (the MuJoCo engine, say) loads none of the others.
if TYPE_CHECKING:
    from .attempt import AttemptDiagnostics
    from .config import Config, ConfigError, GEOMETRY_ONLY_WEIGHTS, ScoreWeights, load_config
    from .execution.pick import execute_grasp, execute_ranked
    from .grasps import Grasp, GraspCandidates, GraspPoses
    from .planning import PlanResult, plan, plan_batch
    from .rating import ZoneRating, get_rater
    from .semantics.scoring import score_candidates
    from .semantics.zones import ZoneDecomposition, assign_zones
    from .study.study_run import run_study
    from .types import CameraData, GraspAttempt, PerceivedCloud, PerceptionFailure
    from .world.objects import ObjectSet, ObjectSpec, load_object_set
    from .world.perception import capture
    from .world.scene import Scene

__all__ = [
    "AttemptDiagnostics", "CameraData", "Config", "ConfigError", "GEOMETRY_ONLY_WEIGHTS", "Grasp", "GraspAttempt",
    "GraspCandidates", "GraspPoses", "ObjectSet", "ObjectSpec", "PerceivedCloud", "PerceptionFailure", "PlanResult",
    "Scene", "ScoreWeights", "ZoneDecomposition", "ZoneRating", "assign_zones", "capture", "execute_grasp",
    "execute_ranked", "get_rater", "load_config", "load_object_set", "plan", "plan_batch", "run_study",
    "score_candidates",
]
__getattr__ = lazy_exports(__name__, __file__)

__version__ = "0.1.0"

