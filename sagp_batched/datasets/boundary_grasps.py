"""Grasps beside the boundary between held and dropped, for floating datasets.

A floating dataset picks antipodal candidates whose open hand the mesh leaves clear, and most of those
hold: a learner shown only them never sees where a grasp stops holding. ``add_boundary_grasps`` makes
variants of picked grasps that sit near that edge: the hand withdrawn along its approach, so the
object lies at or past the fingertips, or turned off its contacts about an axis across the closing
axis, so the fingers meet the surface obliquely. Each variant is measured on the mesh as the planner
would measure a candidate (where its fingers meet the surface, the width, S_geom of those contacts),
kept only where both fingers meet the mesh, its open hand stays clear and it is not the same grasp
(``dataset.nms_translation_m`` / ``nms_rotation_deg``) as a picked one or another variant, and recorded
with the verdict "boundary". Simulation labels a variant like any other grasp; nothing here guesses its outcome.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from sagp_batched_kernels.antipodal import antipodal_pairs
from sagp_batched_kernels.pose_nms import pose_nms, same_grasp

from ..config import Config
from ..grasps import GraspCandidates, GraspPoses
from ..planning import widest_pair_m
from ..robot.description import RobotDescription, robot_of
from .grasp_geometry import ObjectSurface, finger_contacts, open_hand_clear
from .verdicts import VERDICTS, ClassifiedGrasps

# Variants drawn per one wanted: a withdrawn hand may close on nothing, a turned one hit the mesh, and
# either repeat a grasp (on the YCB mug three draws a variant kept half the count, six nearly all).
DRAWS_PER_VARIANT = 6


def add_boundary_grasps(classified: ClassifiedGrasps, count: int, surface: ObjectSurface, object_from_world: np.ndarray,
                        robot: RobotDescription, config: Config, seed: int, taken: GraspPoses | None = None) -> ClassifiedGrasps:
    """``classified`` followed by up to ``count`` boundary variants of its grasps (world frame), drawn
    with ``seed``: half withdrawn by ``dataset.boundary_withdrawal_m``, half turned by
    ``dataset.boundary_turn_deg`` (each a uniform range), both fingers meeting the mesh (object
    frame ``object_from_world``), the open hand clear of it, none the same grasp as one of ``classified``,
    of ``taken`` (object frame: earlier captures' picks) or of another variant. Fewer where the draws run out."""
    if count <= 0 or not len(classified):
        return classified
    rng = np.random.default_rng(seed)
    world_from_object = np.linalg.inv(object_from_world)
    source = classified.candidates.transform(object_from_world, "object")
    drawn = _variant_frames(source, rng.integers(len(source), size=count * DRAWS_PER_VARIANT), rng, config)
    contacts = finger_contacts(surface, GraspPoses(torch.as_tensor(drawn[0]), torch.as_tensor(drawn[1]), "object"), robot.gripper.open_width_m)
    centre = np.nan_to_num(contacts.points.mean(axis=1))
    width = np.linalg.norm(contacts.points[:, 1] - contacts.points[:, 0], axis=1)
    usable = contacts.both_met & (np.nan_to_num(width) >= config.planner.min_width_m)
    usable[usable] = open_hand_clear(surface, GraspPoses(torch.as_tensor(centre[usable]), torch.as_tensor(drawn[1][usable]), "object"),
                                     robot, config.labelling.geometry_tolerance_m)
    others = GraspPoses.cat([source.poses()] + ([taken] if taken is not None else []), "object")
    kept = np.flatnonzero(_distinct(centre, drawn[1], usable, others, config))[:count]
    if not len(kept):
        return classified
    variants = _candidates(contacts.points[kept], contacts.normals[kept], drawn[1][kept], classified.candidates, config)
    variants = variants.with_fields(candidate_id=torch.arange(len(classified), len(classified) + len(kept)))
    reasons = tuple(_reason(kind, amount) for kind, amount in zip(drawn[2][kept], drawn[3][kept]))
    return ClassifiedGrasps(
        classified.candidates.appended(variants.transform(world_from_object, "world")),
        torch.cat([classified.verdict, torch.full((len(kept),), VERDICTS.index("boundary"), dtype=classified.verdict.dtype)]),
        classified.reasons + reasons, classified.pool_size, classified.covering_size,
    )


def _distinct(centre: np.ndarray, rotation: np.ndarray, usable: np.ndarray, others: GraspPoses, config: Config) -> np.ndarray:
    """(V,) bool: the ``usable`` variants that are not the same grasp as one of ``others`` nor as an earlier
    usable variant: a repeat adds no grasp to the dataset, only weight to one."""
    translation_m, rotation_rad = config.dataset.nms_translation_m, math.radians(config.dataset.nms_rotation_deg)
    rows = np.flatnonzero(usable)
    centres, frames = torch.as_tensor(centre[rows]), torch.as_tensor(rotation[rows])
    if len(others) and len(rows):
        rows = rows[~same_grasp(centres, frames, others.position, others.rotation, translation_m, rotation_rad).any(dim=1).numpy()]
    if len(rows):
        rows = rows[np.sort(pose_nms(torch.as_tensor(centre[rows]), torch.as_tensor(rotation[rows]), translation_m, rotation_rad).numpy())]
    distinct = np.zeros(len(usable), dtype=bool)
    distinct[rows] = True
    return distinct


def _variant_frames(source: GraspCandidates, rows: np.ndarray, rng: np.random.Generator,
                    config: Config) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(V, 3) centres, (V, 3, 3) grasp frames (object frame), (V,) kind ("withdrawn"/"turned") and
    (V,) amount (m or deg) of the variants of ``source[rows]``: every other one withdrawn."""
    dataset = config.dataset
    centre = source.position[rows].numpy().copy()
    rotation = source.rotation[rows].numpy().copy()
    withdrawn = np.arange(len(rows)) % 2 == 0
    depth = rng.uniform(*dataset.boundary_withdrawal_m, size=len(rows))
    centre[withdrawn] -= depth[withdrawn, None] * rotation[withdrawn, :, 2]
    # About an axis across the closing axis (between the frame's x and its approach), through the centre.
    phase = rng.uniform(0.0, 2.0 * math.pi, size=len(rows))
    axis_in_grasp = np.stack([np.cos(phase), np.zeros_like(phase), np.sin(phase)], axis=1)
    angle = rng.uniform(*dataset.boundary_turn_deg, size=len(rows))
    axis_in_object = np.einsum("nij,nj->ni", rotation, axis_in_grasp)
    turn = Rotation.from_rotvec(axis_in_object * np.deg2rad(angle)[:, None]).as_matrix()
    rotation[~withdrawn] = turn[~withdrawn] @ rotation[~withdrawn]
    kind = np.where(withdrawn, "withdrawn", "turned")
    return centre, rotation, kind, np.where(withdrawn, depth, angle)


def _candidates(points: np.ndarray, normals: np.ndarray, rotation: np.ndarray, like: GraspCandidates,
                config: Config) -> GraspCandidates:
    """Candidates (object frame) of grasps whose fingers meet the mesh at ``points`` (V, 2, 3) with
    outward ``normals``, the hand turned as ``rotation``: measured like the planner's candidates, not
    planned for the arm (no reach, no joint path, no swept clearance)."""
    planner = config.planner
    count = len(points)
    pairs = torch.arange(2 * count).reshape(count, 2)
    measured = antipodal_pairs(torch.as_tensor(points.reshape(-1, 3)), torch.as_tensor(normals.reshape(-1, 3)), pairs,
                               planner.min_width_m, widest_pair_m(robot_of(config), planner), planner.max_contact_angle_deg)
    zeros = torch.zeros(count, dtype=torch.float64)
    rotation_t = torch.as_tensor(rotation)
    joint_path = None if like.joint_path is None else torch.zeros((count, *like.joint_path.shape[1:]))
    return GraspCandidates(
        contacts=torch.as_tensor(points), closing_axis=measured["closing_axis"], width_m=measured["width_m"],
        s_geom=measured["s_geom"], approach=rotation_t[:, :, 2], rotation=rotation_t, s_reach=zeros,
        ik_solution=torch.zeros(count, like.ik_solution.shape[1]), zone=torch.full((count,), -1, dtype=torch.int64),
        s_afford=zeros, s_avoid=zeros, s_task=zeros, score=measured["s_geom"].clone(), zone_names=like.zone_names,
        joint_path=joint_path, hand_clearance_m=None if like.hand_clearance_m is None else torch.full((count,), math.inf),
        frame="object",
    )


def _reason(kind: str, amount: float) -> str:
    if kind == "withdrawn":
        return f"boundary: a clear grasp withdrawn {amount * 1000:.0f} mm along its approach, the object toward the fingertips"
    return f"boundary: a clear grasp turned {amount:.0f} deg off its contacts about an axis across the closing axis"
