"""The semantic sections: how a cloud is split into named zones, and how a backend rates them for a task."""
from __future__ import annotations

from dataclasses import dataclass

from .settings import _Section, setting

RATING_BACKENDS = ("prior", "transformers", "openai", "oracle")
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
