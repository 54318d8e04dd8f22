"""The rows of (19) from a recorded step: filtered generalized signals, then H_kᵀΘ and H_kᵀBu (paper 6.3).

Per campaign step the measured signals are low-pass filtered zero-phase at ω_g = 40 rad/s, including
the first and second time derivatives; chassis velocities come from odometry (3); the rows
H_kᵀΘ(q, q̇, q̈) and H_kᵀBu of (19) are stacked into (22) and estimated with B_w fixed (24), (25).
The lane change (mode 2) is never used for fitting; it validates the result (Fig. 6).

Coulomb columns. Filtering commutes with the linear terms of (16) but not with d_c·tanh(v/ε): the
filtered torque contains LP(d_c·sign v), a ramp ≈ 1/ω_g wide at every reversal, whereas tanh(LP(v)/ε)
stays a step. The Coulomb columns are therefore built from velocities differentiated at
``COULOMB_VELOCITY_CUTOFF`` and then low-passed at ω_g like the torque ("parallel filtering" of the
non-linear columns); without this the steering d_v/d_c pair is biased by up to 10 %. A steering sensor
coarser than 14 bits differentiates into steps at that cutoff, so the steering rates take a lower one
(:func:`coulomb_steering_cutoff`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qomni.conventions import PARAMETER_NAMES, WHEELS
from qomni.datasheet import DataSheet

from . import dynamics, filtering, kinematics, odometry
from .campaign import IDENTIFICATION_STEPS, VALIDATION_STEP
from .regressor import VELOCITY_THRESHOLD, RegressorBlock  # noqa: F401 - re-exported
from .recording import Signals
from .rundir import step_signals

#: Cutoff (rad/s) of the velocities inside the Coulomb columns before they are low-passed at ω_g.
COULOMB_VELOCITY_CUTOFF = 400.0

COULOMB_COLUMNS = [PARAMETER_NAMES.index(n) for n in ("d_cl", "d_cr", "d_cw")]

#: Generalized coordinates of each mode, in the column order of H_k (10)-(13).
MODE_COORDINATES = {1: ("alpha_l", "alpha_r"), 2: ("alpha_v", "x_ch"), 3: ("y_ch",), 4: ("gamma_ch",)}


@dataclass
class StepSignals:
    """Filtered generalized signals of one step; all (N, …) arrays, SI (docs/conventions.md).

    q (N, 9) has the chassis position entries set to zero: (16) does not depend on them.
    qd_coulomb (N, 9) is q̇ differentiated at ``COULOMB_VELOCITY_CUTOFF`` for the Coulomb columns.
    """

    step: str
    k: int
    time: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    motor_torque: np.ndarray
    qd_coulomb: np.ndarray
    cycle_time: float
    omega_g: float


def model_alpha(st: StepSignals, geometry) -> np.ndarray:
    """(N, 2) steering angles the model of the step is evaluated at, rad: the measured ones in modes 1
    and 2, the mode's nominal angles in modes 3 and 4 (fixed by the mode; the sensor adds only noise)."""
    if st.k in (3, 4):
        return np.broadcast_to(kinematics.mode_alpha(st.k, geometry), st.q[:, 3:5].shape)
    return st.q[:, 3:5]


