"""The vehicle's CANopen network around a plant: 4 CiA 402 drives + 2 CiA 406 encoders, lock-step on SYNC
or in real time.

Node IDs (docs/conventions.md): 1…4 drives fl, rl, fr, rr; 5, 6 steering encoders left, right.

Lock-step (default; deterministic, faster than real time): on every SYNC frame, in the receive thread,

1. every node applies the RPDOs received since the last SYNC (controlword, target torque);
2. every drive latches its target torque → ``plant.set_motor_torques(per_mille · 0x6076 / 10⁶)`` [N m
   motor side, 0 unless OPERATION ENABLED];
3. ``plant.read_sensors()`` is sampled: the state at the SYNC instant (torque actual = torque applied
   from now on);
4. every node sends its synchronous TPDOs;
5. ``plant.step(cycle_time)`` advances the physics by one cycle. A plant that steps in the background
   (``steps_in_background``, :class:`qomni.hil.device.plant_process.PlantProcess`) is told to step right
   after step 3, so that its physics runs while the TPDOs go out; the plant sees the same calls in the
   same order.

The physics advances only on SYNC, so N SYNCs are exactly N·T_s of plant time, whatever the wall clock.

Real time (``realtime=True``, for an external master with its own clock): the plant advances by T_s
per T_s of wall time since :meth:`VehicleServer.start` (tick k is due at t₀ + k·T_s), whether SYNCs
come or not. A SYNC runs steps 1–4 and then the physics ticks that are due, so that the next SYNC
finds the physics idle; a pacing thread runs the due ticks when SYNCs are missing. A tick run more
than one cycle after it was due is counted in :attr:`TimingStats.physics_late`. Ticks are due on the
monotonic clock (absolute deadlines, no drift). While a real-time server runs, Python's thread switch
interval is lowered to 0.2 ms (a waiting receive thread otherwise waits up to 5 ms for the GIL) and the
garbage collector is kept off the cycle (:class:`qomni.hil.device.realtime.QuietCollector`: the heap
frozen, young objects collected only right after a SYNC has been answered).

Timing statistics (:attr:`VehicleServer.stats`): per SYNC, the latency from the SYNC frame's timestamp
(python-can ``Message.timestamp``, the bus's receive time) to the moment the last TPDO of that SYNC was
handed to the bus; a cycle is late if that latency exceeds ``deadline`` (default T_s/2).
A watchdog thread supervises SYNC/RPDO reception (see ``qomni.hil.device.node301``); a drive that loses its master
reacts per 0x6007 and its torque is set to 0 at once.

The plant is anything that fills the contract :class:`qomni.hil.device.plant.Plant` (drive data,
``set_motor_torques``, ``step``, ``read_sensors``); this module does not import the emulator.
"""
from __future__ import annotations

import logging
import sys
import threading
import time
from array import array
from pathlib import Path

import can
import canopen
import numpy as np

from ..bus import batched, open_bus
from ..virtual_bus import attach_inline
from ..cia import EMCY_BUS_OFF
from .drive402 import Drive402
from .encoder406 import Encoder406
from .faults import FaultInjector, FaultPlan, FaultyBus
from ..layout import DRIVE_EDS, DRIVE_NODE_IDS, ENCODER_EDS, ENCODER_NODE_IDS, SIDES, SYNC_COB_ID, WHEELS
from .plant import Plant
from .realtime import QuietCollector, sleep_until

logger = logging.getLogger(__name__)


#: Python thread switch interval [s] while a real-time server runs.
REALTIME_SWITCH_INTERVAL = 0.0002
#: Real time: a physics more than this many ticks behind the wall clock skips ahead.
RESYNC_TICKS = 50
#: Bins of the latency histogram, from 0 to 2·T_s (50 µs wide at T_s = 2 ms).
HISTOGRAM_BINS = 80


