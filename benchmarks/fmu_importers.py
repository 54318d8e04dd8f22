"""The importer matrix: the plant FMU (FMI 2.0 and 3.0) in every importer installable here, each run with the
same torque sequence and compared with fmpy, plus two standard checkers.

    python benchmarks/fmu_importers.py [--steps 500] [--fmusim PATH] [--fmucheck PATH]

Importers (Python packages of the ``test`` and ``bench`` extras):

* fmpy -- the reference (FMI 2 and 3, ``FMU2Slave`` / ``FMU3Slave``);
* ecospy -- Vico's libecos (C++ host; needs libtbb.so.12, from the ``tbb`` wheel or Debian's libtbb12);
* libcosimpy -- Open Simulation Platform's libcosim (C++ host), inputs through an override manipulator;
* checkers: ``fmpy validate`` and the FMU Manipulation Toolbox's ``fmutool -check`` (FMI XSD and semantic
  checks).

Built from source (``benchmarks/build_importers.sh`` builds both with Debian's cmake, libxml2, zlib,
minizip and SUNDIALS CVODE; found on PATH or given by ``--fmusim`` / ``--fmucheck``):

* fmusim -- the Modelica Association's importer of the Reference FMUs (FMI 1, 2, 3; XML schema checks on
  load), also restarted from a serialized FMU state (``--final-fmu-state-file`` /
  ``--initial-fmu-state-file``, FMI 2.0 §2.1.8) at the run's half, compared with the uninterrupted run;
* fmuCheck -- the FMU Compliance Checker (FMI 1 and 2, FMI Library 2.0.3).

The torques are a CSV input file for both (piecewise constant: a row before and after each change at the
same time). fmusim's FMI 2 co-simulation loop applies an input change one communication step late (it
reads the inputs before the event at the switching time), so its FMI 2 difference to fmpy is that of the
late switch, not of the FMU; its FMI 3 loop and fmuCheck switch on time.

Not installable here: OMSimulator (its pip package downloads the binary from build.openmodelica.org; no
network beyond the package index).

Per importer and FMI version it prints whether the FMU loaded and stepped, the largest difference of every
output to fmpy's over the run, and the wall time as a ratio to fmpy's in the same run. Each importer runs
in a child process, so one that crashes is an entry of the matrix (libcosimpy 0.0.6 dies in
``add_local_slave`` on the FMI 3 plant while reading its model description: the binary is never loaded).
"""
from __future__ import annotations

import argparse
import csv
import ctypes
import multiprocessing
import shutil
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
from qomni.fmu.export import export_plant_can_fmu, export_plant_fmu
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


def write_input(u: np.ndarray, h: float, path: Path) -> Path:
    """The torques as a CSV input file (time, motor_torque.*), piecewise constant over each step."""
    rows = [[0.0, *u[0]]]
    for i in range(1, len(u)):
        if np.any(u[i] != u[i - 1]):
            rows += [[i * h, *u[i - 1]], [i * h, *u[i]]]
    rows.append([len(u) * h, *u[-1]])
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["time", *MOTOR_TORQUE])
        writer.writerows([[repr(float(x)) for x in row] for row in rows])
    return path


