"""The planner's screens against their exhaustive references, pose by pose.

The planner decides the table, gripper-volume and swept-hand checks by whatever its kernels do
(bounds, culling, fused passes); each check here is also decided the plain way, on every point of
its input for every pose: every hand hull vertex's height for the table, ``gripper_occupancy``'s
count for the volume, every scene point's k-DOP separation for the swept hand. A disagreement is
reported with how far the reference's value lies from the check's limit, so a kernel that rounds
or approximates can be held to deciding exactly everything farther than its stated resolution.

Clouds: the study's objects as the planner benchmark places them, and shapes the study never sees
(``unseen_shape_clouds``: pybullet_data's procedurally generated meshes, resting on the table at
random yaws).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh

from sagp_batched_kernels.gripper_occupancy import gripper_occupancy
from sagp_batched_kernels.hand_clearance import hand_clearance, separation
from sagp_batched_kernels.occupancy_verdict import gripper_occupancy_within

from ..config import Config
from ..planning.gripper import gripper_geometry, jaw_width_limit
from ..planning.screens import ScreenedCandidates, screen_candidates, swept_hand, table_check_points
from ..robot.hand import DOP_DIRECTIONS
from ..types import PerceivedCloud

CHECKS = ("table", "volume", "hand")
# pybullet_data's generated shapes are stored in units its URDFs scale by this to metres.
RANDOM_URDF_SCALE = 0.015
# (pose, point) pairs the exhaustive swept-hand separation takes at once.
REFERENCE_BLOCK_ELEMENTS = 2_000_000


@dataclass
class CheckAgreement:
    """One check's verdicts on ``poses`` poses: how many the planner and the reference decide alike,
    and for each pose they do not, the reference's signed distance from the limit (metres for the
    table and the swept hand, points for the volume) with the cloud it came from."""

    poses: int = 0
    agree: int = 0
    disagreements: list[dict[str, Any]] = field(default_factory=list)

    @property
    def share(self) -> float:
        return self.agree / self.poses if self.poses else 1.0


def unseen_shape_clouds(config: Config, count: int, n_points: int, object_xy_m: tuple[float, float], seed: int = 0) -> list[PerceivedCloud]:
    """``count`` surface clouds of pybullet_data's ``random_urdfs`` meshes (metres after their URDFs'
    scale), each turned to a random yaw and resting on the table at ``object_xy_m``, normals away
    from its centroid as perception orients them."""
    import pybullet_data

    rng = np.random.default_rng(seed)
    root = Path(pybullet_data.getDataPath()) / "random_urdfs"
    clouds = []
    for index in sorted(rng.choice(1000, size=count, replace=False)):
        mesh = trimesh.load(root / f"{index:03d}" / f"{index:03d}.obj", force="mesh")
        mesh.apply_scale(RANDOM_URDF_SCALE)
        yaw = rng.uniform(0.0, 2.0 * math.pi)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(yaw, (0.0, 0.0, 1.0)))
        points, faces = trimesh.sample.sample_surface(mesh, n_points, seed=int(rng.integers(2**31)))
        points = points - [*mesh.bounds.mean(axis=0)[:2], mesh.bounds[0, 2]] + [*object_xy_m, config.scene.table_top_z_m]
        normals = mesh.face_normals[faces]
        inward = ((points - points.mean(axis=0)) * normals).sum(axis=1) < 0
        normals[inward] *= -1
        clouds.append(PerceivedCloud(
            points_world=torch.as_tensor(points, dtype=torch.float32), normals_world=torch.as_tensor(normals, dtype=torch.float32),
            view_index=torch.zeros(len(points), dtype=torch.int64), crop_rgb=np.zeros((1, 1, 3), dtype=np.uint8), cameras=[],
            object_id=f"random_urdfs/{index:03d}", object_position_world=np.array([*object_xy_m, config.scene.table_top_z_m]),
            object_quat_xyzw=np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]),
        ))
    return clouds


class ScreenedPoses:
    """One cloud's screened poses: every antipodal candidate's approaches clear of the table (the
    volume check's poses) and those also under the volume limit (the hand sweep's)."""

    def __init__(self, screened: ScreenedCandidates):
        rows = torch.arange(screened.n_candidates)
        rotation = screened.frames(rows)[1]
        table_clear = screened.clear_of_table(rows, rotation)
        self.screened, self.rotation, self.table_clear = screened, rotation, table_clear
        self.geometry = gripper_geometry(screened.robot, screened.planner)
        self.limit = screened.planner.occupancy_max_fraction * screened.occupancy_total[screened.object_index]
        # Volume poses, flat: candidate and approach of each.
        self.volume_row, self.volume_slot = table_clear.nonzero(as_tuple=True)
        self.volume_ok = screened.volume_within(rows, rotation, table_clear)
        self.hand_row, self.hand_slot = self.volume_ok.nonzero(as_tuple=True)
        self.low, self.high = swept_hand(screened.robot, screened.pregrasp_offset_m, screened.width_m.device)
        self.margin_m = screened.planner.hand_clearance_margin_m

    def volume_counts(self) -> torch.Tensor:
        """(V,) float32 the exhaustive count (``gripper_occupancy``) of each volume pose."""
        s = self.screened
        counts = gripper_occupancy(s.occupancy_points, s.object_index, s.centre_world, self.rotation, s.width_m, self.geometry,
                                   s.memory.occupancy_chunk_elements, self.table_clear).total
        return counts[self.volume_row, self.volume_slot].to(torch.float32)

    def volume_reference(self) -> torch.Tensor:
        """(V,) bool the exhaustive count's verdict of each volume pose."""
        return self.volume_counts() <= self.limit[self.volume_row]

    def volume_exact(self, row: torch.Tensor, slot: torch.Tensor, compile: bool) -> torch.Tensor:
        """(len(row),) bool ``gripper_occupancy_within``'s verdicts of the given poses."""
        s = self.screened
        if not row.numel():
            return torch.zeros(0, dtype=torch.bool)
        poses = torch.zeros_like(self.table_clear)
        poses[row, slot] = True
        within = gripper_occupancy_within(s.occupancy_points, s.object_index, s.centre_world, self.rotation, s.width_m, self.geometry,
                                          self.limit, s.memory.occupancy_chunk_elements, poses, compile)
        return within[row, slot]

    def hand_exact(self, index: torch.Tensor, compile: bool) -> torch.Tensor:
        """(len(index),) bool ``hand_clearance``'s blocked verdicts of hand poses ``index``."""
        s, row = self.screened, self.hand_row[index]
        if not row.numel():
            return torch.zeros(0, dtype=torch.bool)
        return hand_clearance(s.hand_check_points, s.hand_screen_points, s.object_index[row], s.centre_world[row],
                              self.rotation[row, self.hand_slot[index]], DOP_DIRECTIONS, self.low, self.high, self.margin_m,
                              s.memory.hand_check_chunk_elements, compile).blocked


