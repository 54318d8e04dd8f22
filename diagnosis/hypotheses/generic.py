"""A black-box extension of one channel, to tell "unexplained structure remains" from noise."""
from __future__ import annotations

import numpy as np

from qomni.conventions import EPSILON as EPS_SIGN, SIDE_INDEX

from ..channels import ChannelData
from .backlash import BACKLASH_TORQUE_SCALE
from .base import Hypothesis, Magnitude, _delayed


def generic(channel: str) -> Hypothesis:
    """A black-box extension of one channel — residual on its own velocity, acceleration, friction sign,
    input delayed by 10 and 30 ms, (kinematic) the steering excursion and drive torque, (rolling) integrals
    of the speed and input — used to
    tell "unexplained structure remains" from noise when no named hypothesis is significant."""

    def columns(ch: ChannelData, _):
        if ch.name != channel:
            return None
        v, acc = ch.velocity, ch.acceleration
        if ch.kind == "torque":
            y = ch.y
            lagged = [_delayed(y, n) - y for n in (5, 15)]
            return np.column_stack([v, acc, np.tanh(v / EPS_SIGN), v * np.abs(v), *lagged])
        if ch.kind == "rolling":
            # positions: the integrals of the speed's odd and even powers and the generalized input
            ts = ch.context.st.cycle_time
            u = ch.rows(ch.context.st.motor_torque.sum(axis=1))
            return np.cumsum(np.column_stack([v, np.abs(v), v * v * v, u]), axis=0) * ts
        u = ch.rows(ch.context.st.motor_torque[:, ch.index])
        alpha = ch.rows(ch.context.st.q[:, 3 + SIDE_INDEX[ch.index]])
        return np.column_stack([alpha - alpha[0], u, np.tanh(u / BACKLASH_TORQUE_SCALE), v])

    names = (("c_alpha", "c_u", "c_sign_u", "c_v") if "/kinematic_" in channel
             else ("c_v", "c_abs_v", "c_v3", "c_u") if "/rolling_" in channel
             else ("c_v", "c_a", "c_sign", "c_v2", "c_u5", "c_u15"))
    return Hypothesis("unexplained", channel, names, columns, magnitude=lambda theta, cov, nl, sheet: Magnitude(
                          float(np.linalg.norm(theta)), (0.0, 0.0), "-", "black-box coefficients"))
