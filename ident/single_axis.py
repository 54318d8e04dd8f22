"""Single-axis identification on the lifted vehicle (paper section 7: B_w "estimated by single-axis
identification without ground contact").

With the chassis jacked up every wheel is a single axis, B_w β̈ + d_vw β̇ + d_cw tanh(β̇/ε) = i_G M_mot.
Each wheel tracks its own Fourier trajectory (feed-forward with nominal parameters plus PD on β); the
recording goes to ``<run>/single_axis/`` and the fit to ``<run>/single_axis.json``, from where the main
fit takes B_w.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import numpy as np

from . import filtering
from qomni.vehicle_interface import VehicleInterface

from .campaign import CampaignAborted
from .rundir import METADATA, SIGNALS
from .control_design import design_pd
from qomni.datasheet import DataSheet
from .estimation import SingleAxisResult, estimate_single_axis
from .fourier import design_fourier_trajectory
from .rundir import SINGLE_AXIS_JSON
from .regressor_rows import applied_torque_at_samples, correlation_lag
from .recording import SignalWriter, read_signals

SINGLE_AXIS_DIR = "single_axis"
STEP = "single_axis"


def plan_single_axis(duration: float = 8.0, beta_max: float = 40.0, beta_dot_max: float = 12.0,
                     beta_ddot_max: float = 30.0, seed: int = 10):
    """Four wheel trajectories β(t) [rad, wheel side], one per wheel, different seeds."""
    return [design_fourier_trajectory(duration=duration, q_min=-beta_max, q_max=beta_max,
                                      qd_max=beta_dot_max, qdd_max=beta_ddot_max, n_harmonics=5,
                                      seed=seed + i) for i in range(4)]


def run_single_axis(vehicle: VehicleInterface, sheet: DataSheet, run_dir: str | Path, trajectories,
                    on_progress: Callable[[int, int, str], None] | None = None) -> Path:
    """Drive the lifted vehicle's wheels along ``trajectories`` (from :func:`plan_single_axis`, planned
    before connecting: drives fault when SYNCs pause) and record into ``run_dir/single_axis``.

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
    (out / METADATA).write_text(json.dumps({"format": "qomni-single-axis/1", "status": "running",
                                            "duration": duration,
                                            "trajectories": [tr.to_json_dict() for tr in trajectories]},
                                           indent=2))
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
            (out / METADATA).write_text(json.dumps(meta, indent=2))
    return out


def identify_single_axis(run_dir: str | Path, sheet: DataSheet) -> SingleAxisResult:
    """Fit B_w, d_vw, d_cw per wheel from ``run_dir/single_axis`` and write ``single_axis.json``."""
    run_dir = Path(run_dir)
    sig = read_signals(run_dir / SINGLE_AXIS_DIR / SIGNALS)
    d = sheet.drive
    _, beta_dot, beta_ddot = filtering.zero_phase_derivatives(sig.motor_position / d.i_G, d.cycle_time)
    torque = filtering.zero_phase_lowpass(applied_torque_at_samples(sig.motor_torque), d.cycle_time)
    result = estimate_single_axis(beta_dot, beta_ddot, d.i_G * torque, velocity_threshold=0.5,
                                  correlation_lag=correlation_lag(d.cycle_time))
    (run_dir / SINGLE_AXIS_JSON).write_text(json.dumps(result.to_json_dict(), indent=2))
    return result
