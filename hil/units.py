"""Conversions between CANopen device units and SI (docs/conventions.md, "CANopen mapping (hil)").

Pure numpy functions shared by the master (client) and anything that checks it; no CAN, no emulator.
Torques are motor side. Sources: CiA 402 §6 (0x6071/0x6077 per mille of 0x6076, 0x6064 increments,
0x606C increments/s), CiA 406 (0x6004 position value).
"""
from __future__ import annotations

import numpy as np

from qomni.vehicle_interface import Measurement

INT16_MIN, INT16_MAX = -(2**15), 2**15 - 1
_TWO_PI = 2.0 * np.pi


def torque_to_per_mille(motor_torque, rated_torque, limit=INT16_MAX) -> np.ndarray:
    """Motor torque [N m] → target torque 0x6071 [per mille of rated torque], rounded and clipped.

    Args:
        motor_torque: array-like, N m motor side.
        rated_torque: array-like broadcastable to ``motor_torque``, N m (0x6076 / 1000).
        limit: array-like, per mille, symmetric clip (0x6072 max torque); never beyond INTEGER16.
    Returns:
        int64 array, same shape as ``motor_torque``.
    Raises:
        ValueError: if a torque is not finite.
    """
    tau = np.asarray(motor_torque, dtype=float)
    if not np.all(np.isfinite(tau)):
        raise ValueError(f"motor torque must be finite, got {tau}")
    lim = np.minimum(np.asarray(limit, dtype=float), INT16_MAX)
    return np.clip(np.rint(tau * 1000.0 / np.asarray(rated_torque, dtype=float)), -lim, lim).astype(np.int64)


def per_mille_to_torque(per_mille, rated_torque) -> np.ndarray:
    """Torque 0x6071/0x6077 [per mille of rated] → N m motor side (float array)."""
    return np.asarray(per_mille, dtype=float) * (np.asarray(rated_torque, dtype=float) / 1000.0)


def increments_to_rad(increments, encoder_increments: int) -> np.ndarray:
    """Motor encoder increments (or increments/s) → rad (or rad/s) on the motor shaft."""
    return np.asarray(increments, dtype=float) * (_TWO_PI / encoder_increments)


def unwrap32(raw, previous_raw, previous_total) -> np.ndarray:
    """Extend a wrapping 32-bit counter (0x6064) to int64.

    Args:
        raw: int array, new INTEGER32 readings.
        previous_raw: int array, the readings before (same shape).
        previous_total: int64 array, the unwrapped value belonging to ``previous_raw``.
    Returns:
        int64 array: ``previous_total + d`` with ``d`` the signed 32-bit difference raw − previous_raw.
    """
    d = (np.asarray(raw, dtype=np.int64) - np.asarray(previous_raw, dtype=np.int64) + 2**31) % 2**32 - 2**31
    return np.asarray(previous_total, dtype=np.int64) + d


def counts_to_alpha(counts, bits: int) -> np.ndarray:
    """Steering sensor counts (0x6004) → angle α in (−π, π] rad; inverse of :func:`alpha_to_counts`."""
    full = 1 << bits
    c = np.asarray(counts, dtype=np.int64) % full
    c = np.where(c > full // 2, c - full, c)
    return c * (_TWO_PI / full)


def alpha_to_counts(alpha, bits: int) -> np.ndarray:
    """Angle α [rad] → steering sensor counts ``round(α/2π·2**bits) mod 2**bits`` (int64)."""
    full = 1 << bits
    return np.rint(np.asarray(alpha, dtype=float) / _TWO_PI * full).astype(np.int64) % full


def device_measurement(time: float, position_total, velocity, torque, counts, *, encoder_increments: int,
                       rated_torque, steering_sensor_bits: int) -> Measurement:
    """One SYNC's sample in SI from the device units of the TPDOs: the master's one conversion, used by
    the client on the bus and by the decoder of logs alike.

    Args:
        time: s. position_total: (4,) int64 motor increments, unwrapped (:func:`unwrap32`).
        velocity: (4,) increments/s (0x606C). torque: (4,) per mille of ``rated_torque`` (0x6077).
        counts: (2,) steering sensor measuring units (0x6004 of nodes 5, 6).
        encoder_increments: per motor revolution. rated_torque: (4,) or scalar, N m motor side (0x6076).
        steering_sensor_bits: resolution of the steering sensors.
    """
    return Measurement(time=time,
                       motor_position=increments_to_rad(position_total, encoder_increments),
                       motor_velocity=increments_to_rad(velocity, encoder_increments),
                       motor_torque=per_mille_to_torque(torque, rated_torque),
                       alpha=counts_to_alpha(counts, steering_sensor_bits))
