"""Closed-form inverse kinematics of the Franka Panda arm, batched over targets, sampled q7 values and branches.

Why a closed form: an iterative solver (pytorch-kinematics' ``PseudoInverseIK``) pays Python
overhead on every iteration and keeps iterating rows that have converged or never will, while the
Panda's geometry admits a direct solution once the redundant joint 7 is fixed: a few hundred flops per
(target, q7, branch), all rows in the same handful of tensor operations.

Frames are the URDF joint frames of ``franka_panda/panda.urdf``, which coincide with Craig's modified
Denavit-Hartenberg frames: frame i = frame i-1 * Rx(alpha_i) * Tx(a_i) * Tz(d_i) * Rz(q_i) with
alpha = (0, -pi/2, pi/2, pi/2, -pi/2, pi/2, pi/2), a = (0, 0, 0, a3, a4, 0, a6) and
d = (d1, 0, d3, 0, d5, 0, 0) (``PandaArmGeometry``). Frame 0 is the robot base (``panda_link0``).

Solution, for a target pose (R7, O7) of frame 7 and a chosen q7:

* Wrist: frame 6 follows from frame 7 and q7 alone (x6 = cos q7 x7 - sin q7 y7, y6 = -z7), and
  O6 = O7 - a6 x6. Frames 5 and 6 share their origin.
* Elbow: the shoulder O2 = (0, 0, d1) is fixed, and |O6 - O2| depends on q4 alone (upper arm (a3, 0, d3)
  in frame 3, forearm (a4, d5, 0) in frame 4), so the law of cosines gives q4 = phi +- acos(...)
  with phi = -0.47 rad on the Panda: two elbow branches, both inside q4's limits [-3.07, -0.07]
  (-pi..0 in pybullet_data's URDF) when the elbow is within 0.47 rad of straight.
* Forearm: u = O2 - O5 in frame 4 is known once q4 is (its z component is 0), and
  s = R6^T (O2 - O6) = Rz(-q6) Rx(-pi/2) Rz(-q5) Rx(pi/2) u = (c6 c5 ux + s6 uy, -s6 c5 ux + c6 uy, s5 ux),
  so sin q5 = s_z / ux (two branches) and q6 = atan2(uy, c5 ux) - atan2(s_y, s_x).
* Shoulder: R03 = R6 R36^T = Rz(q1) Ry(q2) Rz(q3) (ZYZ Euler angles, two branches by the sign of q2).
  When sin q2 vanishes only q1 + q3 is determined; it is split evenly, which keeps both inside
  their limits.

Every (q7, elbow, forearm, shoulder) combination is returned with a mask of those that are real
solutions inside the joint limits; angles are shifted by 2 pi where that brings them inside the
limits (joint 6's range crosses pi).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import torch

N_BRANCHES = 8  # 2 elbow (q4) x 2 forearm (q5) x 2 shoulder (q2) branches per q7
N_JOINTS = 7  # the arm this closed form solves: the Panda's seven revolute joints
# A cosine or sine this far beyond +-1 still counts as a real solution at the extreme (straight elbow,
# q5 = +-pi/2): float32 rounding of a pose FK produced there overshoots by ~1e-7, and the clamped
# answer misses the pose by a few micrometres, which the caller's forward-kinematics check sees.
ROUNDING_SLACK = 1e-5


class PandaArmGeometry(NamedTuple):
    """Link offsets of the Panda arm (modified Denavit-Hartenberg a and d), metres."""

    shoulder_height_m: float  # d1: base origin to joint 2 along z0
    upper_arm_m: float  # d3: joint 2 to joint 3 along z3
    elbow_offset_m: float  # a3: joint 3 to joint 4 along x3
    elbow_return_m: float  # a4: joint 4 to joint 5 along x4 (negative on the Panda)
    forearm_m: float  # d5: joint 4 to joint 5 along z5
    wrist_offset_m: float  # a6: joint 6 to joint 7 along x6


class PandaIKSolutions(NamedTuple):
    """All closed-form solutions for N targets, K q7 samples and ``N_BRANCHES`` branches."""

    # (N, K, 8, 7) arm joints, radians (meaningless where not valid), a view of a (7, N, K, 8)
    # tensor: each joint's values are contiguous.
    joints: torch.Tensor
    valid: torch.Tensor  # (N, K, 8) bool: a real solution with every joint inside the limits


def _wrap(angle: torch.Tensor) -> torch.Tensor:
    """Angles (radians, any shape) wrapped to [-pi, pi)."""
    return torch.remainder(angle + math.pi, 2.0 * math.pi) - math.pi


def _into_limits(angle: torch.Tensor, lower: float, upper: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``angle`` (radians in [-pi, pi], any shape) shifted by 2 pi where that brings it inside
    [lower, upper], and a same-shape bool mask of angles inside the limits.

    Only limits reaching beyond +-pi (joint 6's) can take in a shifted angle: for any others
    ``angle`` is returned as it is, the shift would leave every angle it moves outside, where
    its value is of no use (four of every six operations, over the closed form's largest tensors).
    """
    if -math.pi < lower and upper < math.pi:
        return angle, (angle >= lower) & (angle <= upper)
    two_pi = 2.0 * math.pi
    shifted = torch.where(angle < lower, angle + two_pi, torch.where(angle > upper, angle - two_pi, angle))
    return shifted, (shifted >= lower) & (shifted <= upper)


