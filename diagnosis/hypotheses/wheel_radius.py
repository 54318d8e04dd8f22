"""Wheel radius: the effective radius differs from the data sheet's; odometry's scale in the torque rows."""
from __future__ import annotations

import math

from qomni.conventions import SIDE_INDEX

from ..channels import ChannelData
from .base import Z_95, Hypothesis, Magnitude


def _radius_columns(ch: ChannelData, _):
    if ch.kind == "rolling":
        return None  # one radius error scales every wheel's rolling alike: a rigid twist, not redundant
    if ch.kind == "torque":
        # ε = r_nominal/r − 1. The encoders and the steering sensor measure the joint angles exactly;
        # the chassis motion odometry takes from the wheels with r_nominal is (1 + ε) times the true
        # one. Written in the measured coordinates, the true rows of (19) keep every wheel-joint term
        # (input, d_vw, d_cw, B_w) and read the steering joints' (C, d_v, d_c of both sides) through a
        # lever 1/(1 + ε) and the chassis inertia (m_ch, C_ch) through 1/(1 + ε)²: the residual is
        # −ε·(steering-joint terms) − 2ε·(chassis terms) to first order. (A lever 1 + ε on the input,
        # the column before, also scales the wheels' friction; a 4 % smaller wheel left 18 N of a
        # 39 N residual in straight driving under it, 1.2 N against a 1.3 N floor under this one.)
        terms = ch.base * ch.context.p[:10]
        return (-terms[:, :6].sum(axis=1) - 2.0 * terms[:, 6:8].sum(axis=1))[:, None]
    st, side = ch.context.st, SIDE_INDEX[ch.index]
    H1 = ch.context.H[:, 5 + ch.index, side]
    return ch.rows(H1 * (st.q[:, 3 + side] - st.q[0, 3 + side]))[:, None]


def _radius_magnitude(theta, cov, nonlinear, sheet):
    v, s = float(theta[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
    r = sheet.geometry.r
    return Magnitude(r / (1 + v), (r / (1 + v + Z_95 * s), r / (1 + v - Z_95 * s)), "m",
                     "effective wheel radius")


#: 0.25 % of r (0.25 mm on the prototype): the soft contact alone flattens a wheel by about as much, and
#: two runs of the same vehicle differ by ~0.03 %; a real radius error of worn or other tyres is 1–5 %.
WHEEL_RADIUS = Hypothesis("wheel_radius", "", ("r_ratio_minus_one",), _radius_columns,
                          magnitude=_radius_magnitude, relevant=0.0025)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (WHEEL_RADIUS,)
