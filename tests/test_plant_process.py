"""The plant in a process of its own (qomni.hil.device.plant_process): same answers as in-process, errors
raised where the caller waits, a dead child reported instead of waited for.

Bit-identity of a whole lock-step session with the plant in its own process is
tests/test_hil_lockstep_trace.py; here the contract call by call.
"""
from __future__ import annotations

import functools
import os
import signal

import numpy as np
import pytest

from qomni.emulator.description import VehicleDescription
from qomni.emulator.vehicle import Emulator
from qomni.hil.device.plant_process import PlantProcess, PlantProcessError


class FailingPlant:
    """A plant double whose step fails on request (module level: the child unpickles its factory)."""

    def __init__(self, fail_at: int):
        self.description = VehicleDescription.load()
        self.fail_at, self.steps = fail_at, 0

    def set_motor_torques(self, u) -> None:
        self.u = np.asarray(u)

    def step(self, duration: float) -> None:
        self.steps += 1
        if self.steps == self.fail_at:
            raise ZeroDivisionError(f"step {self.steps} failed")

    def read_sensors(self):
        raise KeyError("no sensors")


def _refuse() -> None:
    raise ValueError("cannot build this plant")


@pytest.fixture(scope="module")
def description():
    return VehicleDescription.load()


def _readings(plant, n: int) -> list[tuple]:
    out = []
    for k in range(n):
        plant.set_motor_torques(np.array([0.3, -0.25, 0.2, 2.0]) * np.sin(2 * np.pi * k / 40))
        r = plant.read_sensors()
        out.append((r.time, r.motor_position.tobytes(), r.motor_velocity.tobytes(), r.motor_torque.tobytes(),
                    r.steering_position.tobytes()))
        plant.step(0.002)
    return out


@pytest.mark.parametrize("spin", [0.0, 0.001], ids=["blocking", "polling"])
def test_same_samples_and_state_as_the_plant_in_process(description, spin):
    """Seeded emulator, 200 cycles of changing torques: every sample and the final true state bit for bit,
    whether the waiting sides block or poll."""
    here = Emulator(description, seed=3)
    try:
        expected, state = _readings(here, 200), here.true_state()
    finally:
        here.close()
    with PlantProcess(functools.partial(Emulator, description, seed=3), spin=spin) as there:
        assert _readings(there, 200) == expected
        remote = there.true_state()                  # any other method: a call over the pipe
        assert there.time == pytest.approx(0.4)      # a property
        assert there.description.drive == description.drive
    for field in ("pose", "velocity", "alpha", "beta", "beta_dot"):
        assert getattr(remote, field).tobytes() == getattr(state, field).tobytes(), field


def test_errors_come_back_as_raised_in_the_plant(description):
    with pytest.raises(ValueError, match="cannot build"):
        PlantProcess(_refuse)
    with PlantProcess(functools.partial(FailingPlant, 2)) as plant:
        with pytest.raises(ValueError, match="4 finite"):           # checked on the caller's side
            plant.set_motor_torques([0.0, np.nan, 0.0, 0.0])
        with pytest.raises(KeyError, match="no sensors"):
            plant.read_sensors()
        plant.step(0.002)
        plant.step(0.002)                            # fails in the child; posted, so nothing raised yet
        with pytest.raises(ZeroDivisionError, match="step 2 failed"):
            plant.steps                              # the next call that waits raises it
        assert plant.steps == 2
        with pytest.raises(AttributeError):
            plant.no_such_attribute
        assert not hasattr(plant, "no_such_attribute")


def test_a_dead_plant_process_is_reported_not_waited_for(description):
    plant = PlantProcess(functools.partial(Emulator, description, seed=0), spin=0.0)
    try:
        os.kill(plant._process.pid, signal.SIGKILL)
        plant._process.join(5.0)
        with pytest.raises(PlantProcessError, match="gone"):
            plant.step(0.002)
            plant.read_sensors()
    finally:
        plant.close()
    plant.close()                                    # idempotent
    with pytest.raises(PlantProcessError, match="closed"):
        plant.step(0.002)


def test_lockstep_server_posts_the_step_before_the_tpdos(description):
    """With a plant that steps in the background the server's calls are the in-process ones, in order:
    a seeded embedded vehicle gives the client the same measurements either way."""
    from qomni.embedded import embedded_vehicle

    runs = []
    for plant_process in (False, True):
        with embedded_vehicle(description, seed=5, plant_process=plant_process) as client:
            runs.append([client.exchange(np.array([0.5, -0.5, 1.0, 0.2]) * np.cos(k / 9)) for k in range(150)])
    for a, b in zip(*runs):
        assert a.time == b.time
        for field in ("motor_position", "motor_velocity", "motor_torque", "alpha"):
            assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), field


def test_calls_from_two_threads_are_served_one_at_a_time(description):
    """A tool reading the truth while the server's thread steps: both get whole answers."""
    import threading

    with PlantProcess(functools.partial(Emulator, description, seed=2), spin=0.0) as plant:
        stop, poses, errors = threading.Event(), [], []

        def watch():
            try:
                while not stop.is_set():
                    poses.append(plant.true_state().pose)
            except Exception as exc:                  # noqa: BLE001 - reported below
                errors.append(exc)

        watcher = threading.Thread(target=watch)
        watcher.start()
        try:
            samples = _readings(plant, 300)
        finally:
            stop.set()
            watcher.join(10.0)
    assert not errors and len(poses) > 10 and not watcher.is_alive()
    here = Emulator(description, seed=2)
    try:
        assert _readings(here, 300) == samples         # the other thread's calls change nothing
    finally:
        here.close()
