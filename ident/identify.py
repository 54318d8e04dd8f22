"""From a recorded campaign to identified parameters and their validation (paper sections 6.3 and 7).

Per campaign step the measured signals are low-pass filtered zero-phase at ω_g = 40 rad/s, including
the first and second time derivatives; chassis velocities come from odometry (3); the rows
H_kᵀΘ(q, q̇, q̈) and H_kᵀBu of (19) are stacked into (22) and estimated with B_w fixed (24), (25).
The lane change (mode 2) is never used for fitting; it validates the result (Fig. 6).

Coulomb columns. Filtering commutes with the linear terms of (16) but not with d_c·tanh(v/ε): the
filtered torque contains LP(d_c·sign v), a ramp ≈ 1/ω_g wide at every reversal, whereas tanh(LP(v)/ε)
stays a step. The Coulomb columns are therefore built from velocities differentiated at
``COULOMB_VELOCITY_CUTOFF`` and then low-passed at ω_g like the torque ("parallel filtering" of the
non-linear columns); without this the steering d_v/d_c pair is biased by up to 10 %.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import dynamics, filtering, kinematics, odometry
from .campaign import IDENTIFICATION_STEPS, METADATA, SIGNALS, VALIDATION_STEP
from qomni.datasheet import DataSheet, Drive, Geometry, Nominal
from .estimation import PARAMETER_NAMES, IdentificationResult, RegressorBlock, estimate
from .recording import Signals, read_signals
from .validation import ValidationResult, compare_generalized_torques

IDENTIFICATION_JSON = "identification.json"
VALIDATION_JSON = "validation.json"
SINGLE_AXIS_JSON = "single_axis.json"

#: Stiction thresholds on the generalized velocity (paper section 7), by coordinate: rad/s or m/s.
#: The paper gives no value. A row is only usable when the zero-phase filter (time scale 1/ω_g = 25 ms)
#: does not smear a velocity reversal — where the drive really sticks, unlike tanh(v/ε) — into it:
#: |ṡ| ≳ |s̈|_max/ω_g, i.e. 0.2 rad/s for the steering (≈ 6 rad/s² excitation) and 0.05 for the chassis.
VELOCITY_THRESHOLD = {"alpha_l": 0.2, "alpha_r": 0.2, "alpha_v": 0.2, "x_ch": 0.05,
                      "gamma_ch": 0.05, "*": 0.05}

#: Cutoff (rad/s) of the velocities inside the Coulomb columns before they are low-passed at ω_g.
COULOMB_VELOCITY_CUTOFF = 400.0

COULOMB_COLUMNS = [PARAMETER_NAMES.index(n) for n in ("d_cl", "d_cr", "d_cw")]

#: Generalized coordinates of each mode, in the column order of H_k (10)-(13).
MODE_COORDINATES = {1: ("alpha_l", "alpha_r"), 2: ("alpha_v", "x_ch"), 3: ("y_ch",), 4: ("gamma_ch",)}


class RunDirectoryError(ValueError):
    """A run directory is missing a file or a campaign step."""


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


def generalized_signals(sig: Signals, sheet: DataSheet, omega_g: float = filtering.OMEGA_G) -> StepSignals:
    """q, q̇, q̈ and u of one step from its recorded signals, all zero-phase filtered at ω_g."""
    g, d = sheet.geometry, sheet.drive
    ts = d.cycle_time
    alpha, alpha_d, alpha_dd = filtering.zero_phase_derivatives(sig.alpha, ts, omega_g)
    beta, beta_d, beta_dd = filtering.zero_phase_derivatives(sig.motor_position / d.i_G, ts, omega_g)
    torque = filtering.zero_phase_lowpass(applied_torque_at_samples(sig.motor_torque), ts, omega_g)
    velocity = odometry.chassis_velocity(alpha, alpha_d, beta_d, g)
    acceleration = np.gradient(velocity, ts, axis=0, edge_order=2)
    n = len(sig)
    q = np.hstack([np.zeros((n, 3)), alpha, beta])
    qd = np.hstack([velocity, alpha_d, beta_d])
    qdd = np.hstack([acceleration, alpha_dd, beta_dd])
    fast = COULOMB_VELOCITY_CUTOFF
    alpha_f, alpha_df, _ = filtering.zero_phase_derivatives(sig.alpha, ts, fast)
    beta_df = filtering.zero_phase_derivatives(sig.motor_position / d.i_G, ts, fast)[1]
    qd_coulomb = np.hstack([odometry.chassis_velocity(alpha_f, alpha_df, beta_df, g), alpha_df,
                            beta_df])
    return StepSignals(str(sig.step[0]), int(sig.k[0]), sig.time, q, qd, qdd, torque, qd_coulomb,
                       ts, omega_g)


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
    theta = dynamics.reduced_regressor(st.k, q, st.qd, st.qdd, g, eps, alpha_v=alpha_v)
    coulomb = dynamics.reduced_regressor(st.k, q, st.qd_coulomb, np.zeros_like(st.qdd), g, eps,
                                         alpha_v=alpha_v)[:, :, COULOMB_COLUMNS]
    n, n_k, n_c = coulomb.shape
    theta[:, :, COULOMB_COLUMNS] = filtering.zero_phase_lowpass(
        coulomb.reshape(n, n_k * n_c), st.cycle_time, st.omega_g).reshape(n, n_k, n_c)
    tau = dynamics.reduced_input(st.k, q, st.motor_torque, g, d.i_G, alpha_v=alpha_v)
    sdot = kinematics.sdot_from_qdot(st.k, alpha, st.qd, g, alpha_v=alpha_v)
    names = MODE_COORDINATES[st.k]
    blocks = []
    for j, name in enumerate(names):
        if coordinates is not None and name not in coordinates:
            continue
        blocks.append(RegressorBlock(theta[:, j, :], tau[:, j], sdot[:, j], f"{st.step}/{name}"))
    return blocks


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
        st = generalized_signals(_step(signals, step), sheet)
        blocks += step_blocks(st, sheet, EXCITED[step])
    return blocks


def validation_blocks(signals: Signals, sheet: DataSheet) -> list[RegressorBlock]:
    """Rows of the lane change (mode 2, both coordinates α_v and x_ch)."""
    st = generalized_signals(_step(signals, VALIDATION_STEP), sheet)
    return step_blocks(st, sheet)


def _step(signals: Signals, name: str) -> Signals:
    try:
        return signals.of_step(name)
    except KeyError as exc:
        raise RunDirectoryError(f"the recording has no complete '{name}' step: {exc}") from None


def load_run(run_dir: str | Path) -> tuple[Signals, DataSheet, dict]:
    """Signals, data sheet and metadata of a run directory.

    Raises:
        RunDirectoryError: a file is missing; RecordingError/DataSheetError: a file is invalid.
    """
    run_dir = Path(run_dir)
    for name in (SIGNALS, METADATA):
        if not (run_dir / name).exists():
            raise RunDirectoryError(f"{run_dir}: no {name} (not a campaign run directory?)")
    meta = json.loads((run_dir / METADATA).read_text())
    sheet = datasheet_from_metadata(meta, str(run_dir / METADATA))
    return read_signals(run_dir / SIGNALS), sheet, meta


def datasheet_from_metadata(meta: dict, source: str) -> DataSheet:
    """The data sheet stored in a run's metadata.

    Raises:
        RunDirectoryError: the entry is missing or incomplete.
    """
    ds = meta.get("datasheet")
    try:
        sheet = DataSheet(name=str(meta.get("vehicle", "vehicle")),
                          geometry=Geometry(**ds["geometry"]), drive=Drive(**ds["drive"]),
                          nominal=Nominal(**ds["nominal"]), source=source)
    except (TypeError, KeyError) as exc:
        raise RunDirectoryError(f"{source}: 'datasheet' entry missing or incomplete: {exc}") from None
    sheet._check()
    return sheet


def b_w_source(run_dir: Path, sheet: DataSheet) -> tuple[float, str]:
    """B_w for (24): the single-axis result of this run if there is one, else the data sheet's."""
    path = run_dir / SINGLE_AXIS_JSON
    if path.exists():
        data = json.loads(path.read_text())
        return float(data["pooled"]["B_w"]["value"]), "single-axis identification (lifted vehicle)"
    return sheet.nominal.B_w, "data sheet"