def read_output(path: Path, steps: int) -> np.ndarray:
    """(steps, outputs) of an importer's CSV at the communication points after each step (row 0 is t = 0)."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader)
        rows = [[float(x) for x in row[:len(header)]] for row in reader if row]
    column = [header.index(n) for n in REAL_OUTPUTS]
    data = np.array(rows)
    if len(data) != steps + 1:
        raise RuntimeError(f"{path.name}: {len(data)} rows, expected {steps + 1}")
    return data[1:, column]


def run_fmusim(fmu, u, h, exe, start=None, stop=None, state_in=None, state_out=None):
    work = Path(tempfile.mkdtemp(prefix="qomni_fmusim_"))
    try:
        command = [exe, "--interface-type", "cs", "--output-interval", repr(h),
                   "--stop-time", repr((stop or len(u)) * h), "--input-file", str(write_input(u, h, work / "in.csv")),
                   "--output-file", str(work / "out.csv")]
        if start:
            command += ["--start-time", repr(start * h)]
        if state_in:
            command += ["--initial-fmu-state-file", str(state_in)]
        if state_out:
            command += ["--final-fmu-state-file", str(state_out)]
        proc = subprocess.run(command + [str(fmu)], capture_output=True, text=True, timeout=600)
        if proc.returncode != 0:
            raise RuntimeError(f"fmusim exit {proc.returncode}: {(proc.stdout + proc.stderr).strip()[-300:]}")
        return read_output(work / "out.csv", (stop or len(u)) - (start or 0))
    finally:
        shutil.rmtree(work, ignore_errors=True)


def fmusim_restart(fmu, u, h, exe) -> float:
    """Largest output difference of a run restarted at its half from fmusim's serialized FMU state to the
    uninterrupted run."""
    whole = run_fmusim(fmu, u, h, exe)
    half = len(u) // 2
    with tempfile.TemporaryDirectory(prefix="qomni_state_") as tmp:
        state = Path(tmp) / "state.bin"
        first = run_fmusim(fmu, u, h, exe, stop=half, state_out=state)
        second = run_fmusim(fmu, u, h, exe, start=half, state_in=state)
    return float(np.max(np.abs(np.vstack([first, second]) - whole)))


def run_fmucheck(fmu, u, h, exe):
    work = Path(tempfile.mkdtemp(prefix="qomni_fmucheck_"))
    try:
        command = [exe, "-h", repr(h), "-s", repr(len(u) * h), "-i", str(write_input(u, h, work / "in.csv")),
                   "-o", str(work / "out.csv"), "-e", str(work / "log.txt"), str(fmu)]
        proc = subprocess.run(command, capture_output=True, text=True, timeout=600)
        log = (work / "log.txt").read_text(errors="replace") if (work / "log.txt").exists() else ""
        summary = " ".join(log.split("FMU check summary:")[-1].split()) if "FMU check summary:" in log else ""
        clean = "FMU reported: 0 warning(s) and error(s) Checker reported: 0 Warning(s) 0 Error(s)"
        if proc.returncode != 0 or summary != clean or "Simulation finished successfully" not in log:
            raise RuntimeError(f"fmuCheck exit {proc.returncode}: {summary or log.strip()[-300:]}")
        return read_output(work / "out.csv", len(u))
    finally:
        shutil.rmtree(work, ignore_errors=True)


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
    parser.add_argument("--fmusim", default=shutil.which("fmusim"), help="fmusim executable (default: on PATH)")
    parser.add_argument("--fmucheck", default=shutil.which("fmuCheck.linux64"),
                        help="FMU Compliance Checker executable (default: fmuCheck.linux64 on PATH)")
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
    executables = {"fmusim": (args.fmusim, run_fmusim, (2, 3)), "fmuCheck": (args.fmucheck, run_fmucheck, (2,))}
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
            for name, (exe, run, versions) in executables.items():
                if version not in versions:
                    continue
                if not exe:
                    print(f"  {name:<12} not built (benchmarks/build_importers.sh)")
                    continue
                try:
                    t0 = time.perf_counter()
                    out = run(fmu, u, h, exe)
                    elapsed = time.perf_counter() - t0
                    diff = float(np.max(np.abs(out - reference)))
                    print(f"  {name:<12} steps; difference {diff:.1e}; time {elapsed / t_ref:.2f} x fmpy "
                          "(with process start and CSV files)")
                except Exception as exc:  # noqa: BLE001 - a failing importer is a matrix entry
                    print(f"  {name:<12} fails: {str(exc).splitlines()[0][:160]}")
            if args.fmusim:
                try:
                    print(f"  {'fmusim state':<12} restarted at the half from its serialized FMU state: "
                          f"difference {fmusim_restart(fmu, u, h, args.fmusim):.1e} to the uninterrupted run")
                except Exception as exc:  # noqa: BLE001
                    print(f"  {'fmusim state':<12} fails: {str(exc).splitlines()[0][:160]}")
            print(f"  {'fmpy validate':<12} {fmpy_validate(fmu)}")
            print(f"  {'fmutool -check':<12} {check(['fmutool', '-input', str(fmu), '-check'])}")
        fmu = export_plant_can_fmu(ident, sheet, Path(tmp) / "plant_can.fmu")
        print("\nplant-can (FMI 3.0, FMI-LS-BUS CAN terminal; the frames themselves: tests/test_fmu_plant_can.py)")
        print(f"  {'fmpy validate':<12} {fmpy_validate(fmu)}")
        print(f"  {'fmutool -check':<12} {check(['fmutool', '-input', str(fmu), '-check'])}")
        if args.fmusim:
            for mode in ([], ["--event-mode-used"]):
                command = [args.fmusim, "--interface-type", "cs", "--output-interval", repr(h), "--stop-time",
                           repr(args.steps * h), *mode, "--output-file", str(Path(tmp) / "can.csv"), str(fmu)]
                proc = subprocess.run(command, capture_output=True, text=True, timeout=600)
                what = "loads, validates and steps (no bus simulation: no frames)" if proc.returncode == 0 else \
                    f"fails: exit {proc.returncode}: {(proc.stdout + proc.stderr).strip()[-160:]}"
                print(f"  {'fmusim':<12} {' '.join(mode) or 'step mode only'}: {what}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