def screen_agreement(clouds: Sequence[PerceivedCloud], config: Config, seeds: Sequence[int]) -> dict[str, CheckAgreement]:
    """Per check (``CHECKS``), the planner's verdicts against the exhaustive reference on every
    (candidate, approach) pose of each cloud's antipodal candidates: the table on all of them, the
    volume on those clear of the table, the swept hand on those also under the volume limit (as the
    planner checks them)."""
    agreement = {check: CheckAgreement() for check in CHECKS}
    for cloud, seed in zip(clouds, seeds):
        screened = screen_candidates([cloud], config, [seed])
        if screened.n_candidates == 0:
            continue
        poses = ScreenedPoses(screened)
        rows = torch.arange(screened.n_candidates)
        reference_height = _table_reference_height(screened, rows, poses.rotation)
        reference_clear = (reference_height >= 0.0) & (screened.width_m <= jaw_width_limit(screened.robot, screened.planner))[:, None]
        _tally(agreement["table"], poses.table_clear, reference_clear, reference_height, cloud.object_id)

        limit = poses.limit[poses.volume_row]
        counts = poses.volume_counts()
        _tally(agreement["volume"], poses.volume_ok[poses.volume_row, poses.volume_slot], counts <= limit, limit - counts, cloud.object_id)

        if poses.hand_row.numel():
            blocked = poses.hand_exact(torch.arange(poses.hand_row.numel()), screened.planner.compile)
            reference_clearance = _hand_reference_clearance(poses)
            _tally(agreement["hand"], ~blocked, reference_clearance >= poses.margin_m, reference_clearance - poses.margin_m, cloud.object_id)
    return agreement


