"""Prediction accuracy of the plant FMU against a recorded campaign (the emulator or a real vehicle).

For every campaign step (steer_left, steer_right, straight, rotation, lane_change) the step's rows are cut
into consecutive windows of ``window`` seconds. Each window starts the plant FMU from the *measured*
state at its first row -- steering angles alpha, steering rates (Savitzky-Golay derivative of alpha),
chassis velocities by odometry (3) from alpha, alpha_dot and the motor velocities (zero in mode-1 steps),
pose (0, 0, 0) and beta = 0 -- and feeds it the recorded torque actual (0x6077, applied from its SYNC
instant over one cycle). The FMU's outputs after every cycle are compared with the measurements of the
next row:

* ``alpha`` (rad): alpha_l, alpha_r;
* ``motor_position`` (rad, motor side, relative to the window start) and ``motor_velocity`` (rad/s);
* ``position`` (m) and ``heading`` (rad): the chassis pose against the pose integrated from the
  measurements by odometry (3) (the run directory holds no ground-truth pose; odometry is what the
  vehicle's own sensors say), both from (0, 0, 0) at the window start.

In chassis steps the FMU's ``mode_tol`` is 0.01 rad (the controller holds the measured angles within a few
mrad of the configuration, the 14-bit sensor quantizes to 0.38 mrad), in steering steps the default.
"""
from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from qomni.ident import odometry

STEPS = ("steer_left", "steer_right", "straight", "rotation", "lane_change")
OUTPUTS = ("alpha", "motor_position", "motor_velocity", "position", "heading")
UNITS = {"alpha": "rad", "motor_position": "rad", "motor_velocity": "rad/s", "position": "m", "heading": "rad"}
CHASSIS_MODE_TOL = 0.01
"""rad; FMU parameter mode_tol in windows of chassis steps (module docstring)."""
DERIVATIVE_WINDOW = 11
"""Samples of the Savitzky-Golay differentiator (quadratic) of the steering angles."""


@dataclass
class StepAccuracy:
    """Prediction errors of one campaign step.

    Attributes:
        step: the step's name; k: its motion mode; windows: number of windows.
        rms: {output: RMS error over all cycles of all windows} (units: ``UNITS``).
        end_position: (windows,) m, chassis position error at the end of each window.
        end_heading: (windows,) rad, |heading error| at the end of each window.
    """

    step: str
    k: int
    windows: int
    rms: dict[str, float]
    end_position: np.ndarray = field(repr=False)
    end_heading: np.ndarray = field(repr=False)

    @property
    def end_position_max(self) -> float:
        return float(np.max(self.end_position)) if self.windows else float("nan")

    @property
    def end_heading_max(self) -> float:
        return float(np.max(self.end_heading)) if self.windows else float("nan")


def _odometry(alpha, alpha_dot, motor_velocity, sheet):
    return odometry.chassis_velocity(alpha, alpha_dot, motor_velocity / sheet.drive.i_G, sheet.geometry)


def _window_errors(slave_factory, sig, rows, sheet, alpha_dot, k):
    """Simulate one window (row indices ``rows``, the first is the start state) -> squared errors."""
    j0 = rows[0]
    vel = _odometry(sig.alpha[j0], alpha_dot[j0], sig.motor_velocity[j0], sheet)[0]
    if k == 1:
        vel = np.zeros(3)
    start = {"alpha_l0": sig.alpha[j0, 0], "alpha_r0": sig.alpha[j0, 1], "x_ch_dot0": vel[0], "y_ch_dot0": vel[1],
             "gamma_ch_dot0": vel[2], "alpha_l_dot0": alpha_dot[j0, 0], "alpha_r_dot0": alpha_dot[j0, 1]}
    if k != 1:
        start["mode_tol"] = CHASSIS_MODE_TOL
    vehicle = slave_factory(start)
    n = len(rows) - 1
    out = {"alpha": np.zeros((n, 2)), "motor_position": np.zeros((n, 4)), "motor_velocity": np.zeros((n, 4)),
           "pose": np.zeros((n, 3))}
    try:
        for i in range(n):
            vehicle.exchange(sig.motor_torque[rows[i]])
            o = vehicle.outputs()
            for key in ("alpha", "motor_position", "motor_velocity"):
                out[key][i] = o[key]
            out["pose"][i] = o["pose"]
    finally:
        vehicle.close()
    r = rows[1:]
    qd = _odometry(sig.alpha[rows], alpha_dot[rows], sig.motor_velocity[rows], sheet)
    pose = odometry.integrate_pose(sig.time[rows], qd)[1:]
    d_heading = np.angle(np.exp(1j * (out["pose"][:, 2] - pose[:, 2])))
    return {"alpha": (out["alpha"] - sig.alpha[r]) ** 2,
            "motor_position": (out["motor_position"] - (sig.motor_position[r] - sig.motor_position[j0])) ** 2,
            "motor_velocity": (out["motor_velocity"] - sig.motor_velocity[r]) ** 2,
            "position": np.sum((out["pose"][:, :2] - pose[:, :2]) ** 2, axis=1),
            "heading": d_heading**2}


