"""sagp-batched: vectorised semantic affordance-guided grasp planning.

The public API: build a scene, perceive, plan, zone, rate, score, execute::

    from sagp_batched import Scene, capture, load_config, load_object_set, plan
    config = load_config("paper")
    scene = Scene(config)
    scene.reset(load_object_set("../shared/ycb").get("025_mug"), trial=0)
    grasps = plan(capture(scene, config), config, seed=0).candidates   # GraspCandidates, ranked by S_geom
    attempt = execute_grasp(scene, config, grasps[0])      # grasps[0] is the best Grasp
"""
from .lazy_exports import lazy_exports

# Each public name and its module, imported on first use (``lazy_exports``).
_PUBLIC = {
    "AttemptDiagnostics": "attempt", "GEOMETRY_ONLY_WEIGHTS": "config", "Config": "config", "ConfigError": "config",
    "ScoreWeights": "config", "load_config": "config", "execute_grasp": "execution.pick", "execute_ranked": "execution.pick",
    "Grasp": "grasps", "GraspCandidates": "grasps", "GraspPoses": "grasps", "PlanResult": "planning", "plan": "planning",
    "plan_batch": "planning", "ZoneRating": "rating", "get_rater": "rating", "score_candidates": "semantics.scoring",
    "ZoneDecomposition": "semantics.zones", "assign_zones": "semantics.zones", "run_study": "study.run",
    "CameraData": "types", "GraspAttempt": "types", "PerceivedCloud": "types", "PerceptionFailure": "types",
    "ObjectSet": "world.objects", "ObjectSpec": "world.objects", "load_object_set": "world.objects",
    "capture": "world.perception", "Scene": "world.scene",
}
__getattr__ = lazy_exports(__name__, _PUBLIC)

__version__ = "0.1.0"

__all__ = [
    "GEOMETRY_ONLY_WEIGHTS", "AttemptDiagnostics", "CameraData", "Config", "ConfigError", "Grasp", "GraspAttempt", "GraspCandidates", "GraspPoses",
    "ObjectSet", "ObjectSpec", "PerceivedCloud", "PerceptionFailure", "PlanResult", "Scene", "ScoreWeights", "ZoneDecomposition", "ZoneRating",
    "assign_zones", "capture", "execute_grasp", "execute_ranked", "get_rater", "load_config", "load_object_set",
    "plan", "plan_batch", "run_study", "score_candidates",
]
