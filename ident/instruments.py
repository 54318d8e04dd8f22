"""Instruments for the ``iv`` estimator: the rows of (22) evaluated on a trajectory the model simulates
from the measured torque (instrumental-variable identification, Janot, Vandanjon & Gautier 2014).

Per identification step, the excited generalized coordinate s (α_l, α_r, x_ch or γ_ch) is simulated by
the reduced model (19) with parameters p, driven by the step's measured generalized torque τ (the
filtered torque actual through H_kᵀB):

    M s̈ = τ − b(ṡ),   M = H_kᵀΘ(q, 0, H_k·1)p,   b(ṡ) = H_kᵀΘ(q, H_k ṡ, Ḣ_k ṡ)p,

with the mode's other coordinates held at rest, as the campaign holds them. The identification steps
run in fixed configurations (mode 1 at rest, mode 2 with α_v = 0, mode 4), so M and b do not depend on
where the step is; b is tabulated over ṡ at the step's median configuration. The tanh Coulomb term
makes the equation stiff near ṡ = 0 (∂b/∂ṡ = d_c/ε); it is integrated by the linearly implicit
Euler method at T_s, which is L-stable. The simulated ṡ, s̈ then go through the same row builder as
the measurement (:func:`.regressor_rows.step_blocks`): the instruments carry the model's response to
the torque but none of the measurement noise in the positions that Θ̂₁ carries.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from qomni.datasheet import DataSheet

from . import dynamics, kinematics
from .campaign import IDENTIFICATION_STEPS
from .recording import Signals
from .regressor import RegressorBlock
from .regressor_rows import EXCITED, MODE_COORDINATES, StepSignals, generalized_signals, model_alpha, step_blocks
from .rundir import step_signals

#: Velocity table of b(ṡ): points over the step's range, and as many more within ±DENSE·ε around 0,
#: where tanh(ṡ/ε) turns.
TABLE_POINTS = 2001
#: The table spans this multiple of the step's largest measured |ṡ|.
V_MAX_FACTOR = 2.0
DENSE = 20.0


class InstrumentError(ValueError):
    """The model cannot simulate a step for instruments (e.g. an estimate with a non-positive mass)."""


def _rows(st: StepSignals, q: np.ndarray, sd: np.ndarray, sdd: np.ndarray, sheet: DataSheet) -> np.ndarray:
    """H_kᵀΘ(q, H_k ṡ, Ḣ_k ṡ + H_k s̈) of the mode's coordinates, (N, n_k, 11)."""
    qd, qdd = dynamics.generalized_state(st.k, q, sd, sdd, sheet.geometry)
    return dynamics.reduced_regressor(st.k, q, qd, qdd, sheet.geometry)


def simulate_step(st: StepSignals, coordinate: str, tau: np.ndarray, p: np.ndarray, sheet: DataSheet,
                  v_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Simulated (ṡ, s̈), each (N,), of ``coordinate`` driven by its generalized torque ``tau`` (N,).

    Args: st: the step's measured generalized signals (configuration, cycle time); p: (11,) parameters;
        v_max: the table's velocity range ±v_max (the simulation is held within it).
    Raises: InstrumentError when the model's mass M of the coordinate is not positive."""
    j = MODE_COORDINATES[st.k].index(coordinate)
    nk = kinematics.N_GENERALIZED[st.k]
    q = np.median(st.q, axis=0)[None, :]
    q[:, 3:5] = np.median(model_alpha(st, sheet.geometry), axis=0)
    unit = np.zeros((1, nk))
    unit[0, j] = 1.0
    mass = float(_rows(st, q, np.zeros((1, nk)), unit, sheet)[0, j] @ p)
    if not mass > 0:
        raise InstrumentError(f"{st.step}/{coordinate}: the model's mass {mass:.4g} is not positive; "
                         f"no simulation for instruments")
    eps = dynamics.EPS
    vmax = max(v_max, DENSE * eps)
    grid = np.unique(np.concatenate([np.linspace(-vmax, vmax, TABLE_POINTS),
                                     np.linspace(-DENSE * eps, DENSE * eps, TABLE_POINTS)]))
    sd = np.zeros((grid.size, nk))
    sd[:, j] = grid
    bias = _rows(st, np.repeat(q, grid.size, axis=0), sd, np.zeros_like(sd), sheet)[:, j, :] @ p
    slope = np.gradient(bias, grid)
    h = st.cycle_time
    v = np.zeros(len(tau))
    for n in range(len(tau) - 1):
        u = 0.5 * (tau[n] + tau[n + 1])
        f = (u - np.interp(v[n], grid, bias)) / mass
        dfdv = -np.interp(v[n], grid, slope) / mass
        v[n + 1] = np.clip(v[n] + h * f / (1.0 - h * dfdv), -vmax, vmax)
    a = (tau - np.interp(v, grid, bias)) / mass
    return v, a


def simulated_instruments(signals: Signals, sheet: DataSheet, p: np.ndarray) -> list[RegressorBlock]:
    """Rows of the identification steps on the model-simulated trajectories, aligned one to one with
    :func:`.regressor_rows.identification_blocks` (same channels, rows and velocities).

    Args: signals: the (torque-corrected) recording; sheet: the data sheet; p: (11,) parameters (18).
    Raises: RunDirectoryError (a step missing), InstrumentError (a non-positive model mass)."""
    p = np.asarray(p, dtype=float)
    blocks = []
    for step in IDENTIFICATION_STEPS:
        st = generalized_signals(step_signals(signals, step), sheet)
        for measured in step_blocks(st, sheet, EXCITED[step]):
            coordinate = str(measured.channel[0]).partition("/")[2]
            v, a = simulate_step(st, coordinate, measured.tau, p, sheet,
                                 V_MAX_FACTOR * float(np.max(np.abs(measured.velocity))))
            j = MODE_COORDINATES[st.k].index(coordinate)
            sd = np.zeros((len(v), kinematics.N_GENERALIZED[st.k]))
            sdd = np.zeros_like(sd)
            sd[:, j], sdd[:, j] = v, a
            q = st.q.copy()
            q[:, 3:5] = model_alpha(st, sheet.geometry)
            qd, qdd = dynamics.generalized_state(st.k, q, sd, sdd, sheet.geometry)
            sim = replace(st, qd=qd, qdd=qdd, qd_coulomb=qd)
            (block,) = step_blocks(sim, sheet, (coordinate,))
            blocks.append(RegressorBlock(block.Theta, measured.tau, measured.velocity, measured.channel))
    return blocks
