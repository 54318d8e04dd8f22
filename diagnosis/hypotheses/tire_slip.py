"""Tyre slip: lateral slip of a rigid chassis whose side forces need slip angles F/C_α."""
from __future__ import annotations

import numpy as np

from ..channels import ChannelData
from .base import Hypothesis, _linear_magnitude, _rolling, _rolling_only, _tyre_torque


#: m/s: rolling speed below which a wheel's slip velocity is taken at this floor (a tyre's relaxation
#: length makes the side force lag at standstill instead of growing without bound).
SLIP_SPEED_FLOOR = 0.02


@_rolling_only
def _slip_columns(ch: ChannelData, _):
    ctx = ch.context
    st, g, p = ctx.st, ctx.sheet.geometry, ctx.p
    A = ctx.rolling.A
    beta_d = st.qd[:, 5:9]
    # Longitudinal tyre forces from the drives and their generalized chassis force; what the chassis'
    # inertia needs beyond it the side forces must supply.
    f_long = _tyre_torque(ctx) / g.r
    drive = np.einsum("nij,ni->nj", A[:, 4:8, :3], f_long)
    v, acc = st.qd[:, :3], st.qdd[:, :3]
    inertia = np.column_stack([p[6] * (acc[:, 0] - v[:, 2] * v[:, 1]), p[6] * (acc[:, 1] + v[:, 2] * v[:, 0]),
                               p[7] * acc[:, 2]])
    required = inertia - drive
    # Side force F_i = −C_α s_i/|v_i| through the lateral slip velocity s_i of a rigid chassis,
    # s = E_latᵀδ: the slip twist δ solves E_lat D⁻¹ E_latᵀ δ = −C_α⁻¹·required (D = diag|v_i|).
    # At the mode's nominal angles: there the side forces of mode 4 (radial) have no moment, and pinv
    # leaves the yaw share of ``required`` (the torque channel's business) out instead of amplifying it.
    E = np.broadcast_to(ctx.rolling.A_ch_nominal[0:4].T, (len(st.time), 3, 4))
    d_inv = 1.0 / np.maximum(g.r * np.abs(beta_d), SLIP_SPEED_FLOOR)
    K = np.einsum("nik,nk,njk->nij", E, d_inv, E)
    delta = np.einsum("nij,nj->ni", np.linalg.pinv(K, rcond=1e-6), required)
    violation = np.zeros((len(st.time), 8))
    violation[:, :4] = -np.einsum("nik,ni->nk", E, delta)  # per unit 1/C_α
    return _rolling(ch, violation)[:, None]


#: 1/C_α below 2e-5 rad/N (C_α above 50 kN/rad, 1 mrad of slip angle per 50 N; stiffer than the
#: stiffest tyre of this class, 30 kN/rad) is rigid contact for the platform's speeds. The ideal emulator's
#: contact fits ~4e-6 rad/N; an 8 ms actuator delay's torque ripple makes the wheels creep like 1.1e-5.
TIRE_SLIP = Hypothesis("tire_slip", "", ("inverse_cornering_stiffness",), _slip_columns,
                       magnitude=_linear_magnitude(0, "rad/N", "1/C_α per wheel"),
                       physical=lambda t: t[0] > 0, relevant=2e-5)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (TIRE_SLIP,)
