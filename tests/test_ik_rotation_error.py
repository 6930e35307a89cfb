"""The IK's rotation error is pytorch-kinematics' matrix_to_axis_angle, bit for bit, for turns of every size."""
import math

import pytorch_kinematics as pk
import torch

from sagp_batched.robot.ik import _rotation_error_vector


def test_rotation_error_equals_pk_matrix_to_axis_angle_bit_for_bit_from_zero_to_a_half_turn():
    generator = torch.Generator().manual_seed(0)
    count = 20000
    axis = torch.nn.functional.normalize(torch.randn(count, 3, generator=generator), dim=1)
    # Angles from 0 to pi, with many small ones (IK errors) and some at exactly 0, 90 deg and pi.
    angle = torch.cat((torch.rand(count // 2, generator=generator) * 0.1, torch.rand(count // 2 - 3, generator=generator) * math.pi, torch.tensor([0.0, math.pi / 2, math.pi])))
    current = pk.axis_and_angle_to_matrix_33(torch.nn.functional.normalize(torch.randn(count, 3, generator=generator), dim=1), torch.rand(count, generator=generator) * 6.0)
    target = pk.axis_and_angle_to_matrix_33(axis, angle) @ current
    for dtype in (torch.float32, torch.float64):
        got = _rotation_error_vector(target.to(dtype), current.to(dtype))
        expected = pk.matrix_to_axis_angle(target.to(dtype) @ current.to(dtype).transpose(1, 2))
        assert torch.equal(got, expected)
