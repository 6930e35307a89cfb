"""Coarse zones of the perceived object (the published method's stage 3) and the zone of every grasp candidate.

Every cloud point belongs to exactly three geometric zones: one third of the object (its primary
split), one lateral side (left / right) and one depth side (front / back); a point of a protrusion
cluster belongs to that cluster's zone as well, ``protrusion_1``, ``protrusion_2``, ... (largest
first), so a model can rate a pitcher's handle and its spout apart; a rating of plain
``protrusion`` applies to all of them (``ZoneRating.level``). ``memberships`` keeps every zone of
every point, so a rating of any zone can reach the points it names.

The primary split is into vertical thirds (bottom / middle / top), except for an elongated object
lying on the table (``zones.length_split``): its vertical thirds would be layers of its
thickness, each holding handle and working end alike, so it is split into thirds along its length
instead, named by their width (``wide_end`` / ``middle`` / ``narrow_end``): scissors' loops and
blades, a clamp's handles and jaws, a banana's middle and ends become zones of their own.

Protrusions are found by ``zones.protrusion_rule``: "body" (default) takes points farther than
``body_radius_factor`` x the body's radius from the vertical principal axis, for upright clouds
(other clouds keep the centroid rule, see ``ZonesConfig``); "centroid" is the published rule,
points farther than ``protrusion_distance_factor`` x the median centroid distance. Either way the
candidates are clustered with DBSCAN and clusters of ``min_protrusion_points`` are protrusions.
Clouds split along their length have none: what sticks out of them is their ends.

One zone per candidate (``GraspCandidates.zone``, used for reporting, preferred-zone and avoid-zone
metrics) is the *primary* zone of its contact midpoint's nearest cloud point: its protrusion if the
point is in one, else its third (protrusion wins over the thirds).
Side zones never become primary because they split the same points a second and third time.
A candidate is *rated* by its primary zone and its two side zones (``GraspCandidates.rated_zones``): a
handle point in the top third is the handle, so a dangerous rim must not reach it, while a rating of
a side still does.

Degenerate clouds get a typed outcome in ``ZoneDecomposition.degenerate`` instead of NaN zones:
``"empty"`` (no points: candidates get zone -1, unzoned), ``"too_few_points"`` and ``"collinear"``
(no stable principal frame: the world references ``up/left/front`` stand in for the principal
axes and no protrusions are sought), ``"flat"`` (the principal frame is still well defined and is
kept; the thin axis' sides are a split of sensor noise and are described as such).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from sagp_batched_kernels import zone_geometry as zone_kernels

from .._open3d import o3d
from ..config import ZonesConfig
from ..grasps import GraspCandidates
from ..types import LENGTH_ZONES, PROTRUSION, SIDE_ZONES, VERTICAL_ZONES, ZONE_NAMES, PerceivedCloud, protrusion_zone

# Zones every cloud has, in this order; its numbered protrusion zones follow them.
GEOMETRIC_ZONES: tuple[str, ...] = tuple(name for name in ZONE_NAMES if name != PROTRUSION)
ZONE_INDEX: dict[str, int] = {name: i for i, name in enumerate(GEOMETRIC_ZONES)}
# The thirds a point can be in: a protrusion takes its points over from them.
PRIMARY_SPLIT_ZONES: tuple[str, ...] = tuple(dict.fromkeys(VERTICAL_ZONES + LENGTH_ZONES))
# Kernel codes BOTTOM, MIDDLE, TOP -> zone indices.
_VERTICAL_ZONE = torch.tensor([ZONE_INDEX["bottom"], ZONE_INDEX["middle"], ZONE_INDEX["top"]])
# Thirds along the length, narrow end (0) to wide end (2) -> zone indices.
_LENGTH_ZONE = torch.tensor([ZONE_INDEX["narrow_end"], ZONE_INDEX["middle"], ZONE_INDEX["wide_end"]])
UNZONED = -1
DEGENERATE_OUTCOMES = ("empty", "too_few_points", "collinear", "flat")


class ZoneInputError(ValueError):
    """The cloud or the candidates handed to zoning are malformed (shape or non-finite values)."""


@dataclass(frozen=True)
class ZoneFacts:
    """The measurements of one zone that holds points; ``kind`` ("side", "vertical", "length" or
    "protrusion") says which of the optional ones it has."""

    name: str
    kind: str
    point_count: int
    # A vertical third's height, kept as the 0-d float32 tensor it is measured in (as
    # ``ObjectFacts.height_m``) so the prompt's centimetres round in float32, as the object's do.
    height_m: torch.Tensor | None = None
    width_m: float | None = None  # a third along a lying object's length: its extent across the object
    # A protrusion: its height band above the object's lowest point, the side zone it sticks out on,
    # and how far it reaches beyond the body's reference distance (``protrusion_reference_m``).
    band_above_lowest_m: tuple[float, float] | None = None
    side: str | None = None
    beyond_body_m: float | None = None


@dataclass(frozen=True)
class ObjectFacts:
    """The measurements of a zoned object (``ZoneDecomposition.facts``)."""

    n_points: int
    height_m: torch.Tensor  # 0-d float32: its extent along the vertical principal axis
    length_m: float | None  # its extent along ``length_axis_world`` where split along its length
    split: str
    protrusion_rule: str
    degenerate: str | None
    zones: tuple[ZoneFacts, ...]  # the zones holding points, in ``zone_names`` order


@dataclass
class ZoneDecomposition:
    """Zones of one object cloud; every tensor is indexed by cloud point."""

    zone_names: tuple[str, ...]
    points_world: torch.Tensor  # (N, 3) metres
    point_zone: torch.Tensor  # (N,) int64 primary zone index
    memberships: torch.Tensor  # (N, Z) bool, every zone each point belongs to
    protrusion_label: torch.Tensor  # (N,) int64 protrusion cluster id (0 = largest), -1 outside every protrusion
    centroid_world: torch.Tensor  # (3,) metres; the predicted centre of mass
    axes_world: torch.Tensor  # (3, 3) columns (vertical, lateral, depth), unit
    median_centroid_distance_m: float
    protrusion_rule: str = "centroid"  # the rule that found the protrusions ("body", "centroid", or "none")
    # How the cloud's points were split in thirds: "vertical" (top / middle / bottom) or "length"
    # (wide_end / middle / narrow_end along ``length_axis_world``, from the narrow to the wide end).
    split: str = "vertical"
    length_axis_world: torch.Tensor | None = None
    # Each point's distance by that rule (from the vertical axis or the centroid), metres, and the
    # body's reference distance it is compared with (radius or median centroid distance).
    protrusion_distance_m: torch.Tensor | None = None
    protrusion_reference_m: float = 0.0
    degenerate: str | None = None  # one of DEGENERATE_OUTCOMES, None for a well-posed cloud
    degenerate_reason: str = ""

    @property
    def n_points(self) -> int:
        return int(self.points_world.shape[0])

    @property
    def centre_of_mass_world(self) -> torch.Tensor | None:
        """(3,) the predicted centre of mass (the centroid); None for an empty cloud."""
        return self.centroid_world if self.n_points else None

    def zone_point_counts(self) -> dict[str, int]:
        counts = self.memberships.sum(dim=0).tolist()
        return {name: int(count) for name, count in zip(self.zone_names, counts)}

    def facts(self) -> "ObjectFacts":
        """The measurements of the object and of every zone that holds points, which the rating prompt
        states (``zone_descriptions.describe_zones``)."""
        if self.n_points == 0:
            return ObjectFacts(0, torch.zeros(()), None, self.split, self.protrusion_rule, self.degenerate, ())
        relative = self.points_world - self.centroid_world
        offsets = relative @ self.axes_world  # (N, 3) vertical, lateral, depth
        extents = offsets.amax(dim=0) - offsets.amin(dim=0)
        along = relative @ self.length_axis_world if self.split == "length" else None
        counts = self.zone_point_counts()
        zones = tuple(self._zone_facts(index, name, counts[name], relative, offsets, along)
                      for index, name in enumerate(self.zone_names) if counts[name])
        length_m = float(along.amax() - along.amin()) if along is not None else None
        return ObjectFacts(self.n_points, extents[0], length_m, self.split, self.protrusion_rule, self.degenerate, zones)

    def _zone_facts(self, index: int, name: str, count: int, relative: torch.Tensor, offsets: torch.Tensor,
                    along: torch.Tensor | None) -> "ZoneFacts":
        if name in SIDE_ZONES:
            return ZoneFacts(name, "side", count)
        member = self.memberships[:, index]
        zone_heights = offsets[member, 0]
        if along is not None and name in LENGTH_ZONES:
            across = relative @ torch.linalg.cross(self.axes_world[:, 0], self.length_axis_world)
            return ZoneFacts(name, "length", count, width_m=float(across[member].amax() - across[member].amin()))
        if name in VERTICAL_ZONES:
            return ZoneFacts(name, "vertical", count, height_m=zone_heights.amax() - zone_heights.amin())
        lowest = float(offsets[:, 0].amin())
        mean_offset = offsets[member].mean(dim=0)
        axis = 1 + int(mean_offset[1:].abs().argmax())
        side = (("left", "right"), ("front", "back"))[axis - 1][0 if mean_offset[axis] >= 0 else 1]
        return ZoneFacts(
            name, "protrusion", count, band_above_lowest_m=(float(zone_heights.amin()) - lowest, float(zone_heights.amax()) - lowest),
            side=side, beyond_body_m=float(self.protrusion_distance_m[member].max()) - self.protrusion_reference_m,
        )

    def nearest_points(self, positions_world: torch.Tensor) -> torch.Tensor:
        """(C,) index of the cloud point nearest each of ``positions_world`` (C, 3); needs a non-empty cloud."""
        positions = _checked_positions(positions_world, "positions_world")
        if self.n_points == 0:
            raise ZoneInputError("an empty cloud has no nearest points")
        valid = torch.ones(1, self.n_points, dtype=torch.bool)
        return zone_kernels.nearest_point_index(positions.unsqueeze(0), self.points_world.unsqueeze(0), valid)[0]

    def candidate_zones(self, positions_world: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Zones of each position's nearest cloud point: ((C,) int64 primary zone, UNZONED on an
        empty cloud; (C, Z) bool zones it is rated by: the primary zone, where a protrusion wins
        over the third, and the point's two side zones)."""
        positions = _checked_positions(positions_world, "positions_world")
        if self.n_points == 0:
            return (torch.full((positions.shape[0],), UNZONED, dtype=torch.int64),
                    torch.zeros(positions.shape[0], len(self.zone_names), dtype=torch.bool))
        nearest = self.nearest_points(positions)
        memberships = self.memberships[nearest]
        in_protrusion = memberships[:, len(GEOMETRIC_ZONES):].any(dim=1, keepdim=True)
        overridden = torch.zeros(len(self.zone_names), dtype=torch.bool)
        overridden[[ZONE_INDEX[name] for name in PRIMARY_SPLIT_ZONES]] = True
        return self.point_zone[nearest], memberships & ~(in_protrusion & overridden)

    def zone_candidates(self, candidates: GraspCandidates) -> GraspCandidates:
        """``candidates`` carrying their zones (``zone``, ``rated_zones``, ``zone_names``), found once
        from each contact midpoint's nearest cloud point."""
        zone, rated = self.candidate_zones(candidates.position)
        return dataclasses.replace(candidates, zone=zone, rated_zones=rated, zone_names=self.zone_names)


