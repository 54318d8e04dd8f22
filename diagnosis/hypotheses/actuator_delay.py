"""Actuator delay: H_kᵀB(u(t) − u(t − T_d)), the applied torque lagging the reported one, T_d profiled."""
from __future__ import annotations

import math

import numpy as np

from ..channels import ChannelData
from .base import Hypothesis, Magnitude, _ci, _input_torque, _project, _torque_only


DELAY_STEPS = tuple(range(1, 13))  # cycles of T_s


@_torque_only
def _delay_columns(ch: ChannelData, cycles):
    Bu = _input_torque(ch)
    delayed = np.vstack([np.repeat(Bu[:1], cycles, axis=0), Bu[:-cycles]])
    return _project(ch, Bu - delayed)[:, None]


def _delay_magnitude(theta, cov, cycles, sheet):
    # u(t) − u(t − T) ≈ T·u̇: gain·T is the delay to first order, whatever grid point fits best.
    T = cycles * sheet.drive.cycle_time
    g, s = float(theta[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
    return Magnitude(g * T, _ci(g, s, T), "s", "delay commanded → applied torque")


ACTUATOR_DELAY = Hypothesis("actuator_delay", "", ("gain",), _delay_columns, DELAY_STEPS,
                            magnitude=_delay_magnitude, physical=lambda t: 0.3 < t[0] < 3.0,
                            nonlinear_unit="cycles")

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (ACTUATOR_DELAY,)