def _rotate_z(
    cos: torch.Tensor, sin: torch.Tensor, x: torch.Tensor, y: torch.Tensor, z: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Components of Rz(angle) (x, y, z), given cos and sin of the angle (broadcasting tensors)."""
    return cos * x - sin * y, sin * x + cos * y, z


def panda_ik_closed_form(
    rotation_link7: torch.Tensor,
    position_link7: torch.Tensor,
    q7: torch.Tensor,
    geometry: PandaArmGeometry,
    lower: torch.Tensor,
    upper: torch.Tensor,
) -> PandaIKSolutions:
    """Every arm configuration that puts frame 7 at the given poses, for each sampled q7.

    Args:
        rotation_link7: (N, 3, 3) orientation of frame 7 (``panda_link7``) in the base frame.
        position_link7: (N, 3) origin of frame 7 in the base frame, metres.
        q7: (N, K) values of joint 7 to solve for per target, radians.
        geometry: the arm's link offsets.
        lower: (7,) lower joint limits, radians.
        upper: (7,) upper joint limits, radians.

    Returns:
        ``PandaIKSolutions`` with (N, K, 8, 7) joints and an (N, K, 8) validity mask, in the
        inputs' dtype (float64 keeps the solutions within ~1e-7 rad of exact even next to the
        singularities, where float32 input rounding alone moves them by ~1e-3 rad).
        Branch b uses elbow branch b // 4, forearm branch (b // 2) % 2 and shoulder branch b % 2.
    """
    n_targets, n_q7 = q7.shape
    lower, upper = lower.tolist(), upper.tolist()
    q7 = q7.to(rotation_link7.dtype)
    x6, y6, z6, shoulder_to_wrist = _wrist(rotation_link7, position_link7, q7, geometry)
    q4, elbow_ok = _elbow(shoulder_to_wrist, geometry, lower[3], upper[3])
    a3, d3, a4, d5 = geometry.elbow_offset_m, geometry.upper_arm_m, geometry.elbow_return_m, geometry.forearm_m
    cos4, sin4 = torch.cos(q4), torch.sin(q4)
    u_x = -a3 * cos4 - d3 * sin4 - a4  # O2 - O5 in frame 4, (N, K, 2)
    u_y = a3 * sin4 - d3 * cos4 - d5

    # Forearm: s = R6^T (O2 - O6).
    s_x, s_y, s_z = (-(shoulder_to_wrist * axis).sum(dim=-1) for axis in (x6, y6, z6))  # (N, K)
    sin5_needed = s_z[..., None] / u_x  # (N, K, 2)
    elbow_ok = elbow_ok & (sin5_needed.abs() <= 1.0 + ROUNDING_SLACK)  # both forearm branches are real or neither
    asin5 = torch.asin(sin5_needed.clamp(-1.0, 1.0))
    q5, q5_inside = _into_limits(_wrap(torch.stack((asin5, math.pi - asin5), dim=-1)), lower[4], upper[4])  # (N, K, 2, 2)
    cos5, sin5 = torch.cos(q5), torch.sin(q5)
    q6 = _wrap(torch.atan2(u_y[..., None], cos5 * u_x[..., None]) - torch.atan2(s_y, s_x)[..., None, None])
    q6, q6_inside = _into_limits(q6, lower[5], upper[5])
    cos6, sin6 = torch.cos(q6), torch.sin(q6)
    cos4, sin4 = cos4[..., None], sin4[..., None]
    arm_ok = elbow_ok[..., None] & q5_inside & q6_inside  # (N, K, 2, 2)

    q1, q2, q3 = _shoulder_angles(x6, y6, z6, cos4, sin4, cos5, sin5, cos6, sin6)  # (N, K, 2, 2, 2) each
    (q1, q1_inside), (q2, q2_inside), (q3, q3_inside) = (
        _into_limits(angle, lower[joint], upper[joint]) for joint, angle in enumerate((q1, q2, q3))
    )
    q7_inside = (q7 >= lower[6]) & (q7 <= upper[6])
    valid = q1_inside & q2_inside & q3_inside & arm_ok[..., None] & q7_inside[..., None, None, None]
    joints = _joint_major(q1, q2, q3, q4, q5, q6, q7)
    return PandaIKSolutions(
        joints=joints.reshape(7, n_targets, n_q7, N_BRANCHES).permute(1, 2, 3, 0), valid=valid.reshape(n_targets, n_q7, N_BRANCHES)
    )


def _wrist(
    rotation_link7: torch.Tensor, position_link7: torch.Tensor, q7: torch.Tensor, geometry: PandaArmGeometry
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Frame 6's axes x6, y6, z6 in the base frame and the wrist's offset from the shoulder O6 - O2,
    (N, K, 3) each, for (N, 3, 3) / (N, 3) poses of frame 7 and (N, K) ``q7`` in their dtype."""
    cos7, sin7 = torch.cos(q7)[..., None], torch.sin(q7)[..., None]
    x7, y7, z7 = (rotation_link7[:, None, :, axis] for axis in range(3))  # (N, 1, 3) each
    x6 = cos7 * x7 - sin7 * y7  # (N, K, 3)
    y6 = (-z7).expand_as(x6)
    z6 = torch.linalg.cross(x6, y6)
    shoulder = position_link7.new_tensor([0.0, 0.0, geometry.shoulder_height_m])
    shoulder_to_wrist = position_link7[:, None, :] - geometry.wrist_offset_m * x6 - shoulder  # O6 - O2, (N, K, 3)
    return x6, y6, z6, shoulder_to_wrist