def _checked_positions(positions: torch.Tensor, name: str) -> torch.Tensor:
    if not isinstance(positions, torch.Tensor) or positions.ndim != 2 or positions.shape[1] != 3:
        shape = tuple(positions.shape) if isinstance(positions, torch.Tensor) else type(positions).__name__
        raise ZoneInputError(f"{name} must be a (N, 3) tensor, got {shape}")
    if not torch.isfinite(positions).all():
        raise ZoneInputError(f"{name} holds {int((~torch.isfinite(positions)).any(dim=1).sum())} non-finite rows")
    return positions.float()


def _world_reference_axes(config: ZonesConfig) -> torch.Tensor:
    axes = torch.tensor([config.up_world, config.left_world, config.front_world], dtype=torch.float32).T
    if not torch.allclose(axes.T @ axes, torch.eye(3), atol=1e-5):
        raise ZoneInputError(
            f"zones.up_world, left_world and front_world must be orthonormal, got {config.up_world}, "
            f"{config.left_world}, {config.front_world}"
        )
    return axes


def _cluster_protrusions(points: np.ndarray, config: ZonesConfig) -> np.ndarray:
    """DBSCAN labels of ``points`` (M, 3); -1 is noise. Open3D's cluster_dbscan: quicker than
    scikit-learn's, and it counts the point itself in min_points as scikit-learn does."""
    if points.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    labels = cloud.cluster_dbscan(eps=config.dbscan_eps_m, min_points=config.dbscan_min_samples, print_progress=False)
    return np.asarray(labels, dtype=np.int64)


