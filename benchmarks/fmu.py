"""Speed of the native plant FMU against the same model packaged with pythonfmu, all measured in this run.

    python benchmarks/fmu.py [--steps N]

Builds the native C plant FMU (FMI 2.0 and 3.0, fmu.export.export_plant_fmu) and a pythonfmu FMU (FMI 2.0)
that wraps the same hybrid model (fmu.plant_reference, the numpy reference the tests check the C plant
against), then measures communication steps per second (h = 2 ms, constant drive torques, chassis moving
in mode 2):

* fmpy: set the four torques, doStep, get the outputs -- once per step (a co-simulation master's loop);
* ecospy: set the torques once, then ``step(N)`` inside the C++ host.

Ratios are against the pythonfmu FMU in fmpy. The pythonfmu FMU needs a Python interpreter inside the
importer (pythonfmu, extra ``bench``); in ecospy's C++ host it is tried and reported if it fails.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

# this script is named fmu.py: keep its directory off the path so 'fmu' is the package
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != os.path.dirname(os.path.abspath(__file__))]

from qomni.fmu.cosim import MOTOR_TORQUE, FmuSlave  # noqa: E402
from qomni.fmu.export import export_plant_fmu  # noqa: E402
from qomni.datasheet import DataSheet  # noqa: E402
from qomni.conventions import P1_NAMES  # noqa: E402
from qomni.ident.result import IdentificationResult  # noqa: E402

H = 0.002
TORQUE = 1.5

PYTHONFMU_SCRIPT = '''
import numpy as np
from pythonfmu import Fmi2Causality, Fmi2Slave, Real

from qomni.fmu import plant_reference as R
from qomni.datasheet import Geometry

P = np.array({p})


class qomni_plant_py(Fmi2Slave):
    author = "qomni benchmarks/fmu.py"
    description = "fmu.plant_reference (the plant FMU's model in numpy) packaged with pythonfmu"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.params = R.PlantParameters(P, Geometry({l}, {b}, {a}, {r}), {i_G})
        self.state = R.initial_state(self.params)
        for w in ("fl", "rl", "fr", "rr"):
            setattr(self, "motor_torque_" + w, 0.0)
            self.register_variable(Real("motor_torque_" + w, causality=Fmi2Causality.input))
        self.x_w = 0.0
        self.register_variable(Real("x_w", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        u = np.array([self.motor_torque_fl, self.motor_torque_rl, self.motor_torque_fr, self.motor_torque_rr])
        self.state = R.step(self.state, u, self.params, step_size)
        self.x_w = float(self.state[0])
        return True
'''


def identification(sheet: DataSheet) -> IdentificationResult:
    n = sheet.nominal
    return IdentificationResult(values={name: getattr(n, name) for name in P1_NAMES}, std={}, B_w=n.B_w,
                                condition_number=float("nan"), rows_used={}, rows_total={}, residual_rms={})


def build_pythonfmu(sheet: DataSheet, directory: Path) -> Path:
    from pythonfmu.builder import FmuBuilder

    g = sheet.geometry
    script = directory / "qomni_plant_py.py"
    script.write_text(textwrap.dedent(PYTHONFMU_SCRIPT).format(
        p=list(map(float, sheet.nominal.p)), l=g.l, b=g.b, a=g.a, r=g.r, i_G=sheet.drive.i_G))
    return FmuBuilder.build_FMU(script, dest=directory)


def fmpy_rate(path: Path, steps: int, inputs, output: str) -> tuple[float, float]:
    """(steps/s, final output) with set + doStep + get per step."""
    with FmuSlave(path) as s:
        u, y = s.refs(inputs), s.refs([output])
        t0 = time.perf_counter()
        for _ in range(steps):
            s.set_real(u, [TORQUE] * 4)
            s.step(H)
            value = s.get_real(y)[0]
        return steps / (time.perf_counter() - t0), value


def ecospy_rate(path: Path, steps: int, inputs, output: str) -> tuple[float, float]:
    """(steps/s, final output) with the torques set once and ``step(steps)`` in the host."""
    import ecospy

    structure = ecospy.EcosSimulationStructure()
    structure.add_model("m", str(path))
    sim = ecospy.EcosSimulation(structure=structure, step_size=H)
    try:
        sim.init()
        for name in inputs:
            sim.set_real(f"m::{name}", TORQUE)
        t0 = time.perf_counter()
        sim.step(steps)
        rate = steps / (time.perf_counter() - t0)
        return rate, sim.get_real(f"m::{output}")
    finally:
        sim.terminate()
        sim.free()
        structure.free()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=5000, help="steps of the native FMUs")
    parser.add_argument("--python-steps", type=int, default=50, help="steps of the pythonfmu FMU")
    args = parser.parse_args(argv)
    sheet = DataSheet.load()
    rows = []
    with tempfile.TemporaryDirectory(prefix="qomni_bench_fmu_") as tmp:
        tmp = Path(tmp)
        native = {v: export_plant_fmu(identification(sheet), sheet, tmp / f"plant{v}.fmu", v) for v in (2, 3)}
        py = build_pythonfmu(sheet, tmp)
        py_inputs = [n.replace(".", "_") for n in MOTOR_TORQUE]
        base, x_py = fmpy_rate(py, args.python_steps, py_inputs, "x_w")
        rows.append(("pythonfmu FMI 2, fmpy (baseline)", base, x_py, args.python_steps))
        for v in (2, 3):
            rate, x = fmpy_rate(native[v], args.steps, MOTOR_TORQUE, "x_w")
            rows.append((f"native C FMI {v}, fmpy", rate, x, args.steps))
        for v in (2, 3):
            try:
                rate, x = ecospy_rate(native[v], args.steps, MOTOR_TORQUE, "x_w")
                rows.append((f"native C FMI {v}, ecospy", rate, x, args.steps))
            except Exception as exc:  # noqa: BLE001 - report, do not hide
                rows.append((f"native C FMI {v}, ecospy: failed ({exc})", float("nan"), float("nan"), 0))
        try:
            rate, x = ecospy_rate(py, args.python_steps, py_inputs, "x_w")
            rows.append(("pythonfmu FMI 2, ecospy", rate, x, args.python_steps))
        except Exception as exc:  # noqa: BLE001
            rows.append((f"pythonfmu FMI 2, ecospy: failed ({type(exc).__name__}: {exc})".replace("\n", " "),
                         float("nan"), float("nan"), 0))
        # the same model: after the same steps the native FMU is where the pythonfmu one is
        _, x_native = fmpy_rate(native[2], args.python_steps, MOTOR_TORQUE, "x_w")
    print(f"plant FMU, h = {H * 1e3:g} ms, torques {TORQUE} N m (mode 2), all in this run")
    print(f"{'importer':<44} {'steps/s':>12} {'ratio':>9} {'steps':>6}")
    for name, rate, _, n in rows:
        ratio = rate / base if np.isfinite(rate) else float("nan")
        print(f"{name:<44} {rate:>12.0f} {ratio:>9.1f} {n:>6}")
    print(f"x_w after {args.python_steps} steps: native {x_native:.12f} m, pythonfmu {x_py:.12f} m, "
          f"difference {abs(x_native - x_py):.1e} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
