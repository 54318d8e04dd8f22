"""A seeded short lock-step run recorded frame by frame, for the determinism test
(tests/test_hil_lockstep_trace.py) and for writing the reference ``tests/data/lockstep_trace.npz``.

What is recorded: every frame on the bus in the order the bus carried it (arbitration id, DLC, data),
seen by a passive bus opened on the channel before the server and the client, so it receives each frame
before any node can react to it; heartbeats other than boot-up are left out (a 1 s timer sends them,
not the protocol); the plant's true state after every physics step (taken in the thread that steps) and
the client's :class:`~qomni.vehicle_interface.Measurement` of every cycle.

Regenerate the reference (only when the behaviour is meant to change):
``python tests/lockstep_trace.py --write``.
"""
from __future__ import annotations

import sys
import uuid
from pathlib import Path

import can
import numpy as np

REFERENCE = Path(__file__).parent / "data" / "lockstep_trace.npz"
SEED = 7
CYCLES = 120


class TracingPlant:
    """The emulator with its true state recorded after every step (in the stepping thread)."""

    def __init__(self, emulator):
        self._emulator = emulator
        self.description = emulator.description
        self.states: list[np.ndarray] = []

    def set_motor_torques(self, motor_torque) -> None:
        self._emulator.set_motor_torques(motor_torque)

    def read_sensors(self):
        return self._emulator.read_sensors()

    def step(self, duration: float) -> None:
        self._emulator.step(duration)
        s = self._emulator.true_state()
        self.states.append(np.concatenate([[s.time], s.pose, s.velocity, s.alpha, s.alpha_rear, s.alpha_dot,
                                           s.beta, s.beta_dot, s.applied_motor_torque]))

    def close(self) -> None:
        self._emulator.close()


def tracing_emulator(seed: int) -> TracingPlant:
    """The prototype's emulator behind a TracingPlant (a factory for a plant in its own process)."""
    from qomni.emulator.description import VehicleDescription
    from qomni.emulator.vehicle import Emulator

    return TracingPlant(Emulator(VehicleDescription.load(), seed=seed))


def torques(k: int) -> np.ndarray:
    """The run's motor torques at cycle k [N m motor side]: four different sines, one saturating."""
    phase = np.array([0.0, 0.7, 1.9, 3.1])
    return np.array([0.3, -0.25, 0.2, 2.0]) * np.sin(2 * np.pi * k / 40 + phase)


def record(cycles: int = CYCLES, seed: int = SEED, plant_process: bool = False) -> dict[str, np.ndarray]:
    """Run the vehicle in lock-step for ``cycles`` SYNCs; returns the arrays of the reference file.
    ``plant_process``: the plant in a process of its own (:class:`qomni.hil.device.plant_process.PlantProcess`)."""
    import functools

    from qomni.emulator.description import VehicleDescription
    from qomni.hil.device.plant_process import PlantProcess
    from qomni.hil.device.server import VehicleServer
    from qomni.hil.master.client import VehicleClient

    description = VehicleDescription.load()
    channel = f"trace-{uuid.uuid4().hex[:10]}"
    tracer = can.Bus(interface="virtual", channel=channel)    # first on the channel: sees frames first
    frames: list[can.Message] = []
    factory = functools.partial(tracing_emulator, seed)
    plant = PlantProcess(factory) if plant_process else factory()
    server = VehicleServer(plant, f"virtual:{channel}", sync_timeout=5.0)
    measurements = []
    try:
        server.start()
        with VehicleClient.from_drive(description.drive, f"virtual:{channel}", timeout=5.0,
                                      tpdo_grace=5.0) as client:
            for k in range(cycles):
                m = client.exchange(torques(k))
                measurements.append(np.concatenate([[m.time], m.motor_position, m.motor_velocity,
                                                    m.motor_torque, m.alpha]))
        states = np.array(plant.states)
    finally:
        server.stop()
        plant.close()
        while (msg := tracer.recv(0.0)) is not None:
            frames.append(msg)
        tracer.shutdown()
    kept = [f for f in frames if not (0x701 <= f.arbitration_id <= 0x77F and bytes(f.data) != b"\x00")]
    data = np.zeros((len(kept), 8), dtype=np.uint8)
    for i, f in enumerate(kept):
        data[i, :f.dlc] = np.frombuffer(bytes(f.data), dtype=np.uint8)
    return {"arbitration_id": np.array([f.arbitration_id for f in kept], dtype=np.uint32),
            "dlc": np.array([f.dlc for f in kept], dtype=np.uint8), "data": data,
            "plant_state": states, "measurement": np.array(measurements)}


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python tests/lockstep_trace.py --write   (rewrites the reference trace)")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    trace = record()
    np.savez_compressed(REFERENCE, **trace)
    print(f"wrote {REFERENCE}: {len(trace['arbitration_id'])} frames, {len(trace['plant_state'])} plant steps")
