"""The importer matrix: the plant FMU (FMI 2.0 and 3.0) in every importer installable here, each run with the
same torque sequence and compared with fmpy, plus two standard checkers.

    python benchmarks/fmu_importers.py [--steps 500]

Importers (Python packages of the ``test`` and ``bench`` extras):

* fmpy -- the reference (FMI 2 and 3, ``FMU2Slave`` / ``FMU3Slave``);
* ecospy -- Vico's libecos (C++ host; needs libtbb.so.12, from the ``tbb`` wheel or Debian's libtbb12);
* libcosimpy -- Open Simulation Platform's libcosim (C++ host), inputs through an override manipulator;
* checkers: ``fmpy validate`` and the FMU Manipulation Toolbox's ``fmutool -check`` (FMI XSD and semantic
  checks).

Not installable on this machine (no network beyond the package index): OMSimulator (its pip package
downloads the binary from build.openmodelica.org), the Modelica Association's fmusim and the FMU
Compliance Checker (built from source with CMake: ``git clone https://github.com/modelica/Reference-FMUs
&& cmake -S Reference-FMUs/fmusim -B build && cmake --build build``; ``git clone
https://github.com/modelica-tools/FMUComplianceChecker && cmake ...``).

Per importer and FMI version it prints whether the FMU loaded and stepped, the largest difference of every
output to fmpy's over the run, and the wall time as a ratio to fmpy's in the same run. Each importer runs
in a child process, so one that crashes is an entry of the matrix (libcosimpy 0.0.6 dies in
``add_local_slave`` on the FMI 3 plant while reading its model description: the binary is never loaded).
"""
from __future__ import annotations

import argparse
import ctypes
import multiprocessing
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np

from qomni.datasheet import DataSheet
from qomni.fmu.cosim import MOTOR_TORQUE, REAL_OUTPUTS, FmuSlave
from qomni.fmu.export import export_plant_fmu
from qomni.ident.rundir import load_identification


def torques(steps: int, h: float) -> np.ndarray:
    """(steps, 4) motor torques, N m: drive straight from rest, then brake to rest."""
    t = np.arange(steps) * h
    u = np.zeros((steps, 4))
    u[t < 0.6] = 2.0
    u[t >= 0.6] = -1.5
    return u


def run_fmpy(fmu, u, h):
    with FmuSlave(fmu) as s:
        refs_u, refs_y, out = s.refs(MOTOR_TORQUE), s.refs(REAL_OUTPUTS), []
        for row in u:
            s.set_real(refs_u, row)
            s.step(h)
            out.append(s.get_real(refs_y))
    return np.array(out)


def run_ecospy(fmu, u, h):
    tbb = Path(sys.prefix) / "lib" / "libtbb.so.12"
    if tbb.is_file():
        ctypes.CDLL(str(tbb), mode=ctypes.RTLD_GLOBAL)
    import ecospy

    structure = ecospy.EcosSimulationStructure()
    structure.add_model("m", str(fmu))
    sim = ecospy.EcosSimulation(structure=structure, step_size=h)
    sim.init()
    out = []
    try:
        for row in u:
            for name, value in zip(MOTOR_TORQUE, row):
                sim.set_real(f"m::{name}", float(value))
            sim.step(1)
            out.append([sim.get_real(f"m::{n}") for n in REAL_OUTPUTS])
    finally:
        sim.terminate()
        sim.free()
        structure.free()
    return np.array(out)


def run_libcosim(fmu, u, h):
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_step_size(step_size=round(h * 1e9))
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="plant"))
    refs = {v.name: v.reference for v in execution.slave_variables(index)}
    observer, manipulator = CosimObserver.create_last_value(), CosimManipulator.create_override()
    execution.add_observer(observer)
    execution.add_manipulator(manipulator)
    refs = {(k.decode() if isinstance(k, bytes) else k): v for k, v in refs.items()}
    refs_u, refs_y, out = [refs[n] for n in MOTOR_TORQUE], [refs[n] for n in REAL_OUTPUTS], []
    for row in u:
        manipulator.slave_real_values(index, refs_u, [float(x) for x in row])
        if not execution.step():
            raise RuntimeError("libcosim: step failed")
        out.append(observer.last_real_values(index, refs_y))
    return np.array(out)


def timed(run, fmu, u, h):
    """(outputs, wall time in s) of one importer's run."""
    t0 = time.perf_counter()
    out = run(fmu, u, h)
    return out, time.perf_counter() - t0


def fmpy_validate(fmu) -> str:
    from fmpy.validation import validate_fmu

    problems = validate_fmu(str(fmu))
    return "passes" if not problems else f"fails: {problems[0]}"


def check(command) -> str:
    proc = subprocess.run(command, capture_output=True, text=True, timeout=300)
    text = proc.stdout + proc.stderr
    bad = proc.returncode != 0 or "ERROR" in text or "does not validate" in text
    return "fails: " + text.strip().splitlines()[-1] if bad else "passes"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=500, help="communication steps of the data sheet's T_s")
    parser.add_argument("--run-dir", default=None, help="identification to export (default: nominal values)")
    args = parser.parse_args(argv)
    sheet = DataSheet.load()
    h = sheet.drive.cycle_time
    if args.run_dir:
        ident = load_identification(args.run_dir)
    else:
        from qomni.ident.result import IdentificationResult
        from qomni.conventions import P1_NAMES
        nominal = sheet.nominal
        values = {n: float(getattr(nominal, n)) for n in P1_NAMES}
        ident = IdentificationResult(values=values, std={n: 0.0 for n in P1_NAMES}, B_w=float(nominal.B_w),
                                     condition_number=1.0, rows_used={}, rows_total={}, residual_rms={})
    u = torques(args.steps, h)
    importers = {"ecospy": run_ecospy, "libcosimpy": run_libcosim}
    with tempfile.TemporaryDirectory(prefix="qomni_importers_") as tmp:
        print(f"plant FMU, {args.steps} steps of {h} s; difference to fmpy = max over steps and outputs")
        for version in (2, 3):
            fmu = export_plant_fmu(ident, sheet, Path(tmp) / f"plant{version}.fmu", version)
            t0 = time.perf_counter()
            reference = run_fmpy(fmu, u, h)
            t_ref = time.perf_counter() - t0
            print(f"\nFMI {version}.0 (x_w after the run {reference[-1, 0]:.4f} m)")
            print(f"  {'fmpy':<12} reference, {t_ref:.2f} s")
            for name, run in importers.items():
                # each importer in a child process: one that crashes is a matrix entry, not the end of the run
                with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
                    try:
                        out, elapsed = pool.submit(timed, run, fmu, u, h).result()
                        diff = float(np.max(np.abs(out - reference)))
                        print(f"  {name:<12} steps; difference {diff:.1e}; time {elapsed / t_ref:.2f} x fmpy")
                    except BrokenProcessPool:
                        print(f"  {name:<12} crashed (the importer's process died, e.g. a segmentation fault)")
                    except Exception as exc:  # an importer that cannot load or step the FMU is a matrix entry
                        print(f"  {name:<12} fails: {type(exc).__name__}: {str(exc).splitlines()[0][:120]}")
            print(f"  {'fmpy validate':<12} {fmpy_validate(fmu)}")
            print(f"  {'fmutool -check':<12} {check(['fmutool', '-input', str(fmu), '-check'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