def generalized_signals(sig: Signals, sheet: DataSheet, omega_g: float = filtering.OMEGA_G,
                        lifted: bool = False) -> StepSignals:
    """q, q̇, q̈ and u of one step from its recorded signals, all zero-phase filtered at ω_g. ``lifted``: a
    run of the lifted vehicle, whose chassis stays at rest while the wheels turn (no odometry: the chassis
    entries of q̇ and q̈ are 0)."""
    g, d = sheet.geometry, sheet.drive
    ts = d.cycle_time
    alpha, alpha_d, alpha_dd = filtering.zero_phase_derivatives(sig.alpha, ts, omega_g)
    beta, beta_d, beta_dd = filtering.zero_phase_derivatives(sig.motor_position / d.i_G, ts, omega_g)
    torque = filtering.zero_phase_lowpass(applied_torque_at_samples(sig.motor_torque), ts, omega_g)
    velocity = np.zeros((len(sig), 3)) if lifted else odometry.chassis_velocity(alpha, alpha_d, beta_d, g)
    acceleration = np.gradient(velocity, ts, axis=0, edge_order=2)
    n = len(sig)
    q = np.hstack([np.zeros((n, 3)), alpha, beta])
    qd = np.hstack([velocity, alpha_d, beta_d])
    qdd = np.hstack([acceleration, alpha_dd, beta_dd])
    fast = coulomb_velocity_cutoff(d)
    alpha_f, alpha_df, _ = filtering.zero_phase_derivatives(sig.alpha, ts, coulomb_steering_cutoff(d))
    beta_df = filtering.zero_phase_derivatives(sig.motor_position / d.i_G, ts, fast)[1]
    qd_coulomb = np.hstack([np.zeros_like(velocity) if lifted else
                            odometry.chassis_velocity(alpha_f, alpha_df, beta_df, g), alpha_df, beta_df])
    return StepSignals(str(sig.step[0]), int(sig.k[0]), sig.time, q, qd, qdd, torque, qd_coulomb,
                       ts, omega_g)


#: The Coulomb columns' cutoff stays below this share of the Nyquist frequency π/T_s: a sampled signal
#: holds nothing faster, and a Butterworth design needs its cutoff below it.
NYQUIST_SHARE = 0.8


def coulomb_velocity_cutoff(drive) -> float:
    """Cutoff (rad/s) of the velocities inside the Coulomb columns: :data:`COULOMB_VELOCITY_CUTOFF`, or
    :data:`NYQUIST_SHARE` of the Nyquist frequency at a SYNC period longer than 6.3 ms."""
    return min(COULOMB_VELOCITY_CUTOFF, NYQUIST_SHARE * np.pi / drive.cycle_time)


def coulomb_steering_cutoff(drive) -> float:
    """Cutoff (rad/s) of the steering rates inside the Coulomb columns: :func:`coulomb_velocity_cutoff`, or
    less for a coarse steering sensor. The derivative of an angle read in steps of q (``drive.steering_lsb``)
    and low-passed at ω resolves rates of about q·ω (a step per filter time constant); the Coulomb column's
    sign must be resolved at the stiction threshold below which the fit drops the rows, so ω ≤ threshold/q
    (14 bits: 522 rad/s, which does not bind; 12 bits: 130; 10 bits: 33)."""
    return min(coulomb_velocity_cutoff(drive), VELOCITY_THRESHOLD["alpha_l"] / drive.steering_lsb)


def applied_torque_at_samples(motor_torque: np.ndarray) -> np.ndarray:
    """Torque actual of SYNC j is applied over [t_j, t_j + T_s] (docs/conventions.md). A central
    difference at t_j sees the mean torque over [t_j − T_s, t_j + T_s]: (u_{j−1} + u_j)/2.

    Args:
        motor_torque: (N, 4) torque actual per SYNC, N m motor side.
    Returns:
        (N, 4) torque aligned with the sampled positions (the first row is kept as is).
    """
    aligned = np.asarray(motor_torque, dtype=float).copy()
    aligned[1:] = 0.5 * (aligned[1:] + aligned[:-1])
    return aligned


def step_blocks(st: StepSignals, sheet: DataSheet, coordinates: tuple[str, ...] | None = None,
                eps: float = dynamics.EPS) -> list[RegressorBlock]:
    """Rows H_kᵀΘ and H_kᵀBu (19) of one step, one block per generalized coordinate.

    Args:
        st: the step's generalized signals.
        sheet: the data sheet (geometry, i_G).
        coordinates: which of the mode's coordinates to keep (default all of them); e.g. only
            ``("x_ch",)`` for straight motion with α_v ≡ 0.
    """
    g, d = sheet.geometry, sheet.drive
    alpha = model_alpha(st, g)
    alpha_v = kinematics.alpha_v_from_alpha(alpha, g) if st.k == 2 else None
    q = st.q.copy()
    q[:, 3:5] = alpha
    theta = _coulomb_filtered(
        dynamics.reduced_regressor(st.k, q, st.qd, st.qdd, g, eps, alpha_v=alpha_v),
        dynamics.reduced_regressor(st.k, q, st.qd_coulomb, np.zeros_like(st.qdd), g, eps, alpha_v=alpha_v), st)
    tau = dynamics.reduced_input(st.k, q, st.motor_torque, g, d.i_G, alpha_v=alpha_v)
    sdot = kinematics.sdot_from_qdot(st.k, alpha, st.qd, g, alpha_v=alpha_v)
    names = MODE_COORDINATES[st.k]
    blocks = []
    for j, name in enumerate(names):
        if coordinates is not None and name not in coordinates:
            continue
        blocks.append(RegressorBlock(theta[:, j, :], tau[:, j], sdot[:, j], f"{st.step}/{name}"))
    return blocks