def _tally(check: CheckAgreement, planner_ok: torch.Tensor, reference_ok: torch.Tensor, reference_margin: torch.Tensor, object_id: str) -> None:
    """Adds poses whose verdicts are ``planner_ok`` and ``reference_ok`` (bool, same shape) to ``check``."""
    differ = planner_ok != reference_ok
    check.poses += planner_ok.numel()
    check.agree += int((~differ).sum())
    check.disagreements.extend({"object": object_id, "reference_margin": float(value)} for value in reference_margin[differ].tolist())


def _table_reference_height(screened, rows: torch.Tensor, rotation: torch.Tensor) -> torch.Tensor:
    """(R, K) the least height over its limit of any hand hull vertex at the grasp or the pre-grasp
    (fingers against ``finger_table_clearance_m``, the other links against ``arm_table_clearance_m``
    above the table), every vertex placed by its own product: >= 0 where the hand clears the table."""
    planner, table_z = screened.planner, screened.table_top_z_m
    heights = []
    for (vertices, _), clearance in zip(table_check_points(screened.robot, rows.device),
                                        (planner.finger_table_clearance_m, planner.arm_table_clearance_m)):
        at_grasp = screened.centre_world[rows, 2, None, None] + (rotation[..., 2, None, :] * vertices).sum(dim=-1)  # (R, K, V)
        lowest = at_grasp.amin(dim=-1)
        drop = screened.pregrasp_offset_m * rotation[..., 2, 2]
        heights.append(torch.minimum(lowest, lowest - drop) - (table_z + clearance))
    return torch.minimum(*heights)


def _hand_reference_clearance(poses: ScreenedPoses) -> torch.Tensor:
    """(P,) the least k-DOP separation of every scene point from the swept hand of each of ``poses``'
    hand poses: every point of the cloud's hand-check set evaluated exactly."""
    screened, rows = poses.screened, poses.hand_row
    frames = poses.rotation[rows, poses.hand_slot]
    middle, half = ((poses.low + poses.high) / 2)[:, :, None, None], ((poses.high - poses.low) / 2)[:, :, None, None]
    points = screened.hand_check_points[0]
    points = points[~points.isnan().any(dim=1)]
    axes = DOP_DIRECTIONS.to(frames.device) @ frames.transpose(-1, -2)
    block = max(1, REFERENCE_BLOCK_ELEMENTS // max(1, points.shape[0]))
    clearance = []
    for start in range(0, rows.numel(), block):
        relative = points[None] - screened.centre_world[rows[start : start + block], None, :]
        clearance.append(separation(relative, axes[start : start + block], middle, half, compile=False).amin(dim=1))
    return torch.cat(clearance)


def agreement_report(clouds: Sequence[PerceivedCloud], config: Config) -> dict[str, Any]:
    """``screen_agreement`` of ``clouds`` (seed 0 each) as a JSON-ready report, a printed line per check."""
    agreement = screen_agreement(clouds, config, [0] * len(clouds))
    report: dict[str, Any] = {"objects": [cloud.object_id for cloud in clouds], "checks": {}}
    for check, tally in agreement.items():
        farthest = max((abs(d["reference_margin"]) for d in tally.disagreements), default=None)
        report["checks"][check] = {"poses": tally.poses, "agree": tally.agree, "share": tally.share, "disagreements": tally.disagreements}
        print(f"verdicts, {check}: {tally.agree}/{tally.poses} poses agree with the exhaustive reference ({100 * tally.share:.3f} %)"
              + ("" if farthest is None else f", the farthest disagreement {farthest:.3g} from the limit"), flush=True)
    return report
