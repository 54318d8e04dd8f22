"""Fault injection for the emulated vehicle: what goes wrong on a real CAN bus, configurable per run.

A fault plan (TOML, :meth:`FaultPlan.load`) lists the faults; :class:`FaultyBus` applies them to the
emulator's side of the bus as a python-can :class:`can.BusABC` wrapper around the real bus, and
:class:`qomni.hil.device.server.VehicleServer` (``faults=``) runs the node-level ones (power cycling). Example::

    seed = 1                       # random generator of loss and jitter

    [frame_loss]                   # Gilbert-Elliott: independent losses plus bursts
    start = 1.0                    # s of emulated time from which frames get lost (default 0)
    rate = 0.001                   # probability that a frame is lost (either direction)
    burst_rate = 0.0002            # probability per frame that a burst starts
    burst_length = 5               # frames lost in a row once a burst started

    [latency]                      # added to every frame the emulator sends
    mean = 0.0002                  # s
    jitter = 0.0001                # s, standard deviation (normal, cut at 0; order is kept)

    [[power_cycle]]                # a node loses power: silent, then boots (boot-up, PRE-OPERATIONAL)
    node = 3
    at = 4.0                       # s of emulated time (SYNC count x T_s)
    off = 0.3                      # s of wall time without power

    [[bus_off]]                    # the emulator's CAN controller goes bus-off: sends nor receives,
    at = 6.0                       # then recovers and its nodes send EMCY 0x8140
    duration = 0.2                 # s of wall time

    [[sync_loss]]                  # SYNC frames do not reach the nodes
    at = 8.0
    duration = 0.3                 # s of wall time

Times: ``at`` is emulated time (the SYNC count × T_s, the same in lock-step and real time, so a run
is reproducible); a duration is wall time, because in lock-step the emulated time stands still while
SYNCs are missing. Reactions are the devices' own (CiA 301/402): SYNC loss and RPDO timeouts fault the
drives per 0x6007, a power-cycled drive reboots into SWITCH ON DISABLED with its defaults, bus-off ends
with EMCY 0x8140 "recovered from bus-off".
"""
from __future__ import annotations

import heapq
import logging
import math
import random
import threading
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import can

logger = logging.getLogger(__name__)

_SYNC_COB_ID = 0x80


class FaultPlanError(ValueError):
    """A fault plan is invalid: the message names the file, table and key."""


#: s, the largest added latency (mean or jitter) a plan may give: ten times the drives' SYNC-loss time
#: (0.1 s); longer, a frame is lost to every supervision on the bus, which [frame_loss] models.
MAX_LATENCY = 1.0


@dataclass(frozen=True)
class FrameLoss:
    """Frame loss (Gilbert-Elliott): independent ``rate``, bursts of ``burst_length`` frames starting with
    probability ``burst_rate`` per frame; applies to frames in both directions from emulated time
    ``start`` [s] on."""

    rate: float = 0.0
    start: float = 0.0
    burst_rate: float = 0.0
    burst_length: int = 0


@dataclass(frozen=True)
class Latency:
    """Added send latency of the emulator's frames: normal(mean, jitter) [s], cut at 0, order kept."""

    mean: float = 0.0
    jitter: float = 0.0


@dataclass(frozen=True)
class Window:
    """A fault starting at emulated time ``at`` [s] and lasting ``duration`` [s wall]."""

    at: float
    duration: float


@dataclass(frozen=True)
class PowerCycle:
    """Node ``node`` without power from emulated time ``at`` [s] for ``off`` [s wall]."""

    node: int
    at: float
    off: float