def _coulomb_filtered(theta: np.ndarray, coulomb: np.ndarray, st: StepSignals) -> np.ndarray:
    """``theta`` (N, n, 11) with its Coulomb columns taken from ``coulomb`` (the same rows at the Coulomb
    cutoff's velocities) low-passed at ω_g, as the other columns' signals are (parallel filtering)."""
    part = coulomb[:, :, COULOMB_COLUMNS]
    n, n_k, n_c = part.shape
    theta[:, :, COULOMB_COLUMNS] = filtering.zero_phase_lowpass(
        part.reshape(n, n_k * n_c), st.cycle_time, st.omega_g).reshape(n, n_k, n_c)
    return theta


def lifted_blocks(st: StepSignals, sheet: DataSheet, eps: float = dynamics.EPS) -> list[RegressorBlock]:
    """Rows Θ and Bu (15)–(17) of the lifted vehicle's wheels, one block per wheel (order fl, rl, fr, rr):
    with the chassis at rest and no ground contact each wheel is its own coordinate (H selects β_i),
    B_w β̈_i + d_vw β̇_i + d_cw tanh(β̇_i/ε) = i_G u_i. The Coulomb columns are built and filtered as in
    :func:`step_blocks`.

    Args:
        st: the lifted run's generalized signals (:func:`generalized_signals` with ``lifted=True``).
        sheet: the data sheet (i_G)."""
    rows = dynamics.regressor(st.q, st.qd, st.qdd, eps=eps)[:, 5:9, :]
    coulomb = dynamics.regressor(st.q, st.qd_coulomb, np.zeros_like(st.qdd), eps=eps)[:, 5:9, :]
    theta = _coulomb_filtered(rows, coulomb, st)
    tau = sheet.drive.i_G * st.motor_torque
    return [RegressorBlock(theta[:, i, :], tau[:, i], st.qd[:, 5 + i], f"{st.step}/beta_{wheel}")
            for i, wheel in enumerate(WHEELS)]


#: The coordinate each identification step excites (section 6.2); the held side of a steering step
#: stands still in stiction and contributes no rows.
EXCITED = {"steer_left": ("alpha_l",), "steer_right": ("alpha_r",), "straight": ("x_ch",),
           "rotation": ("gamma_ch",)}


def identification_blocks(signals: Signals, sheet: DataSheet) -> list[RegressorBlock]:
    """All rows of the four identification steps (22): mode 1 (the steered side), mode 2 with
    α_v ≡ 0 (x_ch), mode 4 (γ_ch).

    Raises:
        RunDirectoryError: a step is missing from the recording.
    """
    blocks = []
    for step in IDENTIFICATION_STEPS:
        st = generalized_signals(step_signals(signals, step), sheet)
        blocks += step_blocks(st, sheet, EXCITED[step])
    return blocks


def validation_blocks(signals: Signals, sheet: DataSheet) -> list[RegressorBlock]:
    """Rows of the lane change (mode 2, both coordinates α_v and x_ch)."""
    st = generalized_signals(step_signals(signals, VALIDATION_STEP), sheet)
    return step_blocks(st, sheet)


def correlation_lag(cycle_time: float, omega_g: float = filtering.OMEGA_G) -> int:
    """Rows over which residuals of signals filtered at ω_g stay correlated: ≈ 4/(ω_g T_s)."""
    return int(np.ceil(4.0 / (omega_g * cycle_time)))
