"""Stribeck friction: a breakaway peak d_c·exp(−(v/v_s)²) in the wheel or the steering joints, v_s profiled."""
from __future__ import annotations

import numpy as np

from qomni.conventions import EPSILON as EPS_SIGN

from ..channels import ChannelData
from .base import Hypothesis, _linear_magnitude, _project, _torque_only


#: rad/s, joint side: below this speed a joint is taken as sticking. Its friction then holds against the
#: motion that breaks it loose, so its direction is that motion's, which tanh(v/ε) of the filtered speed
#: (≈ 0 there) does not give: the stick-slip transients at every reversal are where a friction peak
#: shows most, and the filter spreads them into the moving rows next to the stuck ones.
STICK_VELOCITY = 0.01


def _friction_direction(v: np.ndarray) -> np.ndarray:
    """(N, m) direction friction acts in, within ±1: tanh(v/ε) where a joint slides, and where it sticks
    the sign of the motion that ends the stick (the motion before it if none follows)."""
    v = np.asarray(v, dtype=float)
    out = np.tanh(v / EPS_SIGN)
    rows = np.arange(len(v))
    for j in range(v.shape[1]):
        sliding = np.abs(v[:, j]) > STICK_VELOCITY
        if not sliding.any():
            continue
        slide_rows = rows[sliding]
        # the first sliding row after each stuck one, or the last sliding row when none follows
        after = np.minimum(np.searchsorted(slide_rows, rows[~sliding]), len(slide_rows) - 1)
        out[~sliding, j] = np.sign(v[slide_rows[after], j])
    return out


def _stribeck(v, v_s):
    return np.exp(-(v / v_s) ** 2) * _friction_direction(v)


STRIBECK_VELOCITIES = (0.02, 0.05, 0.1, 0.2, 0.4)  # rad/s, joint side


@_torque_only
def _stribeck_wheel_columns(ch: ChannelData, v_s):
    st = ch.context.st
    Q = np.zeros((len(st.time), 9))
    Q[:, 5:9] = ch.context.p[9] * _stribeck(st.qd_coulomb[:, 5:9], v_s)
    return _project(ch, Q, smooth=True)[:, None]


@_torque_only
def _stribeck_steering_columns(ch: ChannelData, v_s):
    ctx = ch.context
    peak = _stribeck(ctx.alpha_dot_encoder, v_s)
    Q = np.zeros((len(ctx.st.time), 9))
    Q[:, 3] = ctx.p[2] * peak[:, 0]
    Q[:, 4] = ctx.p[5] * peak[:, 1]
    return _project(ch, Q, smooth=True)[:, None]


STRIBECK_WHEELS = Hypothesis(
    "stribeck", "joints=wheels", ("breakaway_excess",), _stribeck_wheel_columns, STRIBECK_VELOCITIES,
    magnitude=_linear_magnitude(0, "-", "breakaway/Coulomb − 1 (wheel joints)"),
    physical=lambda t: t[0] > 0, nonlinear_unit="rad/s (Stribeck velocity)")
STRIBECK_STEERING = Hypothesis(
    "stribeck", "joints=steering", ("breakaway_excess",), _stribeck_steering_columns,
    STRIBECK_VELOCITIES, magnitude=_linear_magnitude(0, "-", "breakaway/Coulomb − 1 (steering joints)"),
    physical=lambda t: t[0] > 0, nonlinear_unit="rad/s (Stribeck velocity)")
