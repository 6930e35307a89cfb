"""The random draws of a plan: contact pairs, and the point subsets the screens test."""
from __future__ import annotations

from dataclasses import dataclass

import torch

from sagp_batched_kernels.sampling import (
    sample_guided_pair_indices,
    sample_pair_indices,
    sample_subset_indices,
    voxel_representatives,
)

from ..config import MemoryConfig, PlannerConfig
from ..robot.description import RobotDescription
from ..types import PerceivedCloud
from .gripper import jaw_width_limit, widest_pair_m


def check_cloud(cloud: PerceivedCloud, position: int) -> None:
    """Raise ``ValueError`` naming cloud ``position`` where its arrays cannot be planned on."""
    points, normals = cloud.points_world, cloud.normals_world
    if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape:
        raise ValueError(
            f"cloud {position} ({cloud.object_id}): points_world and normals_world must both be (N, 3), "
            f"got {tuple(points.shape)} and {tuple(normals.shape)}"
        )
    if points.shape[0] < 2:
        raise ValueError(f"cloud {position} ({cloud.object_id}) has {points.shape[0]} points; planning needs at least 2")
    if cloud.obstacle_points_world.ndim != 2 or cloud.obstacle_points_world.shape[1] != 3:
        raise ValueError(f"cloud {position} ({cloud.object_id}): obstacle_points_world must be (M, 3)")


@dataclass
class SampledInputs:
    """The random draws of one planning call for one cloud (identical for every method)."""

    pair_indices: torch.Tensor  # (P, 2) int64 indices into the cloud's points
    occupancy_points: torch.Tensor  # (M, 3) object points then obstacle points the occupancy check counts
    occupancy_total: int  # object points in ``occupancy_points``: the occupancy fraction's denominator
    hand_check_points: torch.Tensor  # (H, 3) object then obstacle points the swept-hand check tests
    hand_screen_points: torch.Tensor  # (S, 3) a coarser subset of them, probed first


def sample_inputs(cloud: PerceivedCloud, robot: RobotDescription, planner: PlannerConfig, memory: MemoryConfig, seed: int) -> SampledInputs:
    """Draw the contact pairs and the occupancy subset of ``cloud`` from one generator seeded by ``seed``."""
    # The draws come from a CPU generator on every device: a seed gives the same pairs and subsets
    # wherever the plan runs (CUDA generators draw other streams).
    generator = torch.Generator().manual_seed(int(seed))
    device = cloud.points_world.device
    if planner.pair_sampling == "guided":
        # Proposals wider than the open jaws can descend around pass the width filter but are
        # never usable, so the guided sampler's reach is the narrower of the two limits.
        pair_indices = sample_guided_pair_indices(
            cloud.points_world.to(torch.float32),
            cloud.normals_world.to(torch.float32),
            planner.n_pairs,
            planner.pair_proposals,
            planner.min_width_m,
            min(widest_pair_m(robot, planner), jaw_width_limit(robot, planner)),
            generator,
            memory.pair_proposal_chunk_elements,
            planner.compile,
        )
    else:
        pair_indices = sample_pair_indices(cloud.n_points, planner.n_pairs, generator).to(device)
    object_subset = sample_subset_indices(cloud.n_points, planner.occupancy_max_points, generator).to(device)
    n_obstacles = cloud.obstacle_points_world.shape[0]
    n_obstacles_kept = round(n_obstacles * len(object_subset) / cloud.n_points)
    obstacle_subset = sample_subset_indices(n_obstacles, n_obstacles_kept, generator).to(device)
    occupancy_points = torch.cat(
        (
            cloud.points_world.to(torch.float32)[object_subset],
            cloud.obstacle_points_world.to(torch.float32)[obstacle_subset],
        )
    )
    scene_points = torch.cat((cloud.points_world.to(torch.float32), cloud.obstacle_points_world.to(torch.float32)))
    hand_check_points = scene_points[voxel_representatives(scene_points, planner.hand_check_voxel_m)]
    hand_screen_points = hand_check_points[voxel_representatives(hand_check_points, planner.hand_screen_voxel_m)]
    return SampledInputs(pair_indices, occupancy_points, len(object_subset), hand_check_points, hand_screen_points)