def _elbow(shoulder_to_wrist: torch.Tensor, geometry: PandaArmGeometry, lower: float, upper: float) -> tuple[torch.Tensor, torch.Tensor]:
    """q4 (N, K, 2) of the two elbow branches that span the wrist's offset O6 - O2 (N, K, 3) from
    the shoulder, inside joint 4's limits [``lower``, ``upper``] where it can be, and whether each
    branch is a real solution inside them, (N, K, 2) bool."""
    # |O6 - O2|^2 = L + 2 (A cos q4 + B sin q4) with the constants below.
    a3, d3, a4, d5 = geometry.elbow_offset_m, geometry.upper_arm_m, geometry.elbow_return_m, geometry.forearm_m
    length_sq = a3**2 + d3**2 + a4**2 + d5**2
    coeff_cos, coeff_sin = a3 * a4 + d3 * d5, d3 * a4 - a3 * d5
    amplitude, phase = math.hypot(coeff_cos, coeff_sin), math.atan2(coeff_sin, coeff_cos)
    elbow_ratio = (shoulder_to_wrist.square().sum(dim=-1) - length_sq) / (2.0 * amplitude)  # (N, K)
    elbow_spread = torch.acos(elbow_ratio.clamp(-1.0, 1.0))
    q4, q4_inside = _into_limits(_wrap(phase + torch.stack((-elbow_spread, elbow_spread), dim=-1)), lower, upper)
    return q4, q4_inside & (elbow_ratio.abs() <= 1.0 + ROUNDING_SLACK)[..., None]


