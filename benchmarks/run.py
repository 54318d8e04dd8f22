"""Benchmarks, one command: ``python benchmarks/run.py [--quick]``.

Measured in the same run, so the ratios hold on a noisy shared machine:
1. emulator physics step vs. bare PyBullet stepping of the same URDF (same time step, no drives), also
   with every unmodelled effect on at its example magnitude;
2. one lock-step CANopen cycle (client + server + emulator, virtual bus) vs. the bare physics of a cycle,
   with the emulator in the bus' process and in a process of its own (``--plant-process`` of the CLI);
3. the campaign controller's command per cycle vs. the bare physics of a cycle;
4. the lock-step campaign (quick or full) vs. real time, both ways.

2 and 4 also in CPU time of the process (all its threads): the work a cycle costs, which the other
load of a shared machine disturbs far less than the wall time.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))                 # this checkout's qomni, not an installed one

from qomni.emulator.bullet import bullet_client, pybullet  # noqa: E402

from qomni.emulator.description import VehicleDescription  # noqa: E402
from qomni.emulator.effects import REGISTRY, EffectSet  # noqa: E402
from qomni.emulator.urdf import vehicle_urdf  # noqa: E402
from qomni.emulator.vehicle import Emulator  # noqa: E402
from qomni.hil.device.plant_process import default_spin  # noqa: E402


def best_of(fn, repeats: int = 3) -> float:
    """Fastest of ``repeats`` runs of fn() (s): the least disturbed by other load."""
    return min(fn() for _ in range(repeats))


def bare_pybullet_step(description: VehicleDescription, steps: int) -> float:
    """Wall s per bare PyBullet step (best of 3)."""
    return bare_pybullet_step_times(description, steps)[0]


def bare_pybullet_step_times(description: VehicleDescription, steps: int) -> tuple[float, float]:
    """(wall s, CPU s) per bare PyBullet step of the vehicle's URDF, each the best of 3 runs."""
    pb = bullet_client()                    # the emulator's: banner-free, functions bound once
    pb.setPhysicsEngineParameter(fixedTimeStep=0.001, numSubSteps=0, numSolverIterations=50)
    pb.setGravity(0, 0, -9.81)
    pb.createMultiBody(0, pb.createCollisionShape(pybullet.GEOM_PLANE))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "vehicle.urdf"
        path.write_text(vehicle_urdf(description))
        pb.loadURDF(str(path), [0, 0, description.geometry.r], flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
    for _ in range(300):
        pb.stepSimulation()

    def run() -> tuple[float, float]:
        t, c = time.perf_counter(), time.process_time()
        for _ in range(steps):
            pb.stepSimulation()
        return (time.perf_counter() - t) / steps, (time.process_time() - c) / steps

    runs = [run() for _ in range(3)]
    pb.disconnect()
    return min(r[0] for r in runs), min(r[1] for r in runs)


def emulator_step(description: VehicleDescription, steps: int, effects=None) -> float:
    with Emulator(description, seed=0, effects=effects) as emu:
        def run() -> float:
            t = time.perf_counter()
            for k in range(steps):
                emu.set_motor_torques(np.full(4, 0.3 * np.sin(k * 1e-3)))
                emu.step(0.001)
                if k % 2:
                    emu.read_sensors()
            return (time.perf_counter() - t) / steps

        return best_of(run)


def lockstep_cycle(description: VehicleDescription, cycles: int,
                   plant_process: bool = False) -> tuple[float, float]:
    """(wall s, CPU s of the whole process, all threads) per lock-step cycle, each the best of 3 runs.
    CPU time is the work done; on a shared machine it is far less disturbed than wall time (with
    ``plant_process`` it leaves out the plant's process)."""
    from qomni.embedded import embedded_vehicle

    with embedded_vehicle(description, seed=0, plant_process=plant_process) as client:
        def run() -> tuple[float, float]:
            t, c = time.perf_counter(), time.process_time()
            for k in range(cycles):
                client.exchange(np.full(4, 0.3 * np.sin(k * 2e-3)))
            return (time.perf_counter() - t) / cycles, (time.process_time() - c) / cycles

        runs = [run() for _ in range(3)]
        return min(r[0] for r in runs), min(r[1] for r in runs)


def controller_command(quick: bool) -> float:
    """Wall s per ``StepController.command`` over the campaign's steps (each controller run through 500 of
    its cycles on a measurement at its reference, quantized to the steering sensor's LSB as the bus gives
    it), best of 3: the campaign's own share of a cycle."""
    from qomni.datasheet import DataSheet
    from qomni.ident.campaign import Campaign, CampaignSettings
    from qomni.vehicle_interface import Measurement

    sheet = DataSheet.load()
    ts, lsb = sheet.drive.cycle_time, sheet.drive.steering_lsb
    with tempfile.TemporaryDirectory() as tmp:
        run = Campaign(sheet, Path(tmp) / "run", CampaignSettings.quick() if quick else CampaignSettings())
        controllers = run.controllers

    def one() -> float:
        calls, t = 0, time.perf_counter()
        for ctrl in controllers:
            for j in range(min(500, ctrl.cycles)):
                alpha = np.round(ctrl._reference_row(j * ts)[0] / lsb) * lsb
                ctrl.command(j * ts, Measurement(j * ts, np.zeros(4), np.ones(4), np.zeros(4), alpha))
                calls += 1
        return (time.perf_counter() - t) / calls

    return best_of(one)


def campaign(description: VehicleDescription, quick: bool,
             plant_process: bool = False) -> tuple[float, float, float]:
    """(emulated s, wall s, CPU s of the process) of a lock-step campaign against the embedded emulator
    over CAN (``plant_process``: the emulator in a process of its own)."""
    from qomni.ident.campaign import Campaign, CampaignSettings
    from qomni.datasheet import DataSheet
    from qomni.embedded import embedded_vehicle

    with tempfile.TemporaryDirectory() as tmp:
        settings = CampaignSettings.quick() if quick else CampaignSettings()
        run = Campaign(DataSheet.load(), tmp, settings)
        with embedded_vehicle(description, seed=0, plant_process=plant_process) as client:
            t, c = time.perf_counter(), time.process_time()
            run.run(client)
            wall, cpu = time.perf_counter() - t, time.process_time() - c
        return run.total_cycles * description.drive.cycle_time, wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short campaign (default: full)")
    args = parser.parse_args()
    d = VehicleDescription.load()
    steps = 2000 if args.quick else 5000
    bare, bare_cpu = bare_pybullet_step_times(d, steps)
    emu = emulator_step(d, steps)
    every_effect = EffectSet.combine(*(EffectSet.example(name) for name in REGISTRY))
    emu_effects = emulator_step(d, steps, every_effect)
    cycle, cycle_cpu = lockstep_cycle(d, 500 if args.quick else 1500)
    cycle_pp, _ = lockstep_cycle(d, 500 if args.quick else 1500, plant_process=True)
    command = controller_command(args.quick)
    emulated, wall, cpu = campaign(d, args.quick)
    _, wall_pp, _ = campaign(d, args.quick, plant_process=True)
    physics_per_cycle = bare * round(d.drive.cycle_time / 0.001)
    rows = [
        ("bare PyBullet step (same URDF, 1 ms)", f"{bare * 1e6:8.1f} µs", "1.00 (baseline)"),
        ("  the same, CPU time", f"{bare_cpu * 1e6:8.1f} µs", "1.00 (baseline of the CPU rows)"),
        ("emulator step (drives, friction, sensors)", f"{emu * 1e6:8.1f} µs", f"{emu / bare:.2f} × bare"),
        ("emulator step with all effects (example files)", f"{emu_effects * 1e6:8.1f} µs",
         f"{emu_effects / bare:.2f} × bare"),
        ("lock-step CANopen cycle (2 ms emulated)", f"{cycle * 1e6:8.1f} µs",
         f"{cycle / physics_per_cycle:.2f} × bare physics of a cycle"),
        ("  the same, CPU time of the process (all threads)", f"{cycle_cpu * 1e6:8.1f} µs",
         f"{cycle_cpu / (bare_cpu * round(d.drive.cycle_time / 0.001)):.2f} × bare physics of a cycle (CPU)"),
        ("  the same, emulator in a process of its own", f"{cycle_pp * 1e6:8.1f} µs",
         f"{cycle_pp / physics_per_cycle:.2f} × bare physics of a cycle"),
        ("campaign controller command (per cycle)", f"{command * 1e6:8.1f} µs",
         f"{command / physics_per_cycle:.2f} × bare physics of a cycle"),
        (f"campaign ({'quick' if args.quick else 'full'}, {emulated:.1f} s emulated)", f"{wall:8.1f} s",
         f"{emulated / wall:.2f} × real time"),
        ("  the same, CPU time of the process", f"{cpu:8.1f} s", f"{emulated / cpu:.2f} × real time"),
        ("  the same, emulator in a process of its own", f"{wall_pp:8.1f} s", f"{emulated / wall_pp:.2f} × real time"),
    ]
    print(f"machine: {len(os.sched_getaffinity(0))} CPUs usable, load average {os.getloadavg()[0]:.2f} at the "
          f"end; plant process polls {default_spin() * 1e3:g} ms before it blocks")
    width = max(len(r[0]) for r in rows)
    print(f"{'benchmark':<{width}}  {'cost':>11}  ratio")
    for name, cost, ratio in rows:
        print(f"{name:<{width}}  {cost:>11}  {ratio}")


if __name__ == "__main__":
    main()
