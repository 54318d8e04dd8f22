"""Forward simulation of a torque channel's coordinate under the model, from the measured state at the
start of each window, driven by the measured generalized input (paper (19) for one coordinate).

For the excited coordinate s of a step, with the other coordinates as measured::

    m(q) s̈ + h(q, ṡ) = τ̂ − Φ_e θ_e − Θ̂₁ δp                 m = H_jᵀ M(p) H_j,  h = H_jᵀ Y(q, H_j ṡ, 0) p

integrated with implicit Euler on the velocity (the tanh Coulomb term is stiff at ε = 0.01 rad/s) at
the recording's T_s. The effect term Φ_e θ_e is taken from the measured rows (teacher forcing), which is
exact for input effects (delay, torque constant) and first order for state-dependent ones. H̃_j's rate
terms are neglected, exact for every identification step (H constant) and small in the lane change.
"""
from __future__ import annotations

import numpy as np

from qomni.ident import dynamics

from .channels import ChannelData

WINDOW = 1.0  # s


def _h(ch: ChannelData, p: np.ndarray, row: int, sd: np.ndarray) -> np.ndarray:
    """h(q, ṡ) for one step row and several ṡ values (n,)."""
    ctx = ch.context
    Hj = ctx.H[row, :, ch.index]
    n = len(sd)
    q = np.repeat(ctx.st.q[row][None, :], n, axis=0)
    qd = sd[:, None] * Hj[None, :]
    Y = dynamics.regressor(q, qd, np.zeros_like(qd), eps=dynamics.EPS)
    return np.einsum("i,nij,j->n", Hj, Y, p)


def simulate_channel(ch: ChannelData, p: np.ndarray, correction: np.ndarray | None = None,
                     window: float = WINDOW) -> dict:
    """Windowed forward simulation of one torque channel.

    Args:
        ch: a torque channel.
        p: (11,) parameters (order (18)).
        correction: (n,) generalized torque removed from the input (Φ_e θ_e + Θ̂₁δp), or None.
    Returns:
        ``{"rms": RMS position error over all windows, "end_rms": RMS error after each full window,
        "unit": m or rad, "windows": n}``.
    Raises:
        ValueError: for a kinematic channel.
    """
    if ch.kind != "torque":
        raise ValueError(f"{ch.name} is not a torque channel")
    ctx = ch.context
    rows = np.flatnonzero(ctx.keep)
    ts = ctx.st.cycle_time
    # y is τ̂ − Θ̂₂p₂: B_w's term goes back into the input, since m holds B_w
    wheel_inertia = dynamics.regressor(ctx.st.q[rows], ctx.st.qd[rows], ctx.st.qdd[rows])[:, :, 10]
    tau = ch.y + p[10] * np.einsum("ni,ni->n", ctx.H[rows, :, ch.index], wheel_inertia)
    if correction is not None:
        tau = tau - correction
    sd_meas = ch.velocity
    s_meas = np.concatenate([[0.0], np.cumsum(0.5 * (sd_meas[1:] + sd_meas[:-1]) * ts)])
    M = np.einsum("nij,j->ni", dynamics.regressor(
        ctx.st.q[rows], np.zeros((len(rows), 9)), ctx.H[rows, :, ch.index], eps=dynamics.EPS), p)
    m = np.einsum("ni,ni->n", ctx.H[rows, :, ch.index], M)
    per_window = int(round(window / ts))
    errors, ends = [], []
    for start in range(0, len(rows) - per_window, per_window):
        if rows[start + per_window] - rows[start] != per_window:
            continue   # the window spans a break in the kept rows (the lifted channel's next wheel)
        s, sd = s_meas[start], sd_meas[start]
        err = []
        for k in range(start, start + per_window):
            row = rows[k]
            # Implicit Euler on ṡ: solve m(ṡ' − ṡ)/T + h(ṡ') = τ by Newton on a scalar.
            x = sd
            for _ in range(4):
                hv = _h(ch, p, row, np.array([x, x + 1e-4]))
                f = m[k] * (x - sd) / ts + hv[0] - tau[k]
                df = m[k] / ts + (hv[1] - hv[0]) / 1e-4
                x -= f / df
            sd = x
            s += ts * sd
            err.append(s - s_meas[k + 1])
        errors += err
        ends.append(err[-1])
    unit = "m" if ch.unit == "N" else "rad"
    if not errors:
        return {"rms": float("nan"), "end_rms": float("nan"), "unit": unit, "windows": 0}
    return {"rms": float(np.sqrt(np.mean(np.square(errors)))),
            "end_rms": float(np.sqrt(np.mean(np.square(ends)))), "unit": unit, "windows": len(ends)}