def _joint_major(
    q1: torch.Tensor, q2: torch.Tensor, q3: torch.Tensor, q4: torch.Tensor, q5: torch.Tensor, q6: torch.Tensor, q7: torch.Tensor
) -> torch.Tensor:
    """(7, N, K, 2, 2, 2) every branch's joints, from (N, K, 2, 2, 2) ``q1`` to ``q3``, (N, K, 2)
    ``q4``, (N, K, 2, 2) ``q5`` and ``q6`` and (N, K) ``q7``."""
    shape = q1.shape
    # Stacked joint-major: seven contiguous copies, where stacking along a last axis of 7
    # writes every value with a stride of 7.
    return torch.stack(
        (q1, q2, q3, q4[..., None, None].expand(shape), q5[..., None].expand(shape), q6[..., None].expand(shape),
         q7[..., None, None, None].expand(shape)),
    )


def wrist_in_reach(rotation_link7: torch.Tensor, position_link7: torch.Tensor, geometry: PandaArmGeometry) -> torch.Tensor:
    """Whether some value of q7 brings the wrist within the elbow's reach of the shoulder.

    Where it does not, ``panda_ik_closed_form`` finds no solution at any q7 (its elbow test fails
    by more than its rounding slack), so a caller can skip such targets instead of searching a
    fine q7 grid for nothing (grasps on the far side of an object beyond the arm's reach).

    O6 = O7 - a6 (cos q7 x7 - sin q7 y7) runs over a circle of radius |a6| about O7 normal to z7,
    so |O6 - O2|^2 spans [h^2 + (rho - |a6|)^2, h^2 + (rho + |a6|)^2], h and rho the parts of
    O7 - O2 along z7 and across it; the elbow reaches |O6 - O2|^2 = L + 2 A cos(q4 - phi) only.

    Args:
        rotation_link7: (N, 3, 3) orientation of frame 7 in the base frame.
        position_link7: (N, 3) origin of frame 7 in the base frame, metres.
        geometry: the arm's link offsets.

    Returns:
        (N,) bool, False only where no q7 can give a solution.
    """
    a3, d3, a4, d5 = geometry.elbow_offset_m, geometry.upper_arm_m, geometry.elbow_return_m, geometry.forearm_m
    length_sq = a3**2 + d3**2 + a4**2 + d5**2
    amplitude = math.hypot(a3 * a4 + d3 * d5, d3 * a4 - a3 * d5)
    shoulder_to_target = position_link7 - position_link7.new_tensor([0.0, 0.0, geometry.shoulder_height_m])
    along = (shoulder_to_target * rotation_link7[..., 2]).sum(dim=-1)
    across = (shoulder_to_target - along[:, None] * rotation_link7[..., 2]).norm(dim=-1)
    wrist = abs(geometry.wrist_offset_m)
    nearest_sq = along.square() + (across - wrist).square()
    farthest_sq = along.square() + (across + wrist).square()
    # The closed form admits |O6 - O2|^2 within L +- 2 A (1 + ROUNDING_SLACK); 1e-9 m^2 is far
    # beyond the float64 rounding of either side and far inside any reach that matters.
    reach = 2.0 * amplitude * (1.0 + ROUNDING_SLACK) + 1e-9
    return (nearest_sq <= length_sq + reach) & (farthest_sq >= length_sq - reach)


