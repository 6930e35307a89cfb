"""The world's sections: the simulated scene, the cameras that view it, and the perception that turns their
images into a cloud."""
from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

from .settings import _Section, setting

# The robots the package describes, a file each (``<name>.toml`` here, read by ``robot.description``).
ROBOTS_DIR = resources.files("sagp_batched").joinpath("data/robots")
ROBOTS: tuple[str, ...] = tuple(sorted(entry.name.removesuffix(".toml") for entry in ROBOTS_DIR.iterdir() if entry.name.endswith(".toml")))
# The grippers the package describes, a file each (``<name>.toml`` here, read by ``robot.gripper_description``).
GRIPPERS_DIR = resources.files("sagp_batched").joinpath("data/grippers")
GRIPPERS: tuple[str, ...] = tuple(sorted(entry.name.removesuffix(".toml") for entry in GRIPPERS_DIR.iterdir() if entry.name.endswith(".toml")))
# Each view renders RGB, depth and segmentation buffers, ~12 bytes a pixel: ~200 MB a view at 4,096 px a side.
MAX_IMAGE_SIDE_PX = 4096


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
    robot: str = setting("panda", choices=ROBOTS)
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
