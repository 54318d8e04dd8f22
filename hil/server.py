"""The vehicle's CANopen network around a plant: 4 CiA 402 drives + 2 CiA 406 encoders, lock-step on SYNC.

Node IDs (docs/conventions.md): 1…4 drives fl, rl, fr, rr; 5, 6 steering encoders left, right.

Lock-step (deterministic, faster than real time): on every SYNC frame, in the receive thread,

1. every node applies the RPDOs received since the last SYNC (controlword, target torque);
2. every drive latches its target torque → ``plant.set_motor_torques(per_mille · 0x6076 / 10⁶)`` [N m
   motor side, 0 unless OPERATION ENABLED];
3. ``plant.read_sensors()`` is sampled: the state at the SYNC instant (torque actual = torque applied
   from now on);
4. every node sends its synchronous TPDOs;
5. ``plant.step(cycle_time)`` advances the physics by one cycle.

The physics advances only on SYNC, so N SYNCs are exactly N·T_s of plant time, whatever the wall clock.
A watchdog thread supervises SYNC/RPDO reception (see ``hil.node301``); a drive that loses its master
reacts per 0x6007 and its torque is set to 0 at once.

The plant is duck-typed (this module does not import ``emulator``)::

    plant.description.drive  # .i_G, .rated_torque [N m], .max_torque [N m], .encoder_increments,
                             # .steering_sensor_bits, .cycle_time [s]
    plant.set_motor_torques(np.ndarray (4,))   # N m motor side, fl rl fr rr
    plant.step(duration: float)
    plant.read_sensors()     # .time, .motor_position (4,) incr, .motor_velocity (4,) incr/s,
                             # .motor_torque (4,) N m, .steering_position (2,) counts
"""
from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import can
import canopen
import numpy as np

from .bus import open_bus
from .drive402 import Drive402
from .encoder406 import Encoder406
from .layout import DRIVE_EDS, DRIVE_NODE_IDS, ENCODER_EDS, ENCODER_NODE_IDS, SIDES, SYNC_COB_ID, WHEELS

logger = logging.getLogger(__name__)


