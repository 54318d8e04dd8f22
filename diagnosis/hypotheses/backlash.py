"""Gear backlash: the motor encoder leads the wheel by half the gap in the direction of the torque."""
from __future__ import annotations

import numpy as np

from ..channels import ChannelData
from .base import Hypothesis, _linear_magnitude, _rolling


BACKLASH_TORQUE_SCALE = 0.05  # N m motor side: torque below which the gear floats in its gap


def _backlash_columns(ch: ChannelData, _):
    if ch.kind == "torque":
        return None
    st = ch.context.st
    if ch.kind == "kinematic":
        return ch.rows(0.5 * np.tanh(st.motor_torque[:, ch.index] / BACKLASH_TORQUE_SCALE))[:, None]
    # The encoder reads the motor, half the gap ahead of the wheel in the direction of the torque: the
    # longitudinal rows (−r β̇) see the rate of that lead.
    lead = 0.5 * np.tanh(st.motor_torque / BACKLASH_TORQUE_SCALE)
    violation = np.zeros((len(st.time), 8))
    violation[:, 4:] = -ch.context.sheet.geometry.r * np.gradient(lead, st.cycle_time, axis=0)
    return _rolling(ch, violation)[:, None]


#: 0.3 mrad (1 arcmin) at the gear output: what precision gearboxes are specified at; less is no backlash
#: of practical consequence (standard planetary gears have 3–6 mrad).
BACKLASH = Hypothesis("backlash", "", ("gap",), _backlash_columns,
                      magnitude=_linear_magnitude(0, "rad", "gear backlash (wheel side)"),
                      physical=lambda t: t[0] > 0, relevant=3e-4)


#: Tyre/floor friction coefficient the scrub of a toed wheel is taken at (dry rubber on concrete, the

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (BACKLASH,)