def _stands_upright(points: torch.Tensor, reference_axes: torch.Tensor, config: ZonesConfig) -> bool:
    """Whether the cloud ``points`` (N, 3) is at least ``body_min_height_ratio`` as tall as its widest
    horizontal extent; ``reference_axes`` (3, 3): columns up, left, front."""
    offsets = points @ reference_axes
    extent = offsets.amax(dim=0) - offsets.amin(dim=0)
    return float(extent[0]) >= config.body_min_height_ratio * float(extent[1:].max())


def _far_points(
    batch_points: torch.Tensor, valid: torch.Tensor, centroid: torch.Tensor, reference_axes: torch.Tensor, upright: bool, config: ZonesConfig
) -> tuple[str, torch.Tensor, torch.Tensor, float, float]:
    """(rule applied, far (N,), distance (N,) by that rule, the body's reference distance, median
    centroid distance) of one cloud; the body rule applies to upright clouds with a round wall."""
    far, distance, median_distance = zone_kernels.far_points(batch_points, valid, centroid, config.protrusion_distance_factor)
    median_centroid = float(median_distance[0])
    if config.protrusion_rule == "body" and upright:
        # A body standing on the table has its axis along world up; the principal axes tilt
        # toward a handle or spout, which is what the rule must not absorb.
        upright_axes = reference_axes.unsqueeze(0)
        axis_point, roundness_error = zone_kernels.fit_body_axis(batch_points, valid, centroid, upright_axes, config.body_radius_factor)
        if float(roundness_error[0]) <= config.body_max_roundness_error:
            far_body, radial, radius = zone_kernels.far_from_axis(batch_points, valid, axis_point, upright_axes[:, :, 0], config.body_radius_factor)
            return "body", far_body[0], radial[0], float(radius[0]), median_centroid
    return "centroid", far[0], distance[0], median_centroid, median_centroid