@dataclass(frozen=True)
class FaultPlan:
    """Everything injected in one run (module docstring for the file format)."""

    seed: int = 0
    frame_loss: FrameLoss = FrameLoss()
    latency: Latency = Latency()
    power_cycle: tuple[PowerCycle, ...] = ()
    bus_off: tuple[Window, ...] = ()
    sync_loss: tuple[Window, ...] = ()
    source: str = field(default="(in memory)", compare=False)

    @classmethod
    def load(cls, path: str | Path) -> "FaultPlan":
        """Read a fault plan from a TOML file.

        Raises:
            FileNotFoundError: no such file.
            FaultPlanError: TOML syntax, an unknown table or key, a wrong type, or a value out of range
                (rates in [0, 1], times and durations ≥ 0, node ids 1…127), naming file, table and key.
        """
        path = Path(path)
        text = path.read_text()
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise FaultPlanError(f"{path}: not valid TOML: {exc}") from None
        return cls.from_dict(data, str(path))

    @classmethod
    def from_dict(cls, data: dict, source: str = "(in memory)") -> "FaultPlan":
        """A plan from the parsed TOML structure. Raises FaultPlanError like :meth:`load`."""
        known = {"seed", "frame_loss", "latency", "power_cycle", "bus_off", "sync_loss"}
        unknown = set(data) - known
        if unknown:
            raise FaultPlanError(f"{source}: unknown entries {sorted(unknown)}; known: {sorted(known)}")
        seed = data.get("seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool):
            raise FaultPlanError(f"{source}: seed must be an integer, got {seed!r}")
        loss = _table(data, "frame_loss", source, {"rate": float, "burst_rate": float, "burst_length": int,
                                                   "start": float})
        lat = _table(data, "latency", source, {"mean": float, "jitter": float})
        for key in ("rate", "burst_rate"):
            if not 0.0 <= loss.get(key, 0.0) <= 1.0:
                raise FaultPlanError(f"{source}: [frame_loss] {key} must be in [0, 1], got {loss[key]}")
        for key in ("mean", "jitter"):
            if lat.get(key, 0.0) > MAX_LATENCY:
                raise FaultPlanError(f"{source}: [latency] {key} must be ≤ {MAX_LATENCY} s, got {lat[key]}: a frame "
                                     "held longer is lost to every supervision on the bus; use [frame_loss]")
        for where, table in (("frame_loss", loss), ("latency", lat)):
            for key, value in table.items():
                if value < 0:
                    raise FaultPlanError(f"{source}: [{where}] {key} must be ≥ 0, got {value}")
        cycles = tuple(PowerCycle(**t) for t in _array(data, "power_cycle", source,
                                                          {"node": int, "at": float, "off": float}))
        for i, c in enumerate(cycles):
            if not 1 <= c.node <= 127:
                raise FaultPlanError(f"{source}: [[power_cycle]] #{i + 1} node must be 1…127, got {c.node}")
        windows = {name: tuple(Window(**t) for t in _array(data, name, source,
                                                            {"at": float, "duration": float}))
                   for name in ("bus_off", "sync_loss")}
        return cls(seed=seed, frame_loss=FrameLoss(**loss), latency=Latency(**lat), power_cycle=cycles,
                   source=source, **windows)


def _check_value(value, kind, where: str):
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or isinstance(value, bool):
        raise FaultPlanError(f"{where} must be {'a number' if kind is float else 'an integer'}, got {value!r}")
    if kind is float and not math.isfinite(value):
        raise FaultPlanError(f"{where} must be finite (a fault at nan never happens), got {value!r}")
    if value < 0:
        raise FaultPlanError(f"{where} must be ≥ 0, got {value}")
    return value


def _table(data: dict, name: str, source: str, keys: dict) -> dict:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise FaultPlanError(f"{source}: [{name}] must be a table")
    unknown = set(table) - set(keys)
    if unknown:
        raise FaultPlanError(f"{source}: [{name}] unknown keys {sorted(unknown)}; known: {sorted(keys)}")
    return {k: _check_value(v, keys[k], f"{source}: [{name}] {k}") for k, v in table.items()}


def _array(data: dict, name: str, source: str, keys: dict) -> list[dict]:
    items = data.get(name, [])
    if not isinstance(items, list):
        raise FaultPlanError(f"{source}: {name} must be an array of tables ([[{name}]])")
    out = []
    for i, item in enumerate(items, start=1):
        where = f"{source}: [[{name}]] #{i}"
        if not isinstance(item, dict):
            raise FaultPlanError(f"{where} must be a table")
        missing, unknown = set(keys) - set(item), set(item) - set(keys)
        if missing or unknown:
            raise FaultPlanError(f"{where}: needs exactly the keys {sorted(keys)} "
                                 f"(missing {sorted(missing)}, unknown {sorted(unknown)})")
        out.append({k: _check_value(v, keys[k], f"{where} {k}") for k, v in item.items()})
    return out


@dataclass
class FaultCounters:
    """What was injected so far."""

    lost_rx: int = 0
    lost_tx: int = 0
    sync_dropped: int = 0
    bus_off_dropped: int = 0
    delayed: int = 0
    power_cycles: int = 0
    bus_offs: int = 0
    sync_losses: int = 0


class FaultInjector:
    """Run-time state of a :class:`FaultPlan`: decides per frame, and fires the timed faults.

    Args:
        plan: the faults.
        clock: returns the emulated time [s] (the server's SYNC count × T_s).
    Attributes:
        counters: :class:`FaultCounters`.
        on_power_off, on_power_on: called with the node id when a power cycle starts / ends.
        on_bus_off_recovered: called when a bus-off ends.
    """

    def __init__(self, plan: FaultPlan, clock):
        self.plan = plan
        self.clock = clock
        self.counters = FaultCounters()
        self._rng = random.Random(plan.seed)
        self._lock = threading.Lock()
        self._burst_left = 0
        self._pending = sorted(
            [(c.at, "power", c) for c in plan.power_cycle] + [(w.at, "bus_off", w) for w in plan.bus_off]
            + [(w.at, "sync_loss", w) for w in plan.sync_loss], key=lambda e: e[0])
        self._active: list[tuple[float, str, object]] = []     # (wall end, kind, item)
        self._fired: list[tuple[str, object]] = []
        self.on_power_off = lambda node: None
        self.on_power_on = lambda node: None
        self.on_bus_off_recovered = lambda: None

    # ------------------------------------------------------------ frames
    def _lost(self) -> bool:
        loss = self.plan.frame_loss
        if not (loss.rate or loss.burst_rate) or (loss.start and self.clock() < loss.start):
            return False
        if self._burst_left > 0:
            self._burst_left -= 1
            return True
        if loss.burst_rate and self._rng.random() < loss.burst_rate:
            self._burst_left = max(0, loss.burst_length - 1)
            return True
        return bool(loss.rate) and self._rng.random() < loss.rate

    def _active_kind(self, kind: str) -> bool:
        return any(k == kind for _, k, _ in self._active)

    def drop_received(self, msg: can.Message) -> bool:
        """True if a frame coming from the bus must not reach the nodes."""
        return self._drop(msg, received=True)

    def drop_sent(self, msg: can.Message) -> bool:
        """True if a frame the nodes send must not reach the bus."""
        return self._drop(msg, received=False)

    def _drop(self, msg: can.Message, received: bool) -> bool:
        with self._lock:
            self._update()
            counters = self.counters
            if self._active_kind("bus_off"):
                counters.bus_off_dropped += 1
                return True
            if received and msg.arbitration_id == _SYNC_COB_ID and not msg.is_extended_id and \
                    self._active_kind("sync_loss"):
                counters.sync_dropped += 1
                return True
            if self._lost():
                if received:
                    counters.lost_rx += 1
                else:
                    counters.lost_tx += 1
                return True
            return False

    def send_delay(self) -> float:
        """Added latency [s] of the next sent frame (≥ 0)."""
        lat = self.plan.latency
        if not lat.mean and not lat.jitter:
            return 0.0
        with self._lock:
            return max(0.0, self._rng.gauss(lat.mean, lat.jitter) if lat.jitter else lat.mean)

    # ------------------------------------------------------------ timed faults
    def poll(self) -> None:
        """Start the faults whose emulated time has come and end those whose wall duration is over; call
        from the server's SYNC handler and watchdog."""
        with self._lock:
            self._update()
            fired, self._fired = self._fired, []
        for action, item in fired:
            try:
                if action == "power_off":
                    self.on_power_off(item.node)
                elif action == "power_on":
                    self.on_power_on(item.node)
                elif action == "bus_off_end":
                    self.on_bus_off_recovered()
            except Exception:                      # noqa: BLE001 - a fault must not kill the server
                logger.exception("fault action %s failed", action)

    def _update(self) -> None:
        """Start/end timed faults (lock held); their node actions wait in ``_fired`` for :meth:`poll`."""
        fired = self._fired
        now_wall = time.monotonic()
        if self._pending:
            emulated = self.clock()
            while self._pending and self._pending[0][0] <= emulated + 1e-9:
                _, kind, item = self._pending.pop(0)
                duration = item.off if kind == "power" else item.duration
                self._active.append((now_wall + duration, kind, item))
                logger.warning("fault: %s at %.3f s emulated for %.3f s", kind, emulated, duration)
                if kind == "power":
                    self.counters.power_cycles += 1
                    fired.append(("power_off", item))
                elif kind == "bus_off":
                    self.counters.bus_offs += 1
                else:
                    self.counters.sync_losses += 1
        for entry in [e for e in self._active if e[0] <= now_wall]:
            self._active.remove(entry)
            _, kind, item = entry
            if kind == "power":
                fired.append(("power_on", item))
            elif kind == "bus_off":
                fired.append(("bus_off_end", item))


class FaultyBus(can.BusABC):
    """A python-can bus that injects the frame-level faults of a :class:`FaultInjector` into another bus.

    Frames received from ``bus`` may be lost (frame loss, SYNC loss, bus-off); frames sent may be lost
    or delayed (latency and jitter: a sender thread releases them in order). Closing this bus closes
    ``bus`` only if ``own_bus``.

    Args:
        bus: the real bus (any python-can bus).
        injector: the fault state (shared with the server).
        own_bus: shut ``bus`` down on :meth:`shutdown`.
    """

    def __init__(self, bus: can.BusABC, injector: FaultInjector, own_bus: bool = False):
        self._bus = bus
        self._injector = injector
        self._own_bus = own_bus
        self.channel_info = f"faults on {getattr(bus, 'channel_info', bus)}"
        self._queue: list[tuple[float, int, can.Message]] = []
        self._seq = 0
        self._last_release = 0.0
        self._cv = threading.Condition()
        self._sender: threading.Thread | None = None
        self._closing = False
        super().__init__(channel=getattr(bus, "channel", None))

    def _recv_internal(self, timeout):
        msg = self._bus.recv(timeout)
        if msg is None or self._injector.drop_received(msg):
            return None, False
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._injector.drop_sent(msg):
            return
        delay = self._injector.send_delay()
        if delay <= 0.0 and not self._queue:
            self._bus.send(msg, timeout)
            return
        with self._cv:
            release = max(time.monotonic() + delay, self._last_release)   # CAN keeps the order
            self._last_release = release
            heapq.heappush(self._queue, (release, self._seq, msg))
            self._seq += 1
            self._injector.counters.delayed += 1
            if self._sender is None:
                self._sender = threading.Thread(target=self._send_delayed, name="faulty-bus-sender",
                                                daemon=True)
                self._sender.start()
            self._cv.notify()

    def _send_delayed(self) -> None:
        while True:
            with self._cv:
                while not self._queue and not self._closing:
                    self._cv.wait()
                if self._closing:
                    return
                release, _, msg = self._queue[0]
                wait = release - time.monotonic()
                if wait > 0:
                    self._cv.wait(wait)
                    continue
                heapq.heappop(self._queue)
            try:
                self._bus.send(msg)
            except can.CanError as exc:
                logger.warning("faulty bus: delayed frame 0x%03X not sent: %s", msg.arbitration_id, exc)

    @property
    def state(self):
        return self._bus.state

    def shutdown(self) -> None:
        with self._cv:
            self._closing = True
            self._cv.notify()
        if self._sender is not None:
            self._sender.join(1.0)
        if self._own_bus:
            self._bus.shutdown()
        super().shutdown()
