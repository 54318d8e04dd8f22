"""Sensors of the emulated vehicle at data-sheet resolution: motor encoders, steering-angle sensors and
the drives' torque measurement. Raw device units, exactly what the drives and encoders put on the bus."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SensorReading:
    """One sample of every sensor, taken at ``time``.

    Attributes:
        time: s since the emulator started.
        motor_position: (4,) int64, motor encoder increments, multi-turn, order fl, rl, fr, rr.
        motor_velocity: (4,) int64, increments/s, the drive's estimate (position difference over the
            last 2 ms).
        motor_torque: (4,) float, N m on the motor side: applied torque as the drive measures it.
        steering_position: (2,) int64, steering sensor counts in [0, 2**bits), left then right
            (``counts = round(α/2π·2**bits) mod 2**bits``).
    """

    time: float
    motor_position: np.ndarray
    motor_velocity: np.ndarray
    motor_torque: np.ndarray
    steering_position: np.ndarray
