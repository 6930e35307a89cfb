"""Forward kinematics and the geometric Jacobian of a serial chain of revolute joints, batched.

Why not pytorch-kinematics' own (``Chain.forward_kinematics_tensor``, which these reproduce to
float32 rounding): it composes the frames as batched 4x4 matrix products, and a product of B tiny
matrices costs one small GEMM each, and it builds every joint's 4x4 rotation through a dozen
intermediate tensors; on these CPUs that is ~4 us a configuration (25-38 ms for the ~7,600
waypoints of one motion check). Here each matrix entry is a row of B values (structure of
arrays), so a frame's product is two elementwise operations over (3, 3, 4, B): ~3 ms for the same
7,600, and half pk's time for the ~10-configuration calls of damped least squares.

Frames follow pytorch-kinematics' convention: frame f's pose is its parent's (frame f - 1, the
base for frame 0) times its static offset (the URDF link and joint origin), times the rotation of
its joint about the joint's axis if it has one.
"""
from __future__ import annotations

from typing import NamedTuple

import torch


class SerialChain(NamedTuple):
    """A serial chain of fixed and revolute joints in the form ``serial_chain_poses`` evaluates (``serial_chain``)."""

    # (F, 3, 3, 3): frame f's rotation from its parent's is terms[f, 0] + cos q terms[f, 1] + sin q
    # terms[f, 2], q its joint's angle (the cos and sin terms are zero for a fixed frame).
    rotation_terms: torch.Tensor
    translation: torch.Tensor  # (F, 3) frame f's origin in its parent's frame, metres
    joint_of_frame: torch.Tensor  # (F,) int64 joint turning each frame (0 for a fixed frame)


def serial_chain(static_offsets: torch.Tensor, joint_of_frame: tuple[int, ...], axes: torch.Tensor) -> SerialChain:
    """The chain whose frame f is its parent's (frame f - 1, the base for frame 0) times
    ``static_offsets[f]`` (F, 4, 4), times a turn of joint ``joint_of_frame[f]`` (-1: none) about
    its axis (``axes``: (J, 3) unit, in the joint's frame)."""
    rotation = static_offsets[:, :3, :3]
    terms = torch.zeros(len(joint_of_frame), 3, 3, 3, dtype=static_offsets.dtype)
    terms[:, 0] = rotation
    for frame, joint in enumerate(joint_of_frame):
        if joint >= 0:
            # Rodrigues: R(q) = k k^T + cos q (I - k k^T) + sin q [k]x, premultiplied by the offset.
            k = axes[joint].to(static_offsets.dtype)
            along = torch.outer(k, k)
            cross = torch.zeros(3, 3, dtype=k.dtype)
            cross[0, 1], cross[0, 2], cross[1, 2] = -k[2], k[1], -k[0]
            cross = cross - cross.T
            terms[frame] = torch.stack((rotation[frame] @ along, rotation[frame] @ (torch.eye(3, dtype=k.dtype) - along), rotation[frame] @ cross))
    return SerialChain(terms, static_offsets[:, :3, 3].clone(), torch.tensor(joint_of_frame).clamp_min(0))


def serial_chain_poses(joints: torch.Tensor, chain: SerialChain) -> torch.Tensor:
    """Poses of every frame of ``chain`` at B joint configurations.

    Args:
        joints: (B, J) joint angles, radians.
        chain: the chain's F frames (``serial_chain``).

    Returns:
        (F, B, 4, 4) transforms from each frame to the chain's base frame, in ``joints``' dtype.
    """
    n_frames, n_configs = chain.translation.shape[0], joints.shape[0]
    terms, translation = chain.rotation_terms.to(joints.dtype), chain.translation.to(joints.dtype)
    angles = joints.T[chain.joint_of_frame][:, None, None, :]  # (F, 1, 1, B)
    # Every frame's transform from its parent's as (F, 3, 4, B): entry rows of B values.
    local = torch.cat(
        (
            torch.addcmul(terms[:, 0, ..., None], terms[:, 1, ..., None], torch.cos(angles)).addcmul_(terms[:, 2, ..., None], torch.sin(angles)),
            translation[:, :, None, None].expand(-1, -1, -1, n_configs),
        ),
        dim=2,
    )
    frames = [local[0]]
    for frame in range(1, n_frames):
        parent = frames[-1]
        pose = (parent[:, :3, None, :] * local[frame]).sum(dim=1)  # (3, 4, B): rotation, and the origin's offset
        pose[:, 3] += parent[:, 3]
        frames.append(pose)
    poses = torch.zeros(n_frames, n_configs, 4, 4, dtype=joints.dtype)
    poses[..., :3, :] = torch.stack(frames).permute(0, 3, 1, 2)
    poses[..., 3, 3] = 1.0
    return poses


def geometric_jacobian(poses: torch.Tensor, joint_frames: tuple[int, ...], axes: torch.Tensor, end_frame: int) -> torch.Tensor:
    """The geometric Jacobian of a chain's end frame, base frame, from its frames' poses.

    Args:
        poses: (F, B, 4, 4) frame-to-base transforms (``serial_chain_poses``).
        joint_frames: J frame indices, the frame each revolute joint turns.
        axes: (J, 3) unit joint axes, each in its own frame.
        end_frame: index of the end frame.

    Returns:
        (B, 6, J): rows 0-2 the end frame origin's linear velocity (m/rad), rows 3-5 its
        angular velocity, per unit joint velocity.
    """
    frames = poses[list(joint_frames)]  # (J, B, 4, 4)
    axis_base = (frames[..., :3, :3] * axes.to(poses.dtype)[:, None, None, :]).sum(dim=-1)  # (J, B, 3)
    lever = poses[end_frame, None, :, :3, 3] - frames[..., :3, 3]
    linear = torch.linalg.cross(axis_base, lever, dim=-1)
    return torch.cat((linear, axis_base), dim=-1).permute(1, 2, 0)