def correlation_lag(cycle_time: float, omega_g: float = filtering.OMEGA_G) -> int:
    """Rows over which residuals of signals filtered at ω_g stay correlated: ≈ 4/(ω_g T_s)."""
    return int(np.ceil(4.0 / (omega_g * cycle_time)))


def identify_run(run_dir: str | Path) -> IdentificationResult:
    """Identify from a run directory and write ``identification.json`` into it."""
    run_dir = Path(run_dir)
    signals, sheet, _ = load_run(run_dir)
    B_w, source = b_w_source(run_dir, sheet)
    lag = correlation_lag(sheet.drive.cycle_time)
    result = estimate(identification_blocks(signals, sheet), B_w,
                      velocity_threshold=VELOCITY_THRESHOLD, correlation_lag=lag)
    data = result.to_json_dict()
    data["parameters"]["B_w"]["source"] = source
    data["filter"] = {"omega_g": filtering.OMEGA_G, "unit": "rad/s", "zero_phase": True}
    data["velocity_threshold"] = VELOCITY_THRESHOLD
    data["coulomb_velocity_cutoff"] = {"value": COULOMB_VELOCITY_CUTOFF, "unit": "rad/s"}
    data["std_method"] = f"Newey-West, Bartlett kernel, {lag} lags (filtered rows are correlated)"
    (run_dir / IDENTIFICATION_JSON).write_text(json.dumps(data, indent=2))
    return result


def load_identification(path: str | Path) -> IdentificationResult:
    """Read ``identification.json`` (a file or the run directory holding it)."""
    path = Path(path)
    if path.is_dir():
        path = path / IDENTIFICATION_JSON
    if not path.exists():
        raise RunDirectoryError(f"{path} does not exist: run 'qomni identify' first")
    return IdentificationResult.from_json_dict(json.loads(path.read_text()))


def validate_run(run_dir: str | Path) -> ValidationResult:
    """Validate ``identification.json`` on the lane change and write ``validation.json``."""
    run_dir = Path(run_dir)
    signals, sheet, _ = load_run(run_dir)
    result = load_identification(run_dir)
    blocks = validation_blocks(signals, sheet)
    validation = compare_generalized_torques(blocks, result)
    data = validation.to_json_dict()
    data["step"] = VALIDATION_STEP
    # As the paper's Fig. 6, all rows count above. Rows in stiction carry static friction that no
    # tanh(v/ε) model predicts; the same comparison over moving rows only separates that effect.
    moving = {}
    for block in blocks:
        try:
            one = compare_generalized_torques([block], result, velocity_threshold=VELOCITY_THRESHOLD)
            moving.update({c: {"nrmse": v, "n_rows": one.channels[c].n_rows}
                           for c, v in one.nrmse.items()})
        except ValueError:  # no row of this channel moves faster than its stiction threshold
            moving[str(block.channel[0])] = {"nrmse": None, "n_rows": 0}
    data["moving_rows"] = {"velocity_threshold": VELOCITY_THRESHOLD, "channels": moving}
    validation.moving = moving
    (run_dir / VALIDATION_JSON).write_text(json.dumps(data, indent=2))
    return validation
