"""Exact directional derivatives against finite differences: the feed-forward FMU's 4 x 7 Jacobian of the
motor torques by (q.alpha_l, q.alpha_r, alpha_v, s_dot, s_ddot) in fmpy, per motion mode, from
fmi3GetDirectionalDerivative (one call per known) and from central differences of the outputs (two input
settings and output reads per known): the time as a ratio to the exact one, measured in the same run, and
the finite differences' largest error relative to the row's largest exact entry.

    python benchmarks/fmu_derivatives.py [--states 200] [--step 1e-6]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from qomni.conventions import P1_NAMES, WHEELS
from qomni.datasheet import DataSheet
from qomni.fmu.cosim import FmuSlave
from qomni.fmu.export import export_feedforward_fmu
from qomni.ident import kinematics
from qomni.ident.result import IdentificationResult

KNOWNS = ["q.alpha_l", "q.alpha_r", "alpha_v", "s_dot[1]", "s_dot[2]", "s_ddot[1]", "s_ddot[2]"]
UNKNOWNS = [f"motor_torque.{w}" for w in WHEELS]


def state(rng, k, g) -> dict[str, float]:
    alpha_v = rng.uniform(-0.8, 0.8) * kinematics.alpha_v_max(g)
    alpha = kinematics.f_icr(alpha_v, g)[0] if k == 2 else rng.uniform(-1.3, 1.3, 2)
    return {"q.alpha_l": alpha[0], "q.alpha_r": alpha[1], "alpha_v": 0.0,
            "s_dot[1]": rng.normal(0, 0.5), "s_dot[2]": rng.normal(0, 0.5),
            "s_ddot[1]": rng.normal(0, 2.0), "s_ddot[2]": rng.normal(0, 2.0)}


def exact(s, unknowns, knowns) -> np.ndarray:
    eye = np.eye(len(knowns))
    return np.array([s.fmu.getDirectionalDerivative(unknowns, knowns, list(e)) for e in eye]).T


def finite_differences(s, values, step) -> np.ndarray:
    out, J = s.refs(UNKNOWNS), np.zeros((len(UNKNOWNS), len(KNOWNS)))
    for j, name in enumerate(KNOWNS):
        h = step * max(1.0, abs(values[name]))
        s.set({name: values[name] + h})
        up = s.get_real(out)
        s.set({name: values[name] - h})
        J[:, j] = (up - s.get_real(out)) / (2 * h)
        s.set({name: values[name]})
    return J


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--states", type=int, default=200, help="random states per mode")
    parser.add_argument("--step", type=float, default=1e-6, help="relative finite-difference step")
    args = parser.parse_args(argv)
    sheet = DataSheet.load()
    values = {n: float(getattr(sheet.nominal, n)) for n in P1_NAMES}
    ident = IdentificationResult(values=values, std={n: 0.0 for n in P1_NAMES}, B_w=float(sheet.nominal.B_w),
                                 condition_number=1.0, rows_used={}, rows_total={}, residual_rms={})
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory(prefix="qomni_derivatives_") as tmp:
        fmu = export_feedforward_fmu(ident, sheet, Path(tmp) / "ff.fmu", 3)
        print(f"feed-forward FMU (FMI 3, fmpy), {args.states} random states per mode, FD step {args.step}")
        print(f"{'mode':>4} {'exact [ms]':>11} {'FD / exact':>11} {'FD error (rel.)':>16}")
        with FmuSlave(fmu) as s:
            unknowns, knowns = s.refs(UNKNOWNS), s.refs(KNOWNS)
            for k in (1, 2, 3, 4):
                t_exact = t_fd = worst = 0.0
                for _ in range(args.states):
                    x = state(rng, k, sheet.geometry)
                    s.set({"k": k, **x})
                    t0 = time.perf_counter()
                    J = exact(s, unknowns, knowns)
                    t1 = time.perf_counter()
                    D = finite_differences(s, x, args.step)
                    t2 = time.perf_counter()
                    t_exact, t_fd = t_exact + t1 - t0, t_fd + t2 - t1
                    scale = np.max(np.abs(J), axis=1, keepdims=True)
                    worst = max(worst, float(np.max(np.abs(D - J) / scale)))
                print(f"{k:>4} {1e3 * t_exact / args.states:>11.3f} {t_fd / t_exact:>11.2f} {worst:>16.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