class TimingStats:
    """Latency of the emulator's answers to SYNC, and late cycles.

    Args:
        cycle_time: s, T_s.
        deadline: s, a SYNC whose last TPDO leaves later than this is a late cycle.
    Attributes:
        latencies: s per processed SYNC (``array('d')``).
        late: SYNCs answered after ``deadline``.
        physics_late: real-time physics ticks started more than one cycle behind the wall clock.
    """

    def __init__(self, cycle_time: float, deadline: float):
        self.cycle_time = cycle_time
        self.deadline = deadline
        self.latencies = array("d")
        self.late = 0
        self.physics_late = 0
        self.physics_ticks = 0

    def record(self, latency: float) -> None:
        """Add one SYNC's latency [s]."""
        self.latencies.append(latency)
        if latency > self.deadline:
            self.late += 1

    def histogram(self, bins: int = HISTOGRAM_BINS) -> dict:
        """Latency histogram: {'edges' (s, bins + 1 edges from 0 to 2·T_s), 'counts' (bins), 'above' (SYNCs
        answered later than 2·T_s)}."""
        edges = np.linspace(0.0, 2 * self.cycle_time, bins + 1)
        lat = np.frombuffer(self.latencies, dtype=float)
        counts, _ = np.histogram(lat, edges)
        return {"edges": edges.tolist(), "counts": counts.tolist(), "above": int(np.sum(lat > edges[-1]))}

    def summary(self) -> dict:
        """{'cycles', 'latency_median', 'latency_p99', 'latency_max' (s), 'late', 'late_fraction',
        'deadline' (s), 'physics_ticks', 'physics_late', 'histogram' (:meth:`histogram`)}; latencies are
        None before the first SYNC."""
        n = len(self.latencies)
        out = {"cycles": n, "deadline": self.deadline, "late": self.late,
               "late_fraction": self.late / n if n else 0.0, "physics_ticks": self.physics_ticks,
               "physics_late": self.physics_late, "histogram": self.histogram()}
        if n:
            lat = np.frombuffer(self.latencies, dtype=float)
            out.update(latency_median=float(np.median(lat)), latency_p99=float(np.percentile(lat, 99)),
                       latency_max=float(lat.max()))
        else:
            out.update(latency_median=None, latency_p99=None, latency_max=None)
        return out

    def report(self) -> str:
        """One human-readable paragraph of :meth:`summary` (µs)."""
        s = self.summary()
        if not s["cycles"]:
            return "no SYNC received"
        text = (f"{s['cycles']} SYNCs; SYNC-to-last-TPDO latency median {s['latency_median'] * 1e6:.0f} µs, "
                f"p99 {s['latency_p99'] * 1e6:.0f} µs, max {s['latency_max'] * 1e6:.0f} µs; late cycles "
                f"(> {s['deadline'] * 1e6:.0f} µs) {s['late']} ({100 * s['late_fraction']:.2f} %)")
        if s["physics_ticks"]:
            text += (f"; physics ticks {s['physics_ticks']}, more than a cycle late {s['physics_late']} "
                     f"({100 * s['physics_late'] / s['physics_ticks']:.2f} %)")
        return text


class DeviceListener(can.Listener):
    """What reaches the devices from the bus: 11-bit data frames only. The pre-defined connection set of
    CiA 301 (§7.3.3) is 11-bit, so a 29-bit frame with the same number (a 29-bit 0x80, 0x601) is another
    message, not a SYNC or an SDO request; remote (RTR) requests are answered by no object of these
    devices (CiA 301 advises against RTR). canopen's own listener passes every frame on by its number."""

    def __init__(self, network: canopen.Network, after_command=None):
        self.network = network
        self.after_command = after_command
        #: Frames whose handling raised inside a node (a defect of this emulator, logged with the frame).
        self.internal_errors = 0

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        self.on_frame(msg.arbitration_id, msg.data, msg.timestamp)

    def on_frame(self, can_id: int, data, timestamp: float) -> None:
        """An 11-bit data frame, given as its values (the in-process bus's frame lane)."""
        try:
            self.network.notify(can_id, data, timestamp)
        except Exception:                                 # noqa: BLE001 - one frame must not silence the bus
            # An exception here would end the notifier thread, and with it every node's reception: a
            # real drive that cannot handle a frame drops it and keeps serving the others.
            self.internal_errors += 1
            logger.exception("frame 0x%03X %s raised inside a node; dropped", can_id, bytes(data).hex())
        if self.after_command is not None and (can_id == 0 or 0x600 < can_id < 0x680):
            self.after_command()                   # NMT command or SDO request: may have disabled a drive


