"""Single-axis identification on the lifted vehicle (paper section 7: B_w "estimated by single-axis
identification without ground contact").

With the chassis jacked up every wheel is a single axis, B_w β̈ + d_vw β̇ + d_cw tanh(β̇/ε) = i_G M_mot.
Each wheel tracks its own Fourier trajectory (feed-forward with nominal parameters plus PD on β); the
recording goes to ``<run>/single_axis/`` and the fit to ``<run>/single_axis.json``, from where the main
fit takes B_w.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from qomni.conventions import EPSILON, PARAMETER_UNITS, WHEELS
from qomni.datasheet import DataSheet
from qomni.vehicle_interface import VehicleInterface

from . import filtering
from .breakaway import STEP as BREAKAWAY_STEP
from .breakaway import BreakawayController, BreakawayPlan, analyse_breakaway
from .campaign import CampaignAborted
from .control_design import design_pd
from .fourier import design_fourier_trajectory
from .least_squares import RANK_TOL, lstsq, newey_west_cov, rms
from .plausibility import check_drives
from .recording import RecordingError, SignalWriter, read_signals
from .spikes import repair_spikes
from .regressor import DEFAULT_VELOCITY_THRESHOLD
from .regressor_rows import applied_torque_at_samples, correlation_lag
from .rundir import METADATA, SIGNALS, SINGLE_AXIS_DIR, SINGLE_AXIS_JSON, write_json
from .torque_timing import shift_torque

STEP = "single_axis"
#: |β̇| (rad/s) below which the lifted fit drops a row: static friction is indeterminate there.
VELOCITY_THRESHOLD = 0.5


def plan_single_axis(duration: float = 8.0, beta_max: float = 40.0, beta_dot_max: float = 12.0,
                     beta_ddot_max: float = 30.0, seed: int = 10):
    """Four wheel trajectories β(t) [rad, wheel side], one per wheel, different seeds."""
    return [design_fourier_trajectory(duration=duration, q_min=-beta_max, q_max=beta_max,
                                      qd_max=beta_dot_max, qdd_max=beta_ddot_max, n_harmonics=5,
                                      seed=seed + i) for i in range(4)]


def run_single_axis(vehicle: VehicleInterface, sheet: DataSheet, run_dir: str | Path, trajectories,
                    on_progress: Callable[[int, int, str], None] | None = None,
                    breakaway: BreakawayPlan | None = BreakawayPlan()) -> Path:
    """Drive the lifted vehicle's wheels along ``trajectories`` (from :func:`plan_single_axis`, planned
    before connecting: drives fault when SYNCs pause), then (``breakaway`` not None) the breakaway ramps
    of :mod:`.breakaway` from rest, and record both into ``run_dir/single_axis`` (steps ``single_axis``
    and ``breakaway``).

    The operator must have lifted the vehicle (wheels free); the emulator does so with ``lifted``.

    Raises:
        CampaignAborted: as the campaign; the recording is kept.
    """
    d, n = sheet.drive, sheet.nominal
    out = Path(run_dir) / SINGLE_AXIS_DIR
    out.mkdir(parents=True, exist_ok=True)
    duration = max(tr.duration for tr in trajectories)
    gains = design_pd(30.0, 0.9, d.cycle_time)
    cycles = int(round(duration / d.cycle_time)) + 1
    write_json(out / METADATA, {"format": "qomni-single-axis/1", "status": "running", "duration": duration,
                                "trajectories": [tr.to_json_dict() for tr in trajectories]})
    writer = SignalWriter(out / SIGNALS)
    status = "complete"
    try:
        m = vehicle.exchange(np.zeros(4))
        beta0 = np.asarray(m.motor_position) / d.i_G
        for j in range(cycles):
            t = np.array([j * d.cycle_time])
            ref = np.array([tr.evaluate(t) for tr in trajectories])[:, :, 0]  # (4, 3)
            beta = np.asarray(m.motor_position) / d.i_G - beta0
            beta_dot = np.asarray(m.motor_velocity) / d.i_G
            wheel = (n.B_w * ref[:, 2] + n.d_vw * ref[:, 1] + n.d_cw * np.tanh(ref[:, 1] / 0.01)
                     + n.B_w * (gains.kp * (ref[:, 0] - beta) + gains.kd * (ref[:, 1] - beta_dot)))
            u = np.clip(wheel / d.i_G, -0.95 * d.max_torque, 0.95 * d.max_torque)
            m = vehicle.exchange(u)
            writer.write(STEP, 0, m, u)
            if on_progress:
                on_progress(j + 1, cycles, STEP)
        if breakaway is not None:
            _run_breakaway(vehicle, sheet, breakaway, m, beta0, writer, on_progress)
    except BaseException as exc:  # noqa: BLE001 - stop the wheels whatever happened
        status = f"aborted: {type(exc).__name__}: {exc}"
        raise CampaignAborted(status) from exc
    finally:
        try:
            vehicle.stop()
        finally:
            writer.close()
            meta = json.loads((out / METADATA).read_text())
            meta["status"] = status
            write_json(out / METADATA, meta)
    return out


def _run_breakaway(vehicle: VehicleInterface, sheet: DataSheet, plan: BreakawayPlan, m, beta0,
                   writer: SignalWriter, on_progress) -> None:
    """The breakaway ramps (:class:`.breakaway.BreakawayController`), from the measurement ``m`` on."""
    d = sheet.drive
    control = BreakawayController(plan, sheet.nominal.d_cw, d.cycle_time)
    cycles = int(math.ceil(plan.longest(sheet.nominal.d_cw) / d.cycle_time))
    for j in range(cycles):
        beta = np.asarray(m.motor_position) / d.i_G - beta0
        wheel = control.torque(beta, np.asarray(m.motor_velocity) / d.i_G)
        if control.done:
            break
        u = np.clip(wheel / d.i_G, -0.95 * d.max_torque, 0.95 * d.max_torque)
        m = vehicle.exchange(u)
        writer.write(BREAKAWAY_STEP, 0, m, u)
        if on_progress:
            on_progress(j + 1, cycles, BREAKAWAY_STEP)


def identify_single_axis(run_dir: str | Path, sheet: DataSheet, torque_lag: float = 0.0) -> SingleAxisResult:
    """Fit B_w, d_vw, d_cw per wheel from ``run_dir/single_axis`` and write ``single_axis.json``.

    ``torque_lag`` (s): the drives' torque-report lag (:mod:`.torque_timing`), corrected before the fit.
    The recording is checked as a campaign's is (:func:`.plausibility.check_drives`) and its isolated
    glitches repaired (:mod:`.spikes`, reported as ``spikes`` in single_axis.json).

    Raises: RecordingError: the recording is invalid, a drive's signals are dead or disagree, or a column
    is more corrupt than single glitches."""
    run_dir = Path(run_dir)
    path = run_dir / SINGLE_AXIS_DIR / SIGNALS
    sig, spikes = read_lifted_recording(run_dir, torque_lag)
    d = sheet.drive
    tracking = tracking_rows(sig)
    _, beta_dot, beta_ddot = filtering.zero_phase_derivatives(tracking.motor_position / d.i_G, d.cycle_time)
    torque = filtering.zero_phase_lowpass(applied_torque_at_samples(tracking.motor_torque), d.cycle_time)
    result = estimate_single_axis(beta_dot, beta_ddot, d.i_G * torque, velocity_threshold=VELOCITY_THRESHOLD,
                                  correlation_lag=correlation_lag(d.cycle_time))
    data = result.to_json_dict()
    try:
        ramps = analyse_breakaway(sig, d.i_G, {w: result.values[w]["d_cw"] for w in result.values},
                                  {w: result.values[w]["B_w"] for w in result.values})
    except ValueError as exc:
        raise RecordingError(f"{path}: breakaway ramps: {exc}") from None
    if ramps is not None:
        data["breakaway"] = ramps.to_json_dict()
    data["torque_lag"] = {"value": float(torque_lag), "unit": "s"}
    data["spikes"] = spikes.to_json_dict()
    data["vehicle"] = sheet.name             # whose wheels these are: a campaign of another vehicle refuses them
    data["datasheet"] = {"geometry": asdict(sheet.geometry), "drive": asdict(sheet.drive)}
    write_json(run_dir / SINGLE_AXIS_JSON, data)
    return result


def read_lifted_recording(run_dir: str | Path, torque_lag: float = 0.0):
    """The lifted run's recording ``run_dir/single_axis/signals.csv`` (tracking and breakaway steps),
    checked as a campaign's is (:func:`.plausibility.check_drives`), its isolated glitches repaired
    (:mod:`.spikes`) and its torque shifted by the drives' report lag ``torque_lag`` (s,
    :mod:`.torque_timing`): (signals, the glitch report).

    Raises: RecordingError: the recording is invalid, a drive's signals are dead or disagree, or a column
    is more corrupt than single glitches."""
    path = Path(run_dir) / SINGLE_AXIS_DIR / SIGNALS
    sig = read_signals(path)
    check_drives(sig, str(path))
    sig, spikes = repair_spikes(sig, str(path))
    return shift_torque(sig, torque_lag), spikes


def tracking_rows(sig):
    """The rows of a lifted recording where the wheels track their Fourier trajectories (step
    :data:`STEP`; all rows of a recording without breakaway ramps)."""
    return sig.select(sig.step == STEP) if (sig.step == BREAKAWAY_STEP).any() else sig


# --- estimation (lifted wheels) ----------------------------------------------------------------------
SINGLE_AXIS_NAMES: tuple[str, ...] = ("B_w", "d_vw", "d_cw")


WHEEL_NAMES: tuple[str, ...] = WHEELS


@dataclass
class SingleAxisResult:
    """Result of :func:`estimate_single_axis`.

    ``values[wheel][name]``, ``std[wheel][name]`` for name in (B_w, d_vw, d_cw) (kg m², N m s/rad,
    N m, wheel side); ``pooled``/``pooled_std``: one fit over all wheels stacked (the paper assumes
    equal wheels); ``rows_used`` and ``residual_rms`` (N m) per wheel.
    """

    values: dict[str, dict[str, float]]
    std: dict[str, dict[str, float]]
    pooled: dict[str, float]
    pooled_std: dict[str, float]
    rows_used: dict[str, int]
    residual_rms: dict[str, float]
    epsilon: float = EPSILON

    @property
    def B_w(self) -> float:
        """Pooled B_w estimate (kg m²), to use as p₂ in :func:`estimate`."""
        return self.pooled["B_w"]

    def to_json_dict(self) -> dict:
        def block(v, s):
            return {n: {"value": v[n], "std": s[n], "unit": PARAMETER_UNITS[n]} for n in SINGLE_AXIS_NAMES}

        return {
            "wheels": {w: block(self.values[w], self.std[w]) for w in self.values},
            "pooled": block(self.pooled, self.pooled_std),
            "rows_used": dict(self.rows_used),
            "residual_rms": dict(self.residual_rms),
            "epsilon": self.epsilon,
        }

    @classmethod
    def from_json_dict(cls, d: Mapping) -> "SingleAxisResult":
        def split(b):
            return ({n: float(b[n]["value"]) for n in SINGLE_AXIS_NAMES},
                    {n: float(b[n]["std"]) for n in SINGLE_AXIS_NAMES})

        vals, stds = {}, {}
        for w, b in d["wheels"].items():
            vals[w], stds[w] = split(b)
        pv, ps = split(d["pooled"])
        return cls(vals, stds, pv, ps, {k: int(v) for k, v in d["rows_used"].items()},
                   {k: float(v) for k, v in d["residual_rms"].items()}, float(d.get("epsilon", EPSILON)))


def estimate_single_axis(
    beta_dot: ArrayLike,
    beta_ddot: ArrayLike,
    wheel_torque: ArrayLike,
    *,
    epsilon: float = EPSILON,
    velocity_threshold: float = DEFAULT_VELOCITY_THRESHOLD,
    wheels: Sequence[str] | None = None,
    rank_tol: float = RANK_TOL,
    correlation_lag: int = 0,
) -> SingleAxisResult:
    """Single-axis fit without ground contact: B_w β̈ + d_vw β̇ + d_cw tanh(β̇/ε) = i_G M_mot.

    Parameters
    ----------
    beta_dot, beta_ddot : array_like, shape (N,) or (N, n_w)
        Wheel speed (rad/s) and acceleration (rad/s²), one column per wheel.
    wheel_torque : array_like, same shape
        Torque on the wheel side of the gear, i_G · motor_torque (N m).
    epsilon : float
        tanh smoothing ε (rad/s).
    velocity_threshold : float
        Rows with |β̇| below it are removed (rad/s).
    wheels : sequence of str, optional
        Wheel names, default ``fl, rl, fr, rr`` (or ``w0, w1, …`` if n_w ≠ 4).
    correlation_lag : int
        Newey–West lag for the covariance of filtered rows, as in :func:`estimate`.

    Returns
    -------
    SingleAxisResult

    Raises
    ------
    ValueError
        Shape mismatch, NaN/inf, or no rows left after the threshold.
    IdentifiabilityError
        If a wheel's regressor [β̈, β̇, tanh(β̇/ε)] is rank deficient.
    """
    bd = np.asarray(beta_dot, dtype=float)
    bdd = np.asarray(beta_ddot, dtype=float)
    tq = np.asarray(wheel_torque, dtype=float)
    if bd.ndim == 1:
        bd, bdd, tq = bd[:, None], bdd[:, None] if bdd.ndim == 1 else bdd, tq[:, None] if tq.ndim == 1 else tq
    if not (bd.shape == bdd.shape == tq.shape) or bd.ndim != 2:
        raise ValueError(f"shapes differ: beta_dot {bd.shape}, beta_ddot {bdd.shape}, wheel_torque {tq.shape}")
    for name, arr in (("beta_dot", bd), ("beta_ddot", bdd), ("wheel_torque", tq)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} contains NaN or inf")
    n_w = bd.shape[1]
    if wheels is None:
        wheels = WHEEL_NAMES if n_w == 4 else tuple(f"w{i}" for i in range(n_w))
    if len(wheels) != n_w:
        raise ValueError(f"{len(wheels)} wheel names for {n_w} columns")

    vals, stds, rows, res = {}, {}, {}, {}
    all_theta, all_y = [], []
    for j, w in enumerate(wheels):
        keep = np.abs(bd[:, j]) >= velocity_threshold
        rows[w] = int(keep.sum())
        if not keep.any():
            raise ValueError(f"wheel {w}: no rows left after the velocity threshold {velocity_threshold}")
        theta = np.column_stack([bdd[keep, j], bd[keep, j], np.tanh(bd[keep, j] / epsilon)])
        y = tq[keep, j]
        fit = lstsq(theta, y, SINGLE_AXIS_NAMES, rank_tol)
        if correlation_lag > 0:
            fit.cov = newey_west_cov(theta, fit.residual, np.zeros(len(y), dtype=object),
                                      np.nonzero(keep)[0], correlation_lag)
        vals[w] = dict(zip(SINGLE_AXIS_NAMES, fit.p.tolist()))
        stds[w] = dict(zip(SINGLE_AXIS_NAMES, np.sqrt(np.diag(fit.cov)).tolist()))
        res[w] = rms(fit.residual)
        all_theta.append(theta)
        all_y.append(y)
    pooled = lstsq(np.vstack(all_theta), np.concatenate(all_y), SINGLE_AXIS_NAMES, rank_tol)
    if correlation_lag > 0:
        labels = np.concatenate([np.full(len(y), w, dtype=object) for w, y in zip(wheels, all_y)])
        index = np.concatenate([np.nonzero(np.abs(bd[:, j]) >= velocity_threshold)[0]
                                for j in range(n_w)])
        pooled.cov = newey_west_cov(np.vstack(all_theta), pooled.residual, labels, index,
                                     correlation_lag)
    return SingleAxisResult(
        values=vals,
        std=stds,
        pooled=dict(zip(SINGLE_AXIS_NAMES, pooled.p.tolist())),
        pooled_std=dict(zip(SINGLE_AXIS_NAMES, np.sqrt(np.diag(pooled.cov)).tolist())),
        rows_used=rows,
        residual_rms=res,
        epsilon=epsilon,
    )

