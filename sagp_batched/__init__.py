"""sagp-batched: vectorised semantic affordance-guided grasp planning."""
from .config import Config, ConfigError, load_config
from .types import CameraData, GraspAttempt, GraspCandidates, PerceivedCloud, PerceptionFailure

__version__ = "0.1.0"