def _shoulder_angles(
    x6: torch.Tensor, y6: torch.Tensor, z6: torch.Tensor,
    cos4: torch.Tensor, sin4: torch.Tensor, cos5: torch.Tensor, sin5: torch.Tensor, cos6: torch.Tensor, sin6: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(q1, q2, q3), each (N, K, 2, 2, 2), that give frame 3 the orientation frame 6's axes
    (``x6``, ``y6``, ``z6``: (N, K, 3), base frame) and the (N, K, 2, 1) / (N, K, 2, 2) cosines and
    sines of q4, q5 and q6 leave for it; the last dimension is the shoulder branch (sign of q2).
    Angles are wrapped to (-pi, pi], not yet moved into the joint limits."""
    # Shoulder: R03 = R6 R36^T, R36 = Rx(pi/2) Rz(q4) Rx(-pi/2) Rz(q5) Rx(pi/2) Rz(q6) = Ry(-q4) Rz(q5) Rx(pi/2) Rz(q6).
    # Row 2 of R03 is R36 applied to the base z axis in frame 6; column 2 is R6 R36^T e_z.
    up_x, up_y, up_z = (axis[..., 2, None, None] for axis in (x6, y6, z6))  # base z axis in frame 6
    x, y, z = _rotate_z(cos6, sin6, up_x, up_y, up_z)
    x, y, z = _rotate_z(cos5, sin5, x, -z, y)  # Rx(pi/2) first
    r20, r21, r22 = cos4 * x - sin4 * z, y, sin4 * x + cos4 * z  # Ry(-q4)
    x, y, z = cos5 * sin4, -sin5 * sin4, cos4  # Rz(-q5) Ry(q4) e_z
    x, y, z = _rotate_z(cos6, -sin6, x, z, -y)  # Rx(-pi/2) first
    r02 = x * x6[..., 0, None, None] + y * y6[..., 0, None, None] + z * z6[..., 0, None, None]
    r12 = x * x6[..., 1, None, None] + y * y6[..., 1, None, None] + z * z6[..., 1, None, None]
    q2_magnitude = torch.acos(r22.clamp(-1.0, 1.0))
    q1_up, q3_up = torch.atan2(r12, r02), torch.atan2(r21, -r20)
    # sin q2 = 0 leaves only q1 + q3 (R03 = Rz(q1 + q3); q2 = pi lies outside the Panda's limits).
    q1_down, q3_down = _wrap(q1_up + math.pi), _wrap(q3_up + math.pi)
    aligned = torch.sin(q2_magnitude) < 1e-6  # beyond it atan2 of the O(1e-16) entries is noise
    if aligned.any():
        x, y, z = cos5 * cos4, -sin5 * cos4, -sin4  # Rz(-q5) Ry(q4) e_x
        x, y, z = _rotate_z(cos6, -sin6, x, z, -y)
        r00 = x * x6[..., 0, None, None] + y * y6[..., 0, None, None] + z * z6[..., 0, None, None]
        r10 = x * x6[..., 1, None, None] + y * y6[..., 1, None, None] + z * z6[..., 1, None, None]
        half_sum = 0.5 * torch.atan2(r10, r00)
        q1_up, q3_up = torch.where(aligned, half_sum, q1_up), torch.where(aligned, half_sum, q3_up)
        # The "down" branch repeats the aligned solution.
        q1_down, q3_down = torch.where(aligned, q1_up, q1_down), torch.where(aligned, q3_up, q3_down)
    q1 = torch.stack((_wrap(q1_up), q1_down), dim=-1)  # (N, K, 2, 2, 2)
    q3 = torch.stack((_wrap(q3_up), q3_down), dim=-1)
    q2 = torch.stack((q2_magnitude, -q2_magnitude), dim=-1)
    return q1, q2, q3
