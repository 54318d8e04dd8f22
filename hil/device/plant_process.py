"""A plant in a process of its own, so that a lock-step cycle's physics overlaps the bus side's work.

PyBullet holds the GIL through ``stepSimulation``, so a thread cannot overlap the physics with the CANopen
stack and the master. :class:`PlantProcess` runs the plant (any object filling
:class:`qomni.hil.device.plant.Plant`, built by a picklable factory) in a child process and keeps the
server's three hot calls off any pipe:

* ``set_motor_torques(u)`` is stored on the calling side and travels with the next command;
* ``step(duration)`` is posted and returns at once: the child steps while the server sends the SYNC's
  TPDOs, the master decodes them, computes and sends the next RPDOs and SYNC;
* ``read_sensors()`` waits for the step in flight, then for the child's sample.

Commands and samples go through a shared block (``multiprocessing.RawArray``); a POSIX semaphore each way
says "posted" and "done". The waiting side first polls the semaphore for ``spin`` seconds (no system
call, no wake-up latency: worth a core on a many-core machine), then blocks on it. Every other attribute
and method (``time``, ``true_state()``, ``close()`` …) is a synchronous call over a pipe, after the step
in flight. Calls from several threads are served one at a time.

The child makes exactly the calls, in exactly the order, that the server makes on an in-process plant,
so a seeded lock-step run is bit-identical either way (``tests/test_plant_process.py`` against
``tests/data/lockstep_trace.npz``). One difference: consecutive ``set_motor_torques`` calls without a
step or read between them reach the child as the last one, which is the same for a plant whose
``set_motor_torques`` only stores the command (the contract: "until the next call"). An exception in the
child's ``step`` is raised by the next call that waits for it (in lock-step: the next SYNC's
``read_sensors``, before that SYNC's TPDOs, as in-process where it ends the SYNC after them).
"""
from __future__ import annotations

import multiprocessing
import os
import threading
from typing import Any, Callable

import numpy as np

from ..busy_poll import poll_first

#: Command codes in the shared command block.
_STEP, _READ, _CALL, _CLOSE = 1, 2, 3, 4
#: Layout of the shared block, float64 slots: command [code, duration, has_torque, u0..u3],
#: status [error flag], sample [time, torque0..3], then int64 slots: position 0..3, velocity 0..3, steering 0..1.
_CMD, _STATUS, _SAMPLE_F, _SAMPLE_I = slice(0, 7), 7, slice(8, 13), slice(13, 23)
_SLOTS = 23
#: s a blocked side waits before it checks that the other side is still alive.
_ALIVE_CHECK = 1.0


class PlantProcessError(RuntimeError):
    """The plant's process died, failed to start, or stopped answering."""


