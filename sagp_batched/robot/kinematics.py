"""The Panda arm's chain as the IK reads it: the pytorch-kinematics chain to the grasp target,
its frames in the layout ``sagp_batched_kernels.serial_kinematics`` takes, and the link offsets
the closed-form IK (``sagp_batched_kernels.panda_ik``) needs, checked against the joint layout
the robot description says it assumes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import pytorch_kinematics as pk
import torch

from sagp_batched_kernels.panda_ik import N_JOINTS, PandaArmGeometry
from sagp_batched_kernels.serial_kinematics import SerialChain, geometric_jacobian, serial_chain, serial_chain_frames

from .. import description_files
from .description import RobotDescription


def arm_chain(robot: RobotDescription) -> pk.SerialChain:
    """The robot's arm chain up to its grasp target."""
    robot.require_mounted_gripper("the arm's IK")
    return description_files.serial_chain(robot.urdf_path, robot.gripper.grasp_target_link)


def link_moved_by(chain: pk.SerialChain, joint_name: str) -> str:
    """Name of the link that joint ``joint_name`` of ``chain`` moves (the link of its frame)."""
    return next(name for name in chain.get_frame_names() if chain.find_frame(name).joint.name == joint_name)


@dataclass(frozen=True)
class ChainFrames:
    """A serial chain's frames as ``serial_chain_frames`` takes them, read from a pytorch-kinematics chain."""

    names: tuple[str, ...]  # every frame, base first, fixed ones included
    chain: SerialChain
    joint_frames: torch.Tensor  # (J,) int64: the frame each joint turns
    axes: torch.Tensor  # (J, 3) joint axes in their frames

    @classmethod
    def of(cls, chain: pk.SerialChain) -> "ChainFrames":
        names = tuple(chain.get_frame_names(exclude_fixed=False))
        joint_names = chain.get_joint_parameter_names()
        frames = [chain.find_frame(name) for name in names]
        if any(frame.joint.joint_type not in ("fixed", "revolute") for frame in frames):
            raise ValueError("serial_chain_frames models fixed and revolute joints only")
        offsets = []
        for frame in frames:
            offset = torch.eye(4, dtype=chain.dtype)
            for origin in (frame.link.offset, frame.joint.offset):
                if origin is not None:
                    offset = offset @ origin.get_matrix()[0]
            offsets.append(offset)
        moving = [frame.joint.name if frame.joint.joint_type == "revolute" else None for frame in frames]
        joint_frames = tuple(moving.index(name) for name in joint_names)
        axes = torch.stack([frames[index].joint.axis for index in joint_frames])
        joint_of_frame = tuple(-1 if name is None else joint_names.index(name) for name in moving)
        return cls(
            names=names, chain=serial_chain(torch.stack(offsets), joint_of_frame, axes), joint_frames=torch.tensor(joint_frames), axes=axes
        )

    def to(self, device: torch.device) -> "ChainFrames":
        """These frames with every tensor on ``device``."""
        return ChainFrames(
            names=self.names, chain=SerialChain(*(tensor.to(device) for tensor in self.chain)),
            joint_frames=self.joint_frames.to(device), axes=self.axes.to(device),
        )

    def poses(self, joints: torch.Tensor) -> torch.Tensor:
        """(F, 3, 4, M) every frame's pose in the chain's base frame at (M, J) ``joints``, as rows
        of M values (``serial_chain_frames``)."""
        return serial_chain_frames(joints, self.chain)

    def jacobian(self, poses: torch.Tensor) -> torch.Tensor:
        """(M, 6, J) geometric Jacobian of the last frame from ``poses`` (``self.poses``)."""
        return geometric_jacobian(poses, self.joint_frames, self.axes, len(self.names) - 1)


def panda_arm_geometry(chain: pk.SerialChain, robot: RobotDescription) -> PandaArmGeometry:
    """The link offsets of ``chain``'s arm joints, checked against the frame layout the closed form assumes.

    Each joint frame's offset from its parent must be Rx(alpha) Tx(a) Tz(d) with the robot's twist
    angles alpha, and a and d zero wherever the robot description says they are.
    """
    joint_names = chain.get_joint_parameter_names()
    if tuple(joint_names) != robot.arm_joints or len(joint_names) != N_JOINTS:
        raise ValueError(f"{robot.name}: the closed-form IK solves {N_JOINTS} arm joints; the chain has {joint_names}, "
                         f"the robot names {list(robot.arm_joints)}")
    offsets = [chain.find_frame(name).joint.offset.get_matrix()[0].double() for name in chain.get_frame_names()]
    a, d = [], []
    for offset, twist in zip(offsets, robot.joint_twist_rad):
        cos, sin = math.cos(twist), math.sin(twist)
        twist_rotation = torch.tensor([[1.0, 0.0, 0.0], [0.0, cos, -sin], [0.0, sin, cos]], dtype=torch.float64)
        a_0_d = twist_rotation.T @ offset[:3, 3]
        if not torch.allclose(offset[:3, :3], twist_rotation, atol=1e-6) or abs(float(a_0_d[1])) > 1e-6:
            raise ValueError("the chain's joint frames do not match the Panda layout the closed-form IK assumes")
        a.append(float(a_0_d[0]))
        d.append(float(a_0_d[2]))
    if any(abs(value) > 1e-6 for value, modelled in zip(a + d, robot.joint_has_a + robot.joint_has_d) if not modelled):
        raise ValueError("the chain's joint frames carry offsets the closed-form IK does not model")
    return PandaArmGeometry(
        shoulder_height_m=d[0], upper_arm_m=d[2], elbow_offset_m=a[3], elbow_return_m=a[4], forearm_m=d[4], wrist_offset_m=a[6]
    )