def decompose(points_world: torch.Tensor, config: ZonesConfig | None = None) -> ZoneDecomposition:
    """Coarse zones of one cloud ``points_world`` (N, 3), world frame, metres."""
    config = config or ZonesConfig()
    points = _checked_positions(points_world, "points_world")
    n = points.shape[0]
    reference_axes = _world_reference_axes(config)
    if n == 0:
        return ZoneDecomposition(
            zone_names=GEOMETRIC_ZONES, points_world=points, point_zone=torch.zeros(0, dtype=torch.int64),
            memberships=torch.zeros(0, len(GEOMETRIC_ZONES), dtype=torch.bool), protrusion_label=torch.zeros(0, dtype=torch.int64),
            centroid_world=torch.zeros(3), axes_world=reference_axes, median_centroid_distance_m=0.0,
            degenerate="empty", degenerate_reason="the cloud has no points",
        )

    batch_points = points.unsqueeze(0)
    valid = torch.ones(1, n, dtype=torch.bool)
    up, left, front = reference_axes.T
    centroid, axes, eigenvalues = zone_kernels.principal_frame(
        batch_points, valid, up, left, front, config.isotropy_tolerance
    )
    degenerate, reason = _degeneracy(n, eigenvalues[0], config)
    frame_fallback = degenerate in ("too_few_points", "collinear")
    if frame_fallback:
        axes = reference_axes.unsqueeze(0)

    third, lateral_positive, depth_positive = zone_kernels.zone_coordinates(
        batch_points, valid, centroid, axes, config.min_split_extent_m
    )
    primary_zone = _VERTICAL_ZONE[third[0]]
    split, length_axis = "vertical", None
    upright = _stands_upright(points, reference_axes, config)
    if config.length_split and not frame_fallback and not upright:
        length_third, axis, elongation, _ = zone_kernels.length_split(batch_points, valid, centroid, up, config.min_split_extent_m)
        if float(elongation[0]) >= config.length_split_min_elongation:
            split, length_axis, primary_zone = "length", axis[0], _LENGTH_ZONE[length_third[0]]
    rule, far, protrusion_distance, reference, median_centroid = _far_points(batch_points, valid, centroid, reference_axes, upright, config)
    protrusion_label = torch.full((n,), -1, dtype=torch.int64)
    if split == "length":
        rule = "none"
    elif not frame_fallback:
        protrusion_label = _protrusion_labels(points, far, config)
    zone_names, memberships, point_zone = _point_zones(primary_zone, lateral_positive[0], depth_positive[0], protrusion_label)
    return ZoneDecomposition(
        zone_names=zone_names, points_world=points, point_zone=point_zone, memberships=memberships,
        protrusion_label=protrusion_label, centroid_world=centroid[0], axes_world=axes[0],
        median_centroid_distance_m=median_centroid, degenerate=degenerate, degenerate_reason=reason,
        protrusion_rule=rule, protrusion_distance_m=protrusion_distance, protrusion_reference_m=reference,
        split=split, length_axis_world=length_axis,
    )


