"""Torque report lag: H_kᵀB(u(t) − u(t + T_r)), the drives' reported torque (0x6077) lagging the torque
they apply by T_r (a drive that samples its torque actual at the SYNC reports the set-point a cycle
late); T_r profiled. The mirror image of an actuator delay: the residual leads the reported input."""
from __future__ import annotations

from .actuator_delay import SHIFT_GAIN_RANGE, shift_columns, shift_magnitude
from .base import LIFTED_MODELLED, Hypothesis

LAG_STEPS = tuple(range(1, 7))  # cycles of T_s
#: The shortest lag the hypothesis names, in cycles of T_s.
SHORTEST_CYCLES = SHIFT_GAIN_RANGE[0] * LAG_STEPS[0]

TORQUE_REPORT_LAG = Hypothesis("torque_report_lag", "", ("gain",), shift_columns(-1), LAG_STEPS,
                               magnitude=shift_magnitude("lag of the reported torque (0x6077) behind the applied"),
                               physical=lambda t: SHIFT_GAIN_RANGE[0] < t[0] < SHIFT_GAIN_RANGE[1],
                               nonlinear_unit="cycles", lifted=LIFTED_MODELLED)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (TORQUE_REPORT_LAG,)