class VehicleServer:
    """Hosts a plant on a CAN bus as the vehicle's CANopen devices.

    Args:
        plant: the duck-typed plant (module docstring).
        bus: a python-can bus (left open on :meth:`stop`) or a bus spec string for
            :func:`hil.bus.open_bus` (closed on :meth:`stop`).
        drive_eds, encoder_eds: EDS files of the devices (default: ``hil/eds``); a file with another
            PDO mapping changes what the nodes send.
        sync_timeout: s, SYNC loss time of the nodes (at least 5·0x1006); ``None`` disables it.
        watchdog_period: s, how often SYNC/RPDO reception is checked.
    Attributes:
        drives: the four :class:`~hil.drive402.Drive402` (fl, rl, fr, rr).
        encoders: the two :class:`~hil.encoder406.Encoder406` (left, right).
        cycles: number of SYNCs processed (= plant steps).
        error: the exception that stopped SYNC processing, if any (the plant raised); later SYNCs
            are ignored, so the master times out.
    Raises:
        AttributeError: the plant lacks ``description.drive`` data.
    """

    def __init__(self, plant, bus: can.BusABC | str = "virtual", *,
                 drive_eds: str | Path = DRIVE_EDS, encoder_eds: str | Path = ENCODER_EDS,
                 sync_timeout: float | None = 0.1, watchdog_period: float = 0.02):
        self.plant = plant
        data = plant.description.drive
        self.cycle_time = float(data.cycle_time)
        self._rated_mnm = int(round(data.rated_torque * 1000))
        self._max_per_mille = int(round(data.max_torque / data.rated_torque * 1000))
        self._sensor_bits = int(data.steering_sensor_bits)
        self._bus_arg = bus
        self._own_bus = isinstance(bus, str)
        self._lock = threading.RLock()
        self.drives = tuple(Drive402(i, drive_eds, lock=self._lock, sync_timeout=sync_timeout, name=w)
                            for i, w in zip(DRIVE_NODE_IDS, WHEELS))
        self.encoders = tuple(Encoder406(i, encoder_eds, lock=self._lock, sync_timeout=sync_timeout,
                                         name=s) for i, s in zip(ENCODER_NODE_IDS, SIDES))
        self.nodes = self.drives + self.encoders
        for d in self.drives:
            d.set_default(0x6076, 0, self._rated_mnm)
            d.set_default(0x6072, 0, self._max_per_mille)
        for n in self.nodes:
            if (0x1006, 0) in n.values:
                n.set_default(0x1006, 0, int(round(self.cycle_time * 1e6)))
        for e in self.encoders:
            e.set_resolution(self._sensor_bits)
        self.cycles = 0
        self.error: BaseException | None = None
        self.network: canopen.Network | None = None
        self._watchdog_period = watchdog_period
        self._stop_event = threading.Event()
        self._watchdog: threading.Thread | None = None
        self._torque = np.zeros(4)

    # --------------------------------------------------------- lifecycle
    def start(self) -> "VehicleServer":
        """Attach the nodes to the bus and power them on (boot-up, PRE-OPERATIONAL, heartbeat).

        Raises:
            RuntimeError: already started.
            ValueError, can.CanError: the bus spec is bad or the bus cannot be opened.
        """
        if self.network is not None:
            raise RuntimeError("server already started")
        bus = open_bus(self._bus_arg) if self._own_bus else self._bus_arg
        network = canopen.Network(bus)
        network.NOTIFIER_CYCLE = 0.05      # short receive timeout: stop() returns quickly
        for node in self.nodes:
            network.add_node(node)
        network.subscribe(SYNC_COB_ID, self._on_sync)
        self.network = network
        network.connect()
        for node in self.nodes:
            node.boot()
        self._stop_event.clear()
        self._watchdog = threading.Thread(target=self._watch, name="hil-server-watchdog", daemon=True)
        self._watchdog.start()
        return self

    def stop(self) -> None:
        """Power the nodes off and detach from the bus; idempotent. Closes the bus only if opened here."""
        network, self.network = self.network, None
        if network is None:
            return
        self._stop_event.set()
        if self._watchdog is not None:
            self._watchdog.join()
        for node in self.nodes:
            node.shutdown()
        if network.notifier is not None:
            network.notifier.stop(1.0)
        for node_id in list(network):
            del network[node_id]
        if self._own_bus:
            network.bus.shutdown()

    def __enter__(self) -> "VehicleServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -------------------------------------------------------- lock-step
    def _on_sync(self, can_id: int, data, timestamp: float) -> None:
        if len(data) > 1:
            for node in self.nodes:
                node.sync_length_error()
            return
        if self.error is not None:
            return
        try:
            with self._lock:
                self._sync()
        except Exception as exc:          # noqa: BLE001 - canopen would swallow it silently
            self.error = exc
            logger.exception("SYNC processing failed; the server ignores further SYNCs")

    def _sync(self) -> None:
        now = time.monotonic()
        for node in self.nodes:
            node.sync_receive(now)
        torque = self._torque
        for i, drive in enumerate(self.drives):
            drive.latch_torque()
            torque[i] = drive.applied_torque_nm
        self.plant.set_motor_torques(torque.copy())
        reading = self.plant.read_sensors()
        position = reading.motor_position.tolist()
        velocity = reading.motor_velocity.tolist()
        measured = reading.motor_torque.tolist()
        for i, drive in enumerate(self.drives):
            drive.set_actuals(int(position[i]), int(velocity[i]), float(measured[i]))
        steering = reading.steering_position.tolist()
        for j, encoder in enumerate(self.encoders):
            encoder.set_position(int(steering[j]))
        for node in self.nodes:
            node.sync_transmit()
        self.plant.step(self.cycle_time)
        self.cycles += 1

    def _watch(self) -> None:
        while not self._stop_event.wait(self._watchdog_period):
            now = time.monotonic()
            with self._lock:
                tripped = [node.check_timeouts(now) for node in self.nodes]
                if any(tripped[:len(self.drives)]) and self.error is None:
                    for i, drive in enumerate(self.drives):
                        self._torque[i] = drive.applied_torque_nm
                    try:
                        self.plant.set_motor_torques(self._torque.copy())
                    except Exception as exc:      # noqa: BLE001
                        self.error = exc
                        logger.exception("plant.set_motor_torques failed in the watchdog")
