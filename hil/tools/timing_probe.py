"""Dynamic timing of one CANopen node, measured by taking it over as its master (``qomni probe --timing``).

The probe starts the node (NMT start), produces SYNC itself every ``cycle`` s for ``syncs`` periods and
times each TPDO against the SYNC it answers (receive timestamp of the TPDO − time the SYNC was handed to
the bus): first and last TPDO of each SYNC, median and 99th percentile. It then withholds SYNC for
``pause`` s and records the node's EMCY codes and heartbeat states meanwhile (its SYNC-loss reaction),
sends SYNCs again, and finally an NMT reset node, timing the boot-up message. The heartbeat periods
seen over the whole run give its mean and jitter (standard deviation). The node is left reset (its
boot state), so this is for a bench, not for a bus in use: another master's SYNC would falsify it.

Source: CiA 301 §7.2.5 (SYNC), §7.2.2 (synchronous TPDOs), §7.2.7 (EMCY), §7.2.8.3 (heartbeat,
boot-up). Times in s. Timestamps are python-can receive times (``Message.timestamp``).
"""
from __future__ import annotations

import struct
import threading
import time
from dataclasses import dataclass, field

import can
import numpy as np

_TPDO_BASES = (0x180, 0x280, 0x380, 0x480)      # pre-defined connection set, CiA 301 §7.3.3


@dataclass
class TimingReport:
    """Dynamic timing of one node (module docstring). None where nothing was seen."""

    node_id: int
    syncs: int
    tpdo_first_p50: float | None = None
    tpdo_first_p99: float | None = None
    tpdo_last_p50: float | None = None
    tpdo_last_p99: float | None = None
    syncs_answered: int = 0          # TPDO1 frames (0x180 + node-ID) received for the SYNCs sent
    heartbeat_period: float | None = None
    heartbeat_jitter: float | None = None
    emcy_on_missed_sync: list[int] = field(default_factory=list)
    states_on_missed_sync: list[int] = field(default_factory=list)
    tpdo_after_sync_returns: bool = False
    boot_up_after_reset: float | None = None

    def rows(self) -> list[tuple[str, str]]:
        """(quantity, value) text pairs for a table; times in ms."""
        def ms(v):
            return "-" if v is None else f"{v * 1e3:.2f} ms"
        return [("SYNCs sent / answered", f"{self.syncs} / {self.syncs_answered}"),
                ("SYNC → first TPDO p50 / p99", f"{ms(self.tpdo_first_p50)} / {ms(self.tpdo_first_p99)}"),
                ("SYNC → last TPDO p50 / p99", f"{ms(self.tpdo_last_p50)} / {ms(self.tpdo_last_p99)}"),
                ("heartbeat period / jitter (std)", f"{ms(self.heartbeat_period)} / {ms(self.heartbeat_jitter)}"),
                ("EMCY while SYNC missing", " ".join(f"0x{c:04X}" for c in self.emcy_on_missed_sync) or "none"),
                ("heartbeat states while SYNC missing", " ".join(map(str, self.states_on_missed_sync)) or "-"),
                ("TPDOs again when SYNC returns", "yes" if self.tpdo_after_sync_returns else "no"),
                ("NMT reset node → boot-up", ms(self.boot_up_after_reset))]


class _Recorder(can.Listener):
    def __init__(self, node_id: int):
        self.node_id = node_id
        self.frames: list[tuple[float, int, bytes]] = []
        self.lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        cob = msg.arbitration_id
        if not msg.is_extended_id and cob & 0x7F == self.node_id and (0x80 <= cob < 0x580 or cob >= 0x700):
            with self.lock:
                self.frames.append((msg.timestamp, cob, bytes(msg.data)))

    def since(self, t0: float) -> list[tuple[float, int, bytes]]:
        with self.lock:
            return [f for f in self.frames if f[0] >= t0]


def measure(bus: can.BusABC, node_id: int, cycle: float = 0.01, syncs: int = 300, pause: float = 0.5,
            boot_timeout: float = 2.0) -> TimingReport:
    """Take node ``node_id`` over and time it (module docstring).

    Raises:
        ValueError: node_id not 1…127, or non-positive cycle / syncs / pause.
    """
    if not 1 <= node_id <= 127 or not cycle > 0 or syncs < 1 or not pause > 0:
        raise ValueError("node_id 1…127, cycle > 0, syncs ≥ 1 and pause > 0 are required")
    recorder = _Recorder(node_id)
    notifier = can.Notifier(bus, [recorder], timeout=0.05)
    report = TimingReport(node_id, syncs)
    try:
        _send(bus, 0, bytes([0x01, node_id]))                       # NMT start
        time.sleep(0.05)
        sent = []
        start = time.perf_counter()
        for k in range(syncs):
            while time.perf_counter() < start + k * cycle:
                time.sleep(0.0002)
            sent.append(_send(bus, 0x80, b""))
        time.sleep(cycle)
        _tpdo_latencies(report, sent, recorder.since(sent[0]), cycle)
        t_pause = time.time()
        time.sleep(pause)
        missing = recorder.since(t_pause)
        report.emcy_on_missed_sync = [struct.unpack_from("<H", d)[0] for _, c, d in missing
                                      if c == 0x80 + node_id and len(d) >= 2]
        report.states_on_missed_sync = sorted({d[0] & 0x7F for _, c, d in missing if c == 0x700 + node_id and d})
        t_back = time.time()
        report.syncs_answered = sum(1 for t, c, _d in recorder.since(sent[0]) if c == 0x180 + node_id and t < t_back)
        for _ in range(3):
            _send(bus, 0x80, b"")
            time.sleep(cycle)
        report.tpdo_after_sync_returns = any(c - node_id in _TPDO_BASES for _, c, _d in recorder.since(t_back))
        t_reset = _send(bus, 0, bytes([0x81, node_id]))
        end = time.time() + boot_timeout
        while time.time() < end and report.boot_up_after_reset is None:
            boots = [t for t, c, d in recorder.since(t_reset) if c == 0x700 + node_id and d[:1] == b"\x00"]
            if boots:
                report.boot_up_after_reset = boots[0] - t_reset
            time.sleep(0.005)
        beats = np.array([t for t, c, d in recorder.since(sent[0]) if c == 0x700 + node_id and d[:1] != b"\x00"
                          and t < t_reset])
        if len(beats) >= 3:
            periods = np.diff(beats)
            report.heartbeat_period, report.heartbeat_jitter = float(periods.mean()), float(periods.std())
    finally:
        notifier.stop(0.5)
    return report


def _send(bus: can.BusABC, cob_id: int, data: bytes) -> float:
    """Send a frame; returns the time it was handed to the bus (taken before: an in-process bus may deliver
    the answers, timestamped, before ``send`` returns)."""
    t = time.time()
    bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))
    return t


def _tpdo_latencies(report: TimingReport, sent: list[float], frames, cycle: float) -> None:
    """First/last TPDO after each SYNC and before the next (or one cycle later for the last SYNC)."""
    first, last = [], []
    tpdos = [t for t, c, _d in frames if c - report.node_id in _TPDO_BASES]
    bounds = sent[1:] + [sent[-1] + cycle]
    for t_sync, t_next in zip(sent, bounds):
        answers = [t - t_sync for t in tpdos if t_sync <= t < t_next]
        if answers:
            first.append(min(answers))
            last.append(max(answers))
    if first:
        report.tpdo_first_p50, report.tpdo_first_p99 = float(np.median(first)), float(np.percentile(first, 99))
        report.tpdo_last_p50, report.tpdo_last_p99 = float(np.median(last)), float(np.percentile(last, 99))
