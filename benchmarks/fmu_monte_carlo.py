"""Monte Carlo with the identified uncertainty: the plant FMU (fmpy) run with N parameter sets sampled from
the identification's covariance (fmu.parameter_sets, the SSP archive's sets), the spread of its 1 s pose
prediction from rest under fixed torques, against the emulator's pose under the same torques.

    python benchmarks/fmu_monte_carlo.py RUN_DIR [--n 200] [--seed 0] [--duration 1.0] [--ssp OUT.ssp]

RUN_DIR is a campaign run directory with identification.json holding the covariance (``qomni campaign
--quick --out DIR``). Per scenario (straight: 2 N m on every wheel from alpha = 0; rotation: +-1.5 N m in
mode 4's configuration) it prints the emulator's displacement (chassis frame at the start), the nominal
FMU's, the Monte Carlo mean, standard deviation and 95 % range, where the emulator lies in units of that
standard deviation, and the time of the N runs as a ratio to one nominal run measured in the same process.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from qomni.conventions import PARAMETER_NAMES
from qomni.datasheet import DataSheet
from qomni.emulator.vehicle import Emulator
from qomni.fmu.cosim import MOTOR_TORQUE, POSE, FmuSlave
from qomni.fmu.export import export_plant_fmu
from qomni.fmu.parameter_sets import read_parameter_sets, write_parameter_sets
from qomni.ident import kinematics
from qomni.ident.rundir import load_identification


SPREAD_FLOOR = 1e-9
"""m or rad: a coordinate whose Monte Carlo spread is below this is not moved by the scenario."""


def _relative(pose0, pose1) -> np.ndarray:
    """Displacement (dx, dy in the start's chassis frame, m; dgamma, rad) from pose0 to pose1."""
    c, s = math.cos(pose0[2]), math.sin(pose0[2])
    dx, dy = pose1[0] - pose0[0], pose1[1] - pose0[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, pose1[2] - pose0[2]])


def emulator_displacement(alpha0, torque, duration, cycle) -> np.ndarray:
    emu = Emulator(initial_alpha=tuple(alpha0))
    try:
        start = emu.true_state().pose.copy()
        for _ in range(round(duration / cycle)):
            emu.set_motor_torques(torque)
            emu.step(cycle)
        return _relative(start, emu.true_state().pose)
    finally:
        emu.close()


def fmu_displacement(fmu, parameters: dict, alpha0, torque, duration, cycle) -> np.ndarray:
    with FmuSlave(fmu, {**parameters, "alpha_l0": alpha0[0], "alpha_r0": alpha0[1]}) as s:
        s.set_real(s.refs(MOTOR_TORQUE), torque)
        for _ in range(round(duration / cycle)):
            s.step(cycle)
        return s.get_real(s.refs(POSE))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir")
    parser.add_argument("--n", type=int, default=200, help="parameter sets")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=1.0, help="s")
    parser.add_argument("--ssp", default=None, help="also keep the SSP archive here")
    args = parser.parse_args(argv)
    sheet = DataSheet.load()
    cycle = sheet.drive.cycle_time
    ident = load_identification(args.run_dir)
    with tempfile.TemporaryDirectory(prefix="qomni_mc_") as tmp:
        fmu = export_plant_fmu(ident, sheet, Path(tmp) / "qomni_plant.fmu", 2)
        ssp = write_parameter_sets(ident, fmu, Path(args.ssp or Path(tmp) / "plant_uncertainty.ssp"), args.n,
                                   args.seed)
        nominal, samples = read_parameter_sets(ssp)
        scenarios = {"straight": ((0.0, 0.0), [2.0] * 4),
                     "rotation": (tuple(kinematics.mode_alpha(4, sheet.geometry)), [1.5, 1.5, -1.5, -1.5])}
        print(f"{args.n} parameter sets from the covariance of {args.run_dir} (seed {args.seed}), "
              f"{args.duration} s from rest, fmpy, FMI 2 plant; displacement in the start's chassis frame")
        for name, (alpha0, torque) in scenarios.items():
            truth = emulator_displacement(alpha0, torque, args.duration, cycle)
            fmu_displacement(fmu, nominal, alpha0, torque, args.duration, cycle)  # warm-up: load the binary
            t0 = time.perf_counter()
            nominal_pose = fmu_displacement(fmu, nominal, alpha0, torque, args.duration, cycle)
            t_nominal = time.perf_counter() - t0
            t0 = time.perf_counter()
            runs = np.array([fmu_displacement(fmu, dict(zip(PARAMETER_NAMES, row)), alpha0, torque,
                                              args.duration, cycle) for row in samples])
            t_mc = time.perf_counter() - t0
            mean, std = runs.mean(axis=0), runs.std(axis=0, ddof=1)
            low, high = np.percentile(runs, [2.5, 97.5], axis=0)
            print(f"\n{name}: torque {torque} N m, alpha0 {np.round(alpha0, 4).tolist()} rad")
            print(f"  {'':<10}{'dx [m]':>12}{'dy [m]':>12}{'dgamma [rad]':>14}")
            for label, row in (("emulator", truth), ("nominal", nominal_pose), ("MC mean", mean),
                               ("MC std", std), ("MC 2.5%", low), ("MC 97.5%", high),
                               ("emu - nom", truth - nominal_pose)):
                print(f"  {label:<10}" + "".join(f"{v:>12.5f}" for v in row[:2]) + f"{row[2]:>14.5f}")
            moving = std > SPREAD_FLOOR  # coordinates the torques move (others stay 0 by symmetry)
            z = ", ".join(f"{c} {(truth[j] - mean[j]) / std[j]:+.1f}" for j, c in enumerate(("dx", "dy", "dgamma"))
                          if moving[j])
            inside = ", ".join(f"{c} {'yes' if low[j] <= truth[j] <= high[j] else 'no'}"
                               for j, c in enumerate(("dx", "dy", "dgamma")) if moving[j])
            print(f"  emulator - MC mean in MC std: {z}; emulator inside the 95 % range: {inside}")
            print(f"  time: {args.n} runs {t_mc:.2f} s = {t_mc / t_nominal:.1f} x one nominal run "
                  f"({t_nominal * 1e3:.1f} ms)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
