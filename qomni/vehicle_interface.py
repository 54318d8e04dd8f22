"""The vehicle interface: what a master gets from the vehicle each cycle (:class:`Measurement`, SI units)
and what every vehicle offers (:class:`VehicleInterface`).

The seam between the campaign and whatever vehicle it drives: the CAN client
(:class:`qomni.hil.master.client.VehicleClient`), the plant FMU's adapter (:class:`qomni.fmu.cosim.PlantVehicle`)
or any in-process adapter satisfy :class:`VehicleInterface`, so the identification campaign runs unchanged
against each. A leaf module (numpy only). Frames, orders and units: docs/conventions.md.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class Measurement:
    """One synchronous sample of every sensor, taken at the SYNC instant.

    Attributes:
        time: s, cycle number × T_s (the first exchange after connecting is at 0).
        motor_position: (4,) float, rad on the motor shaft, order fl, rl, fr, rr, unwrapped (continuous
            across the 32-bit counter wrap of 0x6064).
        motor_velocity: (4,) float, rad/s on the motor shaft (0x606C).
        motor_torque: (4,) float, N m motor side, the torque applied from this instant (0x6077).
        alpha: (2,) float, steering angles α_l, α_r in (−π, π] rad (0x6004 of nodes 5, 6).
    """

    time: float
    motor_position: np.ndarray
    motor_velocity: np.ndarray
    motor_torque: np.ndarray
    alpha: np.ndarray


@runtime_checkable
class VehicleInterface(Protocol):
    """A vehicle (real or emulated) driven in lock-step by its master.

    ``exchange`` sends one set of motor torques (N m motor side, (4,), order fl, rl, fr, rr), triggers one
    cycle of length ``cycle_time`` and returns the sample taken at the start of that cycle.
    ``stop`` makes the vehicle safe (no torque) and is always safe to call.
    """

    cycle_time: float

    def exchange(self, motor_torque: np.ndarray) -> Measurement: ...

    def stop(self) -> None: ...