def default_spin() -> float:
    """Seconds each side polls before blocking: 2 ms where the process may use 4 CPUs or more (the poll
    costs a core, the block a wake-up of tens of µs), else 0 (on 1–3 CPUs polling steals the other side's)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:                      # not Linux
        cpus = os.cpu_count() or 1
    return 0.002 if cpus >= 4 else 0.0


def _wait(sem, spin: float, alive: Callable[[], bool], who: str) -> None:
    """Acquire ``sem``: poll it for ``spin`` s, then block (:func:`qomni.hil.busy_poll.poll_first`),
    checking ``alive()`` every _ALIVE_CHECK s."""
    if poll_first(lambda timeout: sem.acquire(timeout > 0.0, timeout), _ALIVE_CHECK, spin, bool):
        return
    while not sem.acquire(True, _ALIVE_CHECK):
        if not alive():
            raise PlantProcessError(f"{who} is gone")


class _SampleReading:
    """A sensor sample (the fields of :class:`qomni.hil.device.plant.SensorReading`), copied out of the
    shared block."""

    __slots__ = ("time", "motor_position", "motor_velocity", "motor_torque", "steering_position")

    def __init__(self, f: np.ndarray, i: np.ndarray):
        self.time = float(f[0])
        self.motor_torque = f[1:5].copy()
        self.motor_position = i[0:4].copy()
        self.motor_velocity = i[4:8].copy()
        self.steering_position = i[8:10].copy()


def _views(block) -> tuple[np.ndarray, np.ndarray]:
    """The shared block as float64 and as int64 slots (the same memory)."""
    return np.frombuffer(block, dtype=np.float64), np.frombuffer(block, dtype=np.int64)


def _child(factory, block, posted, done, conn, spin: float) -> None:
    """The plant's process: build the plant, then run posted commands until _CLOSE or the parent is gone."""
    f, i = _views(block)
    parent = multiprocessing.parent_process()
    try:
        plant = factory()
    except BaseException as exc:                # noqa: BLE001 - reported to the parent, which raises it
        conn.send(("error", exc))
        return
    conn.send(("ready", None))
    cmd = f[_CMD]
    while True:
        try:
            _wait(posted, spin, parent.is_alive, "the parent process")
        except PlantProcessError:
            break
        code = int(cmd[0])
        try:
            if cmd[2]:
                plant.set_motor_torques(cmd[3:7].copy())
            if code == _STEP:
                plant.step(float(cmd[1]))
            elif code == _READ:
                r = plant.read_sensors()
                f[_SAMPLE_F] = (r.time, *np.asarray(r.motor_torque, dtype=np.float64))
                i[_SAMPLE_I] = (*np.asarray(r.motor_position, dtype=np.int64),
                                *np.asarray(r.motor_velocity, dtype=np.int64),
                                *np.asarray(r.steering_position, dtype=np.int64))
            elif code == _CALL:
                kind, name, args, kwargs = conn.recv()
                value = getattr(plant, name)
                if kind == "get":
                    conn.send(("method", None) if callable(value) else ("value", value))
                else:
                    conn.send(("value", value(*args, **kwargs)))
            elif code == _CLOSE:
                close = getattr(plant, "close", None)
                if close is not None:
                    close()
                f[_STATUS] = 0.0
                done.release()
                break
            f[_STATUS] = 0.0
        except BaseException as exc:            # noqa: BLE001 - raised on the parent's side
            f[_STATUS] = 1.0
            try:
                conn.send(("error", exc))
            except Exception:                   # noqa: BLE001 - unpicklable: send its text
                conn.send(("error", RuntimeError(f"{type(exc).__name__}: {exc}")))
        done.release()


