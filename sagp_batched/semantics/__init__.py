"""What the grasps mean: the cloud's coarse zones and each candidate's (``zones``, drawn for a model
by ``zone_marks``), the fused score (``scoring``) and the VLM-Direct baseline that asks a model to
choose among candidates (``vlm_direct``). The ratings themselves are in ``sagp_batched.rating``."""
from .scoring import score_candidates
from .zones import ZoneDecomposition, assign_zones

__all__ = ["ZoneDecomposition", "assign_zones", "score_candidates"]
