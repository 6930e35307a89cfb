"""The labelling shake (``ShakeConfig``) at every physics step, and the peaks a shaken hand reached.

Both labelling modes shake the same profile: the arm through its joints (``execution``), the hand
alone through its constraint (``labelling``)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from ..config import ShakeConfig


@dataclass(frozen=True)
class ShakeProfile:
    """The shake of ``ShakeConfig`` sampled at every physics step.

    ``offsets`` and ``velocities`` (T, 6): displacement (m) and rotation vector (rad) of the grasp
    target from its lifted pose, in the lifted grasp frame (x, y, z, then about x, y, z), and
    their rates; ``segments``: (axis, first step, end step) of each shaken axis; ``angular_frequency``
    in rad/s."""

    offsets: np.ndarray
    velocities: np.ndarray
    segments: tuple[tuple[int, int, int], ...]
    angular_frequency: float
    time_step_s: float

    @property
    def steps(self) -> int:
        return int(self.offsets.shape[0])


def shake_profile(shake: ShakeConfig, time_step_s: float) -> ShakeProfile:
    """Every step of the shake: one window after another, ``A (1 - cos wt)`` on each of the window's
    axes for ``cycles`` whole cycles, ``A = peak / w^2``. A window is one axis with a non-zero peak,
    or, with ``shake.linear_with_angular``, the motion along and the rotation about one axis at once."""
    omega = 2.0 * math.pi * shake.frequency_hz
    peaks = (*shake.linear_peak_acceleration_m_s2, *shake.angular_peak_acceleration_rad_s2)
    windows = [(axis, axis + 3) for axis in range(3)] if shake.linear_with_angular else [(axis,) for axis in range(6)]
    windows = [tuple(axis for axis in window if peaks[axis] > 0.0) for window in windows]
    windows = [window for window in windows if window]
    steps_per_window = max(1, round(shake.cycles / shake.frequency_hz / time_step_s))
    # Samples at the end of each step, the whole cycles ending exactly at rest on the lifted pose.
    times = np.arange(1, steps_per_window + 1) * (shake.cycles / shake.frequency_hz / steps_per_window)
    offsets = np.zeros((steps_per_window * len(windows), 6))
    velocities = np.zeros_like(offsets)
    segments = []
    for index, window in enumerate(windows):
        start = index * steps_per_window
        for axis in window:
            amplitude = peaks[axis] / omega**2
            offsets[start : start + steps_per_window, axis] = amplitude * (1.0 - np.cos(omega * times))
            velocities[start : start + steps_per_window, axis] = amplitude * omega * np.sin(omega * times)
            segments.append((axis, start, start + steps_per_window))
    return ShakeProfile(offsets=offsets, velocities=velocities, segments=tuple(segments), angular_frequency=omega, time_step_s=time_step_s)


def frame_offsets(start: tuple[Any, Any], poses: Sequence[tuple[Any, Any]]) -> np.ndarray:
    """(T, 6) displacement and rotation vector of each pose from ``start``, in ``start``'s frame:
    the coordinates ``ShakeProfile.offsets`` are written in."""
    start_rotation = Rotation.from_quat(start[1])
    positions = np.array([pose[0] for pose in poses]).reshape(-1, 3)
    rotations = Rotation.from_quat(np.array([pose[1] for pose in poses]).reshape(-1, 4))
    linear = start_rotation.inv().apply(positions - np.asarray(start[0]))
    angular = (start_rotation.inv() * rotations).as_rotvec().reshape(-1, 3)
    return np.concatenate([linear.reshape(-1, 3), angular], axis=1)


def achieved_shake_peaks(profile: ShakeProfile, measured_offsets: np.ndarray) -> tuple[float, ...]:
    """Peak acceleration (m/s^2, then rad/s^2) the hand reached along and about each axis, 0 where
    not shaken: per segment, the measured offset is fitted by ``c0 + c1 cos wt + c2 sin wt`` and
    the peak is ``w^2 |(c1, c2)|``, which ignores the controller's phase lag and the jitter a
    finite difference of contacts would add."""
    peaks = [0.0] * 6
    for axis, start, end in profile.segments:
        times = np.arange(1, end - start + 1) * profile.time_step_s
        omega = profile.angular_frequency
        basis = np.stack([np.ones_like(times), np.cos(omega * times), np.sin(omega * times)], axis=1)
        coefficients = np.linalg.lstsq(basis, measured_offsets[start:end, axis], rcond=None)[0]
        peaks[axis] = float(omega**2 * np.hypot(coefficients[1], coefficients[2]))
    return tuple(peaks)
