"""The plant contract of the CANopen server: what :class:`qomni.hil.device.server.VehicleServer` needs from the
physics it puts on the bus.

The emulator (:class:`qomni.emulator.vehicle.Emulator`) satisfies :class:`Plant`, and so does any test
double; ``hil`` never imports the emulator. Units: motor side, SI except where the device units of
CiA 402/406 are named (increments, measuring units).
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


class DriveData(Protocol):
    """The drive data of the data sheet (:class:`qomni.datasheet.Drive`)."""

    i_G: float                      # gear ratio, wheel torque = i_G · motor torque
    rated_torque: float             # N m motor side (0x6076)
    max_torque: float               # N m motor side (0x6072)
    encoder_increments: int         # motor encoder increments per motor revolution
    steering_sensor_bits: int       # absolute single-turn steering sensor resolution
    cycle_time: float               # s, SYNC period T_s


class PlantDescription(Protocol):
    drive: DriveData


class SensorReading(Protocol):
    """One sample of the plant's sensors, taken at the SYNC instant."""

    time: float                     # s
    motor_position: np.ndarray      # (4,) motor encoder increments, fl rl fr rr
    motor_velocity: np.ndarray      # (4,) increments/s
    motor_torque: np.ndarray        # (4,) N m motor side, the torque applied from this instant (0x6077)
    steering_position: np.ndarray   # (2,) steering sensor measuring units, left then right


@runtime_checkable
class Plant(Protocol):
    """The physics behind the drives and encoders, stepped in lock-step with the SYNC.

    A plant whose ``step`` returns before the physics is done (it has ``steps_in_background = True``,
    :class:`qomni.hil.device.plant_process.PlantProcess`) is told to step right after the sample, before
    the TPDOs; any other plant after them.
    """

    description: PlantDescription

    def set_motor_torques(self, motor_torque: np.ndarray) -> None:
        """Apply (4,) motor torques, N m motor side, order fl, rl, fr, rr, until the next call."""

    def step(self, duration: float) -> None:
        """Advance the physics by ``duration`` seconds."""

    def read_sensors(self) -> SensorReading:
        """Sample every sensor now."""
