"""Torque report lag: H_kᵀB(u(t) − u(t + T_r)), the drives' reported torque (0x6077) lagging the torque
they apply by T_r (a drive that samples its torque actual at the SYNC reports the set-point a cycle
late); T_r profiled. The mirror image of an actuator delay: the residual leads the reported input."""
from __future__ import annotations

import math

import numpy as np

from ..channels import ChannelData
from .base import Hypothesis, Magnitude, _ci, _input_torque, _project, _torque_only

LAG_STEPS = tuple(range(1, 7))  # cycles of T_s


@_torque_only
def _lag_columns(ch: ChannelData, cycles):
    Bu = _input_torque(ch)
    ahead = np.vstack([Bu[cycles:], np.repeat(Bu[-1:], cycles, axis=0)])
    return _project(ch, Bu - ahead)[:, None]


def _lag_magnitude(theta, cov, cycles, sheet):
    # u(t) − u(t + T) ≈ −T·u̇: gain·T is the report's lag to first order.
    T = cycles * sheet.drive.cycle_time
    g, s = float(theta[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
    return Magnitude(g * T, _ci(g, s, T), "s", "lag of the reported torque (0x6077) behind the applied")


TORQUE_REPORT_LAG = Hypothesis("torque_report_lag", "", ("gain",), _lag_columns, LAG_STEPS,
                               magnitude=_lag_magnitude, physical=lambda t: 0.3 < t[0] < 3.0,
                               nonlinear_unit="cycles")

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (TORQUE_REPORT_LAG,)
