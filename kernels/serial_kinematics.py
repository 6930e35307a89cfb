"""Forward kinematics and the geometric Jacobian of a serial chain of revolute joints, batched.

Why not pytorch-kinematics' own (``Chain.forward_kinematics_tensor``, which these reproduce to
float32 rounding): it composes the frames as batched 4x4 matrix products, and a product of B tiny
matrices costs one small GEMM each, and it builds every joint's 4x4 rotation through a dozen
intermediate tensors, a cost per configuration that the ~7,600 waypoints of one motion check
multiply. Here each matrix entry is a row of B values (structure of arrays), so a frame's product
is two elementwise operations over (3, 3, 4, B) and an addition, whatever B. The frames are
returned in that layout, (F, 3, 4, B), and the Jacobian reads them so: its callers need rows (an
end frame's position, a link's height), and no (F, B, 4, 4) copy is made. At the ~10
configurations of a damped-least-squares step, where every tensor operation costs its dispatch
whatever its size, a pass is ~50 operations, fewer than pk's.

Frames follow pytorch-kinematics' convention: frame f's pose is its parent's (frame f - 1, the
base for frame 0) times its static offset (the URDF link and joint origin), times the rotation of
its joint about the joint's axis if it has one.
"""
from __future__ import annotations

from typing import NamedTuple

import torch


class SerialChain(NamedTuple):
    """A serial chain of fixed and revolute joints in the form ``serial_chain_frames`` evaluates (``serial_chain``)."""

    # (3, F, 3, 3, 1): frame f's rotation from its parent's is terms[0, f] + cos q terms[1, f] +
    # sin q terms[2, f], q its joint's angle (the cos and sin terms are zero for a fixed frame);
    # the trailing axis broadcasts over configurations.
    rotation_terms: torch.Tensor
    translation: torch.Tensor  # (F, 3, 1, 1) frame f's origin in its parent's frame, metres
    joint_of_frame: torch.Tensor  # (F,) int64 joint turning each frame (0 for a fixed frame)


def serial_chain(static_offsets: torch.Tensor, joint_of_frame: tuple[int, ...], axes: torch.Tensor) -> SerialChain:
    """The chain whose frame f is its parent's (frame f - 1, the base for frame 0) times
    ``static_offsets[f]`` (F, 4, 4), times a turn of joint ``joint_of_frame[f]`` (-1: none) about
    its axis (``axes``: (J, 3) unit, in the joint's frame)."""
    rotation = static_offsets[:, :3, :3]
    terms = torch.zeros(3, len(joint_of_frame), 3, 3, dtype=static_offsets.dtype)
    terms[0] = rotation
    for frame, joint in enumerate(joint_of_frame):
        if joint >= 0:
            # Rodrigues: R(q) = k k^T + cos q (I - k k^T) + sin q [k]x, premultiplied by the offset.
            k = axes[joint].to(static_offsets.dtype)
            along = torch.outer(k, k)
            cross = torch.zeros(3, 3, dtype=k.dtype)
            cross[0, 1], cross[0, 2], cross[1, 2] = -k[2], k[1], -k[0]
            cross = cross - cross.T
            terms[:, frame] = torch.stack((rotation[frame] @ along, rotation[frame] @ (torch.eye(3, dtype=k.dtype) - along), rotation[frame] @ cross))
    return SerialChain(terms[..., None], static_offsets[:, :3, 3, None, None].clone(), torch.tensor(joint_of_frame).clamp_min(0))


def serial_chain_frames(joints: torch.Tensor, chain: SerialChain) -> torch.Tensor:
    """Poses of every frame of ``chain`` at B joint configurations, as rows of B values.

    Args:
        joints: (B, J) joint angles, radians.
        chain: the chain's F frames (``serial_chain``).

    Returns:
        (F, 3, 4, B) in ``joints``' dtype: [f, :, :3, b] frame f's rotation to the base frame
        at configuration b, [f, :, 3, b] its origin there (the top three rows of its 4x4
        transform).
    """
    n_frames, n_configs = chain.translation.shape[0], joints.shape[0]
    fixed, by_cos, by_sin = chain.rotation_terms.to(joints.dtype).unbind(0)
    angles = joints.T[chain.joint_of_frame].reshape(n_frames, 1, 1, n_configs)
    # Every frame's transform from its parent's as (F, 3, 4, B).
    local = torch.cat(
        (
            torch.addcmul(fixed, by_cos, torch.cos(angles)).addcmul_(by_sin, torch.sin(angles)),
            chain.translation.to(joints.dtype).expand(-1, -1, -1, n_configs),
        ),
        dim=2,
    )
    frames = torch.empty_like(local)
    frames[0] = local[0]
    # Views made once, not per frame: at the ~10 configurations of a damped-least-squares step
    # each view costs about as much as the arithmetic.
    outputs, locals_ = frames.unbind(0), local.unbind(0)
    rotations, origins = frames[:, :, :3, None].unbind(0), frames[:, :, 3].unbind(0)
    for frame in range(1, n_frames):
        # (3, 4, B): the rotation, and the origin's offset, in the base frame
        torch.sum(rotations[frame - 1] * locals_[frame], dim=1, out=outputs[frame])
        origins[frame].add_(origins[frame - 1])
    return frames


def geometric_jacobian(frames: torch.Tensor, joint_frames: torch.Tensor, axes: torch.Tensor, end_frame: int) -> torch.Tensor:
    """The geometric Jacobian of a chain's end frame, base frame, from its frames' poses.

    Args:
        frames: (F, 3, 4, B) frame poses in the base frame (``serial_chain_frames``).
        joint_frames: (J,) int64 frame indices, the frame each revolute joint turns (a tensor: the
            damped-least-squares steps that call this every iteration would otherwise convert a
            list each time).
        axes: (J, 3) unit joint axes, each in its own frame.
        end_frame: index of the end frame.

    Returns:
        (B, 6, J): rows 0-2 the end frame origin's linear velocity (m/rad), rows 3-5 its
        angular velocity, per unit joint velocity.
    """
    joint = frames[joint_frames]  # (J, 3, 4, B)
    axis_base = (joint[:, :, :3] * axes.to(frames.dtype)[:, None, :, None]).sum(dim=2)  # (J, 3, B)
    lever = frames[end_frame, None, :, 3] - joint[:, :, 3]
    linear = torch.linalg.cross(axis_base, lever, dim=1)
    return torch.cat((linear, axis_base), dim=1).permute(2, 1, 0)
