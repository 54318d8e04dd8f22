"""Actuator delay: H_kᵀB(u(t) − u(t − T_d)), the applied torque lagging the reported one, T_d profiled."""
from __future__ import annotations

import math

import numpy as np

from ..channels import ChannelData
from .base import (LIFTED_MODELLED, Hypothesis, Magnitude, _delayed, _input_torque, _project, _torque_only,
                   interval_95)


DELAY_STEPS = tuple(range(1, 13))  # cycles of T_s
#: The shift's gain range a delay or a report lag is physical in; the shift named is gain × step.
SHIFT_GAIN_RANGE = (0.3, 3.0)


def shift_columns(direction: int):
    """Columns H_kᵀB(u(t) − u(t − direction·T)) for T = ``cycles`` SYNC periods: ``direction`` +1 the
    applied torque lags the reported one (a delay), −1 it leads it (the report lags)."""
    @_torque_only
    def columns(ch: ChannelData, cycles):
        Bu = _input_torque(ch)
        if direction > 0:
            shifted = _delayed(Bu, cycles)
        else:
            shifted = np.vstack([Bu[cycles:], np.repeat(Bu[-1:], cycles, axis=0)])
        return _project(ch, Bu - shifted)[:, None]
    return columns


def shift_magnitude(quantity: str):
    """gain·T, the shift to first order (u(t) − u(t ∓ T) ≈ ±T·u̇), whatever grid point fits best."""
    def magnitude(theta, cov, cycles, sheet):
        T = cycles * sheet.drive.cycle_time
        g, s = float(theta[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
        return Magnitude(g * T, interval_95(g, s, T), "s", quantity)
    return magnitude


ACTUATOR_DELAY = Hypothesis("actuator_delay", "", ("gain",), shift_columns(+1), DELAY_STEPS,
                            magnitude=shift_magnitude("delay commanded → applied torque"),
                            physical=lambda t: SHIFT_GAIN_RANGE[0] < t[0] < SHIFT_GAIN_RANGE[1],
                            nonlinear_unit="cycles", lifted=LIFTED_MODELLED)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (ACTUATOR_DELAY,)
