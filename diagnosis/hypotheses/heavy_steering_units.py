"""Heavy steering units: exact point masses at the wheel centres beyond the lumped model."""
from __future__ import annotations

import numpy as np

from qomni.conventions import FRONT_SIGN, SIDE_INDEX, SIDE_SIGN
from qomni.ident.regressor_rows import model_alpha

from ..channels import ChannelData
from .base import Hypothesis, _linear_magnitude, _project, _torque_only


@_torque_only
def _heavy_columns(ch: ChannelData, _):
    ctx = ch.context
    st, g = ctx.st, ctx.sheet.geometry
    n = len(st.time)
    v, acc = st.qd[:, :3], st.qdd[:, :3]
    w, wd = v[:, 2], acc[:, 2]
    alpha, alpha_d, alpha_dd = model_alpha(st, g), st.qd[:, 3:5], st.qdd[:, 3:5]
    if ctx.k in (3, 4):
        alpha_d = alpha_dd = np.zeros_like(alpha)
    Q = np.zeros((n, 9))
    lumped = np.zeros((n, 9))
    for i in range(4):
        s, sigma, side = SIDE_SIGN[i], FRONT_SIGN[i], SIDE_INDEX[i]
        P = np.array([sigma * g.l / 2, s * g.b / 2])
        phi, phid, phidd = sigma * alpha[:, side], sigma * alpha_d[:, side], sigma * alpha_dd[:, side]
        e = np.column_stack([-np.sin(phi), np.cos(phi)])
        de = np.column_stack([-np.cos(phi), -np.sin(phi)])  # d e / d phi
        c = P + s * g.a * e
        cd = s * g.a * de * phid[:, None]
        cdd = s * g.a * (de * phidd[:, None] - e * (phid**2)[:, None])
        # Inertial acceleration of the wheel centre, chassis-frame components.
        A = (acc[:, :2] + np.column_stack([-w * v[:, 1], w * v[:, 0]])
             + np.column_stack([-wd * c[:, 1], wd * c[:, 0]]) - (w**2)[:, None] * c
             + 2 * np.column_stack([-w * cd[:, 1], w * cd[:, 0]]) + cdd)
        Q[:, 0] += A[:, 0]
        Q[:, 1] += A[:, 1]
        Q[:, 2] += -c[:, 1] * A[:, 0] + c[:, 0] * A[:, 1]
        Q[:, 3 + side] += sigma * s * g.a * np.einsum("nj,nj->n", de, A)
        # What the lumped model already holds for this mass: m_ch, C_ch + C_side at α = 0, C_side.
        c0 = P + s * g.a * np.array([0.0, 1.0])
        lumped[:, 0] += acc[:, 0] - w * v[:, 1]
        lumped[:, 1] += acc[:, 1] + w * v[:, 0]
        lumped[:, 2] += float(c0 @ c0) * wd
        lumped[:, 3 + side] += g.a**2 * alpha_dd[:, side]
    return _project(ch, Q - lumped)[:, None]


HEAVY_STEERING_UNITS = Hypothesis(
    "heavy_steering_units", "", ("wheel_mass",), _heavy_columns,
    magnitude=_linear_magnitude(0, "kg", "mass per steering unit at the wheel centre"),
    physical=lambda t: t[0] > 0)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (HEAVY_STEERING_UNITS,)