def _degeneracy(n: int, eigenvalues: torch.Tensor, config: ZonesConfig) -> tuple[str | None, str]:
    """(``ZoneDecomposition.degenerate``, its reason) of a cloud of ``n`` points whose covariance
    has ``eigenvalues`` (3,): None and "" for a cloud with a stable, non-flat principal frame."""
    spread = eigenvalues.sort(descending=True).values
    largest = float(spread[0])
    if n < config.min_points:
        return "too_few_points", f"{n} points, fewer than zones.min_points={config.min_points}"
    if largest <= 0.0 or float(spread[1]) < config.collinear_eigen_ratio * largest:
        return "collinear", f"covariance eigenvalues {spread.tolist()} span a line at most"
    if float(spread[2]) < config.flat_eigen_ratio * largest:
        return "flat", f"covariance eigenvalues {spread.tolist()} span a plane; its thin axis' sides are noise"
    return None, ""


def _protrusion_labels(points: torch.Tensor, far: torch.Tensor, config: ZonesConfig) -> torch.Tensor:
    """(N,) protrusion of each point, -1 for none: the DBSCAN clusters of the ``far`` points of at
    least ``min_protrusion_points``, numbered from 0 largest first."""
    protrusion_label = torch.full((points.shape[0],), -1, dtype=torch.int64)
    far_index = far.nonzero().squeeze(1)
    labels = torch.from_numpy(_cluster_protrusions(points[far_index].numpy(), config))
    cluster_ids, sizes = torch.unique(labels[labels >= 0], return_counts=True)
    large = sizes >= config.min_protrusion_points
    # Largest first (ties by cluster id), so protrusion_1 is the biggest part that sticks out.
    order = sorted(zip((-sizes[large]).tolist(), cluster_ids[large].tolist()))
    for new_id, (_, cluster_id) in enumerate(order):
        protrusion_label[far_index[labels == cluster_id]] = new_id
    return protrusion_label


def _point_zones(
    primary_zone: torch.Tensor, lateral_positive: torch.Tensor, depth_positive: torch.Tensor, protrusion_label: torch.Tensor
) -> tuple[tuple[str, ...], torch.Tensor, torch.Tensor]:
    """(zone names, (N, Z) memberships, (N,) primary zone) of points given their third, their lateral
    and depth sides and their protrusion (-1 for none), which wins the primary zone over the third."""
    n = protrusion_label.numel()
    n_protrusions = int(protrusion_label.max()) + 1
    zone_names = GEOMETRIC_ZONES + tuple(protrusion_zone(k + 1) for k in range(n_protrusions))
    memberships = torch.zeros(n, len(zone_names), dtype=torch.bool)
    rows = torch.arange(n)
    memberships[rows, primary_zone] = True
    memberships[rows, torch.where(lateral_positive, ZONE_INDEX["left"], ZONE_INDEX["right"])] = True
    memberships[rows, torch.where(depth_positive, ZONE_INDEX["front"], ZONE_INDEX["back"])] = True
    in_protrusion = protrusion_label >= 0
    memberships[rows[in_protrusion], len(GEOMETRIC_ZONES) + protrusion_label[in_protrusion]] = True
    point_zone = torch.where(in_protrusion, len(GEOMETRIC_ZONES) + protrusion_label, primary_zone)
    return zone_names, memberships, point_zone


def assign_zones(
    cloud: PerceivedCloud, candidates: GraspCandidates, config: ZonesConfig | None = None
) -> tuple[ZoneDecomposition, GraspCandidates]:
    """Zones of ``cloud``, and ``candidates`` carrying theirs (``ZoneDecomposition.zone_candidates``)."""
    decomposition = decompose(cloud.points_world, config)
    return decomposition, decomposition.zone_candidates(candidates)