def predict_windows(run_dir: str | os.PathLike, fmu_path: str | os.PathLike | None = None, window: float = 1.0,
                    steps: tuple[str, ...] = STEPS, fmi_version: int = 3) -> list[StepAccuracy]:
    """Windowed prediction errors of the plant FMU on a recorded campaign (module docstring).

    Args:
        run_dir: a campaign run directory (signals.csv, metadata.json, identification.json).
        fmu_path: a plant FMU to use; default: exported from the run's identification.json and data sheet
            (needs gcc).
        window: window length, s (> 2 cycles).
        steps: the campaign steps to evaluate (those missing from the recording are skipped).
        fmi_version: FMI version of the exported FMU.
    Returns:
        one :class:`StepAccuracy` per evaluated step, in the order of ``steps``.
    Raises:
        qomni.ident.rundir.RunDirectoryError: missing files; ValueError: window too short.
    """
    from qomni.fmu.cosim import PlantVehicle
    from qomni.fmu.export import export_plant_fmu
    from qomni.ident.rundir import load_identification, load_repaired_run

    signals, sheet, _, _ = load_repaired_run(run_dir)
    ts = sheet.drive.cycle_time
    n_w = int(round(window / ts))
    if n_w < 2:
        raise ValueError(f"window must span at least 2 cycles of {ts} s, got {window!r} s")
    tmp = tempfile.mkdtemp(prefix="qomni_accuracy_")
    try:
        if fmu_path is None:
            fmu_path = export_plant_fmu(load_identification(run_dir), sheet, Path(tmp) / "plant.fmu", fmi_version)
        from fmpy import extract
        directory = extract(str(fmu_path), str(Path(tmp) / "unzipped"))

        def factory(start):
            return PlantVehicle(directory, ts, start)

        results = []
        for name in steps:
            if not np.any(signals.step == name):
                continue
            sig = signals.of_step(name)
            k = int(sig.k[0])
            alpha_dot = savgol_filter(sig.alpha, DERIVATIVE_WINDOW, 2, deriv=1, delta=ts, axis=0)
            squared: dict[str, list] = {o: [] for o in OUTPUTS}
            end_pos, end_head = [], []
            for j0 in range(0, len(sig) - n_w, n_w):
                e = _window_errors(factory, sig, np.arange(j0, j0 + n_w + 1), sheet, alpha_dot, k)
                for o in OUTPUTS:
                    squared[o].append(e[o].ravel() if o in ("position", "heading") else e[o].mean(axis=1))
                end_pos.append(np.sqrt(e["position"][-1]))
                end_head.append(np.sqrt(e["heading"][-1]))
            rms = {o: float(np.sqrt(np.mean(np.concatenate(v)))) if v else float("nan")
                   for o, v in squared.items()}
            results.append(StepAccuracy(name, k, len(end_pos), rms, np.array(end_pos), np.array(end_head)))
        return results
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def format_table(results: list[StepAccuracy]) -> str:
    """A plain-text table: per step the RMS error of every output and the worst pose error at the end of a
    window (position in cm, heading in degrees)."""
    head = (f"{'step':<12} {'k':>1} {'win':>3}  {'alpha':>9} {'mot.pos':>9} {'mot.vel':>9} {'position':>9} "
            f"{'heading':>9}  {'end pos max':>11} {'end head max':>12}")
    units = (f"{'':<12} {'':>1} {'':>3}  {'rad':>9} {'rad':>9} {'rad/s':>9} {'m':>9} {'rad':>9}  "
             f"{'cm':>11} {'deg':>12}")
    lines = [head, units]
    for r in results:
        lines.append(f"{r.step:<12} {r.k:>1} {r.windows:>3}  " + " ".join(f"{r.rms[o]:>9.2e}" for o in OUTPUTS)
                     + f"  {100 * r.end_position_max:>11.2f} {np.degrees(r.end_heading_max):>12.3f}")
    return "\n".join(lines)


__all__ = ["STEPS", "OUTPUTS", "UNITS", "CHASSIS_MODE_TOL", "StepAccuracy", "predict_windows", "format_table"]