class VehicleServer:
    """Hosts a plant on a CAN bus as the vehicle's CANopen devices.

    Args:
        plant: the physics (:class:`qomni.hil.device.plant.Plant`).
        bus: a python-can bus (left open on :meth:`stop`) or a bus spec string for
            :func:`qomni.hil.bus.open_bus` (closed on :meth:`stop`).
        drive_eds, encoder_eds: EDS files of the devices (default: ``hil/eds``); a file with another
            PDO mapping changes what the nodes send.
        sync_timeout: s, SYNC loss time of the nodes (at least 5·0x1006); ``None`` disables it.
        watchdog_period: s, how often SYNC/RPDO reception is checked.
        realtime: physics paced by the wall clock instead of one step per SYNC (module docstring).
        deadline: s, latency above which a SYNC counts as late (default T_s/2).
        faults: a :class:`qomni.hil.device.faults.FaultPlan` injected on the emulator's side of the bus.
    Attributes:
        drives: the four :class:`~qomni.hil.device.drive402.Drive402` (fl, rl, fr, rr).
        encoders: the two :class:`~qomni.hil.device.encoder406.Encoder406` (left, right).
        cycles: number of SYNCs processed (= plant steps in lock-step).
        stats: :class:`TimingStats`.
        injector: the :class:`qomni.hil.device.faults.FaultInjector` (``faults`` given), else None.
        error: the exception that stopped SYNC processing, if any (the plant raised); later SYNCs
            are ignored, so the master times out.
    Raises:
        AttributeError: the plant lacks ``description.drive`` data.
    """

    def __init__(self, plant: Plant, bus: can.BusABC | str = "virtual", *,
                 drive_eds: str | Path = DRIVE_EDS, encoder_eds: str | Path = ENCODER_EDS,
                 sync_timeout: float | None = 0.1, watchdog_period: float = 0.02,
                 realtime: bool = False, deadline: float | None = None, faults: FaultPlan | None = None):
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
        self.realtime = bool(realtime)
        self.stats = TimingStats(self.cycle_time, self.cycle_time / 2 if deadline is None else deadline)
        self.faults = faults
        self.injector: FaultInjector | None = None
        self._physics: threading.Thread | None = None
        self.error: BaseException | None = None
        self.network: canopen.Network | None = None
        self.listener: DeviceListener | None = None
        self._watchdog_period = watchdog_period
        self._stop_event = threading.Event()
        self._watchdog: threading.Thread | None = None
        self._torque = np.zeros(4)
        self._background_physics = bool(getattr(plant, "steps_in_background", False))
        self._collector = QuietCollector()

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
        if self.faults is not None:
            self.injector = FaultInjector(self.faults, lambda: self.cycles * self.cycle_time)
            self.injector.on_power_off = self._power_off
            self.injector.on_power_on = self._power_on
            self.injector.on_bus_off_recovered = self._bus_off_recovered
            bus = FaultyBus(bus, self.injector, own_bus=self._own_bus)
        network = canopen.Network(bus)
        self.listener = DeviceListener(network, self._follow_drive_torques)
        network.listeners = [self.listener]
        network.NOTIFIER_CYCLE = 0.05      # short receive timeout: stop() returns quickly
        for node in self.nodes:
            network.add_node(node)
        network.subscribe(SYNC_COB_ID, self._on_sync)
        self.network = network
        network.connect()
        attach_inline(network)          # an in-process virtual bus: SYNC answered in the sender's thread
        for node in self.nodes:
            node.boot()
        self._stop_event.clear()
        self._watchdog = threading.Thread(target=self._watch, name="hil-server-watchdog", daemon=True)
        self._watchdog.start()
        if self.realtime:
            self._switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(REALTIME_SWITCH_INTERVAL)
            self._collector.start()
            self._t0 = time.monotonic()
            self._physics = threading.Thread(target=self._pace_physics, name="hil-server-physics",
                                             daemon=True)
            self._physics.start()
        return self

    def stop(self) -> None:
        """Power the nodes off and detach from the bus; idempotent. Closes the bus only if opened here."""
        network, self.network = self.network, None
        if network is None:
            return
        self._stop_event.set()
        if self._watchdog is not None:
            self._watchdog.join()
        if self._physics is not None:
            self._physics.join()
            self._physics = None
            sys.setswitchinterval(self._switch_interval)
            self._collector.stop()
        for node in self.nodes:
            node.shutdown()
        if network.notifier is not None:
            network.notifier.stop(1.0)
        for node_id in list(network):
            del network[node_id]
        if self._own_bus or self.injector is not None:
            network.bus.shutdown()                 # a FaultyBus closes the real bus only if owned

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
                latency = self._sync() - timestamp
                if not 0.0 <= latency < 10.0:      # interface without usable receive timestamps
                    latency = 0.0
                self.stats.record(latency)
            if self.injector is not None:
                self.injector.poll()
            self._collector.after_cycle()
        except Exception as exc:          # noqa: BLE001 - canopen would swallow it silently
            self.error = exc
            logger.exception("SYNC processing failed; the server ignores further SYNCs")

    def _sync(self) -> float:
        """Steps 1–5 of the module docstring; returns the time (time.time()) the last TPDO was handed over."""
        now = time.monotonic()
        for node in self.nodes:
            node.sync_receive(now)
        torque = self._torque
        for i, drive in enumerate(self.drives):
            drive.latch_torque()
            torque[i] = drive.applied_torque_nm
        self.plant.set_motor_torques(torque.copy())
        reading = self.plant.read_sensors()
        step_now = not self.realtime and self._background_physics
        if step_now:                               # the physics runs while the TPDOs go out
            self.plant.step(self.cycle_time)
        position = reading.motor_position.tolist()
        velocity = reading.motor_velocity.tolist()
        measured = reading.motor_torque.tolist()
        for i, drive in enumerate(self.drives):
            drive.set_actuals(int(position[i]), int(velocity[i]), float(measured[i]))
        steering = reading.steering_position.tolist()
        for j, encoder in enumerate(self.encoders):
            encoder.set_position(int(steering[j]))
        with batched(self.network.bus):            # the SYNC's TPDOs in one write where the bus can
            for node in self.nodes:
                node.sync_transmit()
        sent = time.time()
        self.cycles += 1
        if self.realtime:
            self._run_due_ticks()
        elif not step_now:
            self.plant.step(self.cycle_time)
        return sent

    def _run_due_ticks(self) -> None:
        """Real time (lock held): step the plant once per tick that is due by the wall clock."""
        period, stats = self.cycle_time, self.stats
        elapsed = time.monotonic() - self._t0
        due = int(elapsed / period) - stats.physics_ticks
        if due > RESYNC_TICKS:                     # hopelessly behind (machine suspended): skip ahead
            logger.warning("real-time physics %d cycles behind the wall clock; skipping ahead", due)
            stats.physics_late += due
            stats.physics_ticks += due - 1
            due = 1
        for _ in range(max(0, due)):
            if elapsed - stats.physics_ticks * period > 2 * period:   # tick k due at k·T_s, run > T_s late
                stats.physics_late += 1
            self.plant.step(period)
            stats.physics_ticks += 1

    def _pace_physics(self) -> None:
        """Real time: run the due physics ticks when no SYNC did (the master is silent or slow)."""
        period = self.cycle_time
        while not self._stop_event.is_set():
            elapsed = time.monotonic() - self._t0
            sleep_until(self._t0 + (int(elapsed / period) + 1.5) * period)   # mid-way between ticks
            with self._lock:
                if self.error is not None:
                    return
                try:
                    self._run_due_ticks()
                except Exception as exc:           # noqa: BLE001
                    self.error = exc
                    logger.exception("plant.step failed in real-time mode; physics stopped")
                    return

    # ------------------------------------------------------------ faults
    def _node(self, node_id: int):
        for node in self.nodes:
            if node.id == node_id:
                return node
        logger.warning("fault plan names node %d, which this vehicle does not have", node_id)
        return None

    def _power_off(self, node_id: int) -> None:
        node = self._node(node_id)
        if node is not None:
            with self._lock:
                node.power_off()
                self._apply_drive_torques()

    def _power_on(self, node_id: int) -> None:
        node = self._node(node_id)
        if node is not None:
            node.power_on()

    def _bus_off_recovered(self) -> None:
        with self._lock:
            for node in self.nodes:
                if node.powered:
                    node.emcy_send(EMCY_BUS_OFF)

    def _apply_drive_torques(self) -> None:
        """Hand the drives' applied torques to the plant now (outside a SYNC)."""
        if self.error is not None:
            return
        for i, drive in enumerate(self.drives):
            self._torque[i] = drive.applied_torque_nm
        try:
            self.plant.set_motor_torques(self._torque.copy())
        except Exception as exc:      # noqa: BLE001
            self.error = exc
            logger.exception("plant.set_motor_torques failed outside a SYNC")

    def _follow_drive_torques(self) -> None:
        """After an NMT command or SDO request: a drive it disabled stops its torque now (the watchdog
        would within ``watchdog_period``)."""
        with self._lock:
            if any(d.applied_torque_nm != self._torque[i] for i, d in enumerate(self.drives)):
                self._apply_drive_torques()

    def _watch(self) -> None:
        while not self._stop_event.wait(self._watchdog_period):
            now = time.monotonic()
            with self._lock:
                tripped = [node.check_timeouts(now) for node in self.nodes]
                # A drive disabled between SYNCs (by SDO, NMT, a fault) stops its torque at once, not at a
                # next SYNC that may never come.
                changed = any(d.applied_torque_nm != self._torque[i] for i, d in enumerate(self.drives))
                if any(tripped[:len(self.drives)]) or changed:
                    self._apply_drive_torques()
            if self.injector is not None:
                self.injector.poll()
