"""Coarse-zone geometry of object clouds (the published method's stage 3), batched over clouds.

Clouds of different sizes share one padded batch: ``points`` (B, N, 3) with a ``valid`` (B, N) mask;
padded entries may hold any finite value and never influence a result. Every position is in the
world frame, metres. Clustering of protruding points (DBSCAN) is not a tensor operation and is left
to the caller; these kernels give it the far points and map candidates to cloud points.
"""
from __future__ import annotations

import torch

BOTTOM, MIDDLE, TOP = 0, 1, 2


def _masked_mean(values: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    weights = valid.to(values.dtype).unsqueeze(-1)
    count = weights.sum(dim=-2).clamp_min(1.0)
    return (values * weights).sum(dim=-2) / count


def _unit(vectors: torch.Tensor) -> torch.Tensor:
    return vectors / torch.linalg.vector_norm(vectors, dim=-1, keepdim=True).clamp_min(1e-12)


def _axis_nearest(
    reference: torch.Tensor, eigenvalues: torch.Tensor, eigenvectors: torch.Tensor, isotropy_tolerance: float
) -> torch.Tensor:
    """(B, D) unit principal direction nearest ``reference`` ((D,) or (B, D)), for eigenvectors (B, D, K) columns.

    Eigenvalues within ``isotropy_tolerance`` (relative) of the best-aligned one's make their span a
    principal subspace in which every direction is principal; the projection of ``reference`` onto that
    span is then the principal direction nearest it.
    """
    batch = torch.arange(eigenvalues.shape[0], device=eigenvalues.device)
    reference = reference.expand(eigenvalues.shape[0], -1).unsqueeze(-1)
    alignment = (eigenvectors.transpose(1, 2) @ reference).squeeze(-1)  # (B, K)
    best = alignment.abs().argmax(dim=1)
    best_value = eigenvalues[batch, best].unsqueeze(1)
    scale = torch.maximum(eigenvalues.abs(), best_value.abs()).clamp_min(1e-30)
    same_space = (eigenvalues - best_value).abs() <= isotropy_tolerance * scale  # (B, K)
    projection = (eigenvectors * (alignment * same_space).unsqueeze(1)).sum(dim=2)
    return _unit(projection)


def principal_frame(
    points: torch.Tensor,
    valid: torch.Tensor,
    up: torch.Tensor,
    left: torch.Tensor,
    front: torch.Tensor,
    isotropy_tolerance: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The object's principal frame, with its axes named by world references.

    Args:
        points: (B, N, 3) cloud points, world frame, metres.
        valid: (B, N) bool, which points are real (not padding).
        up: (3,) unit world up; the principal direction most aligned with it is the vertical axis.
        left: (3,) unit world direction called "left", orthogonal to ``up``; the principal direction
            orthogonal to the vertical that is most aligned with it is the lateral axis.
        front: (3,) unit world direction called "front" (= up x left for a right-handed reference).
        isotropy_tolerance: relative eigenvalue gap under which two principal axes are one principal
            plane (a mug is about as tall as it is wide); the direction nearest the reference in that
            plane is taken, so sampling noise cannot tilt the frame.

    Returns:
        centroid: (B, 3) mean of the valid points, world frame.
        axes: (B, 3, 3) orthonormal columns (vertical, lateral, depth), world frame, signed to point
            along ``up`` / ``left`` / ``front`` (a zero dot product keeps the positive sign).
        eigenvalues: (B, 3) covariance of the points along (vertical, lateral, depth), m^2.
    """
    centroid = _masked_mean(points, valid)
    centred = (points - centroid.unsqueeze(1)) * valid.unsqueeze(-1).to(points.dtype)
    count = valid.sum(dim=1).clamp_min(1).to(points.dtype)
    # float64: near-degenerate covariances of float32 clouds otherwise lose their small axes.
    covariance = (centred.transpose(1, 2) @ centred / count.view(-1, 1, 1)).double()
    eigenvalues, eigenvectors = torch.linalg.eigh(covariance)
    vertical = _axis_nearest(up.double(), eigenvalues, eigenvectors, isotropy_tolerance)

    # Orthonormal basis of the plane normal to the vertical, then its own 2-D principal axes.
    seed = torch.where(((vertical @ left.double()).abs() < 0.9).unsqueeze(1), left.double(), front.double())
    plane_u = _unit(seed - (vertical * seed).sum(dim=1, keepdim=True) * vertical)
    plane_v = torch.linalg.cross(vertical, plane_u)
    plane_basis = torch.stack([plane_u, plane_v], dim=2)  # (B, 3, 2)
    plane_values, plane_vectors = torch.linalg.eigh(plane_basis.transpose(1, 2) @ covariance @ plane_basis)
    left_in_plane = (plane_basis.transpose(1, 2) @ left.double().unsqueeze(-1)).squeeze(-1)  # (B, 2)
    lateral_in_plane = _axis_nearest(left_in_plane, plane_values, plane_vectors, isotropy_tolerance)
    lateral = _unit((plane_basis @ lateral_in_plane.unsqueeze(-1)).squeeze(-1))
    depth = torch.linalg.cross(vertical, lateral)

    axes = torch.stack([vertical, lateral, depth], dim=2)
    references = torch.stack([up, left, front], dim=1).double()
    signs = torch.where((axes * references).sum(dim=1) < 0, -1.0, 1.0).to(axes.dtype)
    axes = axes * signs.unsqueeze(1)
    spread = torch.einsum("bji,bjk,bki->bi", axes, covariance, axes)
    return centroid, axes.to(points.dtype), spread.to(points.dtype)


def zone_coordinates(
    points: torch.Tensor,
    valid: torch.Tensor,
    centroid: torch.Tensor,
    axes: torch.Tensor,
    min_split_extent_m: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each point's vertical third and side of the lateral and depth axes.

    Args:
        points: (B, N, 3) world frame, metres; valid: (B, N) bool.
        centroid: (B, 3) world frame; axes: (B, 3, 3) columns (vertical, lateral, depth).
        min_split_extent_m: a cloud whose vertical extent is below this is not split: all its
            points are MIDDLE.

    Returns:
        vertical_third: (B, N) int64 in {BOTTOM, MIDDLE, TOP}: equal thirds of the valid points'
            extent along the vertical axis.
        lateral_positive: (B, N) bool, offset from the centroid along the lateral axis >= 0 ("left").
        depth_positive: (B, N) bool, offset along the depth axis >= 0 ("front").
        Padded entries hold MIDDLE / False.
    """
    offsets = (points - centroid.unsqueeze(1)) @ axes  # (B, N, 3) in (vertical, lateral, depth)
    height = offsets[..., 0]
    inf = torch.tensor(float("inf"), dtype=points.dtype, device=points.device)
    lowest = torch.where(valid, height, inf).amin(dim=1, keepdim=True)
    highest = torch.where(valid, height, -inf).amax(dim=1, keepdim=True)
    extent = highest - lowest
    splittable = extent >= min_split_extent_m
    fraction = (height - lowest) / torch.where(splittable, extent, torch.ones_like(extent))
    third = torch.floor(fraction * 3).clamp(BOTTOM, TOP).long()
    third = torch.where(splittable & valid, third, torch.full_like(third, MIDDLE))
    lateral_positive = (offsets[..., 1] >= 0) & valid
    depth_positive = (offsets[..., 2] >= 0) & valid
    return third, lateral_positive, depth_positive


def length_split(
    points: torch.Tensor, valid: torch.Tensor, centroid: torch.Tensor, up: torch.Tensor, min_split_extent_m: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Thirds of each cloud along its length: the principal direction of its spread in the
    horizontal plane (normal to ``up``), for objects lying on the table.

    Args:
        points: (B, N, 3) world frame, metres; valid: (B, N) bool; centroid: (B, 3) world frame.
        up: (3,) unit world up.
        min_split_extent_m: a cloud shorter than this along its length is not split: all MIDDLE.

    Returns:
        third: (B, N) int64 in {0, 1, 2}: equal thirds of the valid points' extent along
            ``length_axis``, 0 at its negative end; padded entries hold 1.
        length_axis: (B, 3) unit horizontal direction of the longest spread, world frame, signed so
            that its positive end (third 2) is at least as wide as its negative end (third 0).
        elongation: (B,) sqrt of the ratio of the larger to the smaller horizontal principal variance
            (1 for a round or square footprint, ~6 for a marker).
        end_width_m: (B, 2) extent across the length (horizontal) of the points of third 0 and third 2.
    """
    up = up.to(points.dtype)
    seed = torch.tensor([1.0, 0.0, 0.0], dtype=points.dtype) if float(up[0].abs()) < 0.9 else torch.tensor([0.0, 1.0, 0.0], dtype=points.dtype)
    plane_u = _unit(seed - (seed @ up) * up)
    plane_v = torch.linalg.cross(up, plane_u)
    basis = torch.stack((plane_u, plane_v), dim=1)  # (3, 2)
    weight = valid.to(points.dtype).unsqueeze(-1)
    planar = ((points - centroid.unsqueeze(1)) @ basis) * weight  # (B, N, 2)
    count = valid.sum(dim=1).clamp_min(1).to(points.dtype)
    # float64 for the same reason as in principal_frame: a thin footprint's small axis.
    covariance = (planar.transpose(1, 2) @ planar / count.view(-1, 1, 1)).double()
    variances, directions = torch.linalg.eigh(covariance)  # ascending
    elongation = torch.sqrt(variances[:, 1] / variances[:, 0].clamp_min(1e-18)).to(points.dtype)
    along_in_plane = directions[:, :, 1].to(points.dtype)  # (B, 2)
    across_in_plane = torch.stack((-along_in_plane[:, 1], along_in_plane[:, 0]), dim=1)
    along = (planar * along_in_plane.unsqueeze(1)).sum(dim=-1)
    across = (planar * across_in_plane.unsqueeze(1)).sum(dim=-1)

    inf = torch.tensor(float("inf"), dtype=points.dtype)
    lowest = torch.where(valid, along, inf).amin(dim=1, keepdim=True)
    highest = torch.where(valid, along, -inf).amax(dim=1, keepdim=True)
    extent = highest - lowest
    splittable = extent >= min_split_extent_m
    fraction = (along - lowest) / torch.where(splittable, extent, torch.ones_like(extent))
    third = torch.floor(fraction * 3).clamp(0, 2).long()
    third = torch.where(splittable & valid, third, torch.ones_like(third))

    def width(end: int) -> torch.Tensor:
        member = valid & (third == end)
        widest = torch.where(member, across, -inf).amax(dim=1)
        narrowest = torch.where(member, across, inf).amin(dim=1)
        return torch.where(member.any(dim=1), widest - narrowest, torch.zeros_like(widest))

    end_width = torch.stack((width(0), width(2)), dim=1)
    flip = end_width[:, 0] > end_width[:, 1]
    third = torch.where(flip.unsqueeze(1) & (third != 1), 2 - third, third)
    end_width = torch.where(flip.unsqueeze(1), end_width.flip(1), end_width)
    length_axis = along_in_plane @ basis.T
    length_axis = torch.where(flip.unsqueeze(1), -length_axis, length_axis)
    return third, length_axis, elongation, end_width


def far_points(
    points: torch.Tensor, valid: torch.Tensor, centroid: torch.Tensor, distance_factor: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points farther from the centroid than ``distance_factor`` x the median centroid distance.

    Args:
        points: (B, N, 3) world frame, metres; valid: (B, N) bool; centroid: (B, 3) world frame.
        distance_factor: multiple of the median distance beyond which a point is far (published: 1.5).

    Returns:
        far: (B, N) bool, valid far points (protrusion candidates, to be clustered).
        distance: (B, N) centroid distance of each point, metres (padding: 0).
        median_distance: (B,) median centroid distance of the valid points, metres (0 if none).
    """
    distance = torch.linalg.vector_norm(points - centroid.unsqueeze(1), dim=-1)
    distance = torch.where(valid, distance, torch.zeros_like(distance))
    masked = torch.where(valid, distance, torch.full_like(distance, float("nan")))
    median_distance = torch.nan_to_num(torch.nanmedian(masked, dim=1).values, nan=0.0)
    far = valid & (distance > distance_factor * median_distance.unsqueeze(1))
    return far, distance, median_distance


def fit_body_axis(
    points: torch.Tensor, valid: torch.Tensor, centroid: torch.Tensor, axes: torch.Tensor, trim_factor: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """A point on the axis of an upright body: the centre of the circle fitted (algebraic least
    squares, Kasa's fit) to the points' projection on the horizontal principal plane, refitted
    once on the points within ``trim_factor`` x the first radius so a handle does not pull it.

    The centroid is no such point: a cloud seen from one side (a half shell) has its centroid
    inside the shell, and a handle drags it sideways; a circle through the visible wall does not move.

    Args:
        points: (B, N, 3) world frame, metres; valid: (B, N) bool.
        centroid: (B, 3) world frame; axes: (B, 3, 3) columns (vertical, lateral, depth).
        trim_factor: points farther than this multiple of the first fit's radius are left out of the refit.

    Returns:
        axis_point: (B, 3) a point of each body's vertical axis (at the centroid's height), world frame.
        roundness_error: (B,) median |distance from the axis - radius| / radius of the refit's
            points: near 0 for a round wall (can, mug, pitcher), large for a box or an oval bottle.
    """
    planar = ((points - centroid.unsqueeze(1)) @ axes)[..., 1:]  # (B, N, 2) lateral, depth
    weight = valid.to(points.dtype)
    centre = torch.zeros(points.shape[0], 2, dtype=points.dtype)
    for _ in range(2):
        # x^2 + y^2 = 2 a x + 2 b y + c for a circle of centre (a, b); rows out of the fit are zeroed.
        design = torch.cat((2.0 * planar, torch.ones_like(planar[..., :1])), dim=-1) * weight.unsqueeze(-1)
        target = (planar**2).sum(dim=-1, keepdim=True) * weight.unsqueeze(-1)
        solution = torch.linalg.lstsq(design, target).solution[..., 0]  # (B, 3)
        centre = solution[:, :2]
        radius = torch.sqrt((solution[:, 2] + (centre**2).sum(dim=-1)).clamp_min(0.0))
        distance = torch.linalg.vector_norm(planar - centre.unsqueeze(1), dim=-1)
        fitted = valid & (distance <= trim_factor * radius.unsqueeze(1))
        weight = fitted.to(points.dtype)
    deviation = torch.where(fitted, (distance - radius.unsqueeze(1)).abs(), torch.full_like(distance, float("nan")))
    roundness_error = torch.nan_to_num(torch.nanmedian(deviation, dim=1).values / radius.clamp_min(1e-9), nan=float("inf"))
    return centroid + (axes[:, :, 1:] @ centre.unsqueeze(-1)).squeeze(-1), roundness_error


def far_from_axis(
    points: torch.Tensor, valid: torch.Tensor, centroid: torch.Tensor, axis: torch.Tensor, distance_factor: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points farther from a body axis than ``distance_factor`` x the body's radius (the median
    distance of the valid points from that axis): a handle or spout beside an upright body.

    Args:
        points: (B, N, 3) world frame, metres; valid: (B, N) bool.
        centroid: (B, 3) a point of each axis (``fit_body_axis``), world frame; axis: (B, 3) unit axis directions.
        distance_factor: multiple of the body radius beyond which a point is far.

    Returns:
        far: (B, N) bool, valid far points (protrusion candidates, to be clustered).
        distance: (B, N) distance of each point from the axis, metres (padding: 0).
        radius: (B,) median axis distance of the valid points, metres (0 if none).
    """
    relative = points - centroid.unsqueeze(1)
    along = (relative * axis.unsqueeze(1)).sum(dim=-1, keepdim=True)
    distance = torch.linalg.vector_norm(relative - along * axis.unsqueeze(1), dim=-1)
    distance = torch.where(valid, distance, torch.zeros_like(distance))
    masked = torch.where(valid, distance, torch.full_like(distance, float("nan")))
    radius = torch.nan_to_num(torch.nanmedian(masked, dim=1).values, nan=0.0)
    far = valid & (distance > distance_factor * radius.unsqueeze(1))
    return far, distance, radius


def nearest_point_index(queries: torch.Tensor, points: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Index of the nearest valid cloud point to each query.

    Args:
        queries: (B, C, 3) query positions (e.g. grasp contact midpoints), world frame, metres.
        points: (B, N, 3) cloud points, world frame; valid: (B, N) bool with at least one True per cloud.

    Returns:
        (B, C) int64 indices into N.
    """
    distance = torch.cdist(queries, points)
    distance = torch.where(valid.unsqueeze(1), distance, torch.full_like(distance, float("inf")))
    return distance.argmin(dim=-1)