class PlantProcess:
    """A plant (:class:`qomni.hil.device.plant.Plant`) run in a child process (module docstring).

    ``steps_in_background`` tells :class:`qomni.hil.device.server.VehicleServer` that ``step`` returns at
    once, so that it posts the step before it sends the SYNC's TPDOs.

    Args:
        factory: picklable callable that builds the plant in the child, e.g.
            ``functools.partial(Emulator, description, seed=0)``.
        spin: s each side polls before it blocks (default :func:`default_spin`).
        start_timeout: s to wait for the plant to be built.

    Raises:
        PlantProcessError: the child cannot be started, or died.
        Exception: whatever the factory raised in the child.
    """

    steps_in_background = True

    def __init__(self, factory: Callable[[], Any], *, spin: float | None = None,
                 start_timeout: float = 120.0):
        self._spin = default_spin() if spin is None else float(spin)
        ctx = multiprocessing.get_context("spawn")    # the parent has threads: no fork
        self._block = ctx.RawArray("d", _SLOTS)        # zeroed; shared with the child by inheritance
        self._f, self._i = _views(self._block)
        self._cmd = self._f[_CMD]
        self._posted, self._done = ctx.Semaphore(0), ctx.Semaphore(0)
        self._conn, child_conn = ctx.Pipe()
        self._lock = threading.Lock()            # one caller at a time: the protocol has one slot
        self._torque = np.zeros(4)
        self._has_torque = False
        self._busy = False
        self._closed = False
        self._process = ctx.Process(target=_child, name="qomni-plant", daemon=True,
                                    args=(factory, self._block, self._posted, self._done, child_conn,
                                          self._spin))
        try:
            self._process.start()
            child_conn.close()
            if not self._conn.poll(start_timeout):
                raise PlantProcessError(f"the plant's process did not start within {start_timeout:g} s")
            try:
                kind, payload = self._conn.recv()
            except EOFError:
                self._process.join(5.0)
                raise PlantProcessError(f"the plant's process ended while starting (exit code "
                                        f"{self._process.exitcode}; a script that starts it needs "
                                        f"`if __name__ == '__main__':`)") from None
            if kind == "error":
                raise payload
            self.description = self._call("get", "description")
        except BaseException:
            self._teardown()
            raise

    # -- hot path ----------------------------------------------------------------------------
    def set_motor_torques(self, motor_torque) -> None:
        """Store (4,) motor torques [N m, motor side] for the next command.

        Raises:
            ValueError: wrong shape or a non-finite value (checked here, as the plant would).
        """
        u = np.asarray(motor_torque, dtype=float)
        if u.shape != (4,) or not np.isfinite(u).all():
            raise ValueError(f"motor_torque must be 4 finite values, got {motor_torque!r}")
        with self._lock:
            self._torque[:] = u
            self._has_torque = True

    def step(self, duration: float) -> None:
        """Post a step of ``duration`` s and return; the next call waits for it."""
        with self._lock:
            self._post(_STEP, duration)

    def read_sensors(self):
        """The plant's sample now (after the step in flight), as a reading with the
        :class:`~qomni.hil.device.plant.SensorReading` fields."""
        with self._lock:
            self._post(_READ)
            self._wait_done()
            return _SampleReading(self._f[_SAMPLE_F], self._i[_SAMPLE_I])

    # -- everything else ---------------------------------------------------------------------
    def __getattr__(self, name: str):
        if name.startswith("_") or name == "description":
            raise AttributeError(name)
        kind = self._call("get", name)
        if kind is _METHOD:
            return lambda *args, **kwargs: self._call("call", name, args, kwargs)
        return kind

    def close(self) -> None:
        """Close the plant (its ``close()`` if it has one) and end its process."""
        with self._lock:
            if self._closed:
                return
            try:
                if self._process.is_alive():
                    self._post(_CLOSE)
                    self._wait_done()
            except Exception:                   # noqa: BLE001 - closing anyway
                pass
            finally:
                self._teardown()

    def __enter__(self) -> "PlantProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- plumbing ----------------------------------------------------------------------------
    def _post(self, code: int, duration: float = 0.0) -> None:
        if self._closed:
            raise PlantProcessError("the plant's process is closed")
        self._wait_done()
        cmd = self._cmd
        cmd[0] = code
        cmd[1] = duration
        if self._has_torque:
            cmd[2] = 1.0
            cmd[3:7] = self._torque
            self._has_torque = False
        else:
            cmd[2] = 0.0
        self._busy = True
        self._posted.release()

    def _wait_done(self) -> None:
        if not self._busy:
            return
        _wait(self._done, self._spin, self._process.is_alive, "the plant's process")
        self._busy = False
        if self._f[_STATUS]:
            self._f[_STATUS] = 0.0
            _, exc = self._conn.recv()
            raise exc

    def _call(self, kind: str, name: str, args: tuple = (), kwargs: dict | None = None):
        with self._lock:
            self._post(_CALL)
            self._conn.send((kind, name, args, kwargs or {}))
            self._wait_done()
            answer, value = self._conn.recv()
        return _METHOD if answer == "method" else value

    def _teardown(self) -> None:
        self._closed = True
        process = getattr(self, "_process", None)
        if process is not None and process.pid is not None:
            process.join(5.0)
            if process.is_alive():
                process.kill()
                process.join(5.0)
        self._conn.close()
        self._cmd = self._f = self._i = None


_METHOD = object()
