"""What is on a CANopen bus: every node that answers an SDO, its identity, profile and CiA 402 modes, and
how fast it answers — without an EDS (objects are read by index, CiA 301/402/406 codings).

Scan: one SDO upload request of 0x1000 (device type) to each node-ID at once, answers collected for
``timeout``. Per node then, by SDO: device type 0x1000 (profile number in bits 0–15), manufacturer device
name 0x1008, identity 0x1018:1…4, producer heartbeat time 0x1017; for a CiA 402 device supported drive
modes 0x6502, modes of operation display 0x6061 and statusword 0x6041 (power state); for a CiA 406
device measuring units per revolution 0x6001. An object the device lacks reads as None. Timing: the
SDO response time (request handed to the bus → response received) of ``samples`` uploads of 0x1000,
as median and 99th percentile.
"""
from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field

import can
import canopen
import numpy as np
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from ..cia import MODE_NAMES

#: Short names of the CiA 402 modes (canopen / ros2_canopen usage).
MODE_SHORT = {0: "none", 1: "PP", 2: "VL", 3: "PV", 4: "TQ", 6: "HM", 7: "IP", 8: "CSP", 9: "CSV", 10: "CST"}
#: Power states by statusword (mask, value), CiA 402 §6.
POWER_STATES = (("NOT READY TO SWITCH ON", 0x4F, 0x00), ("SWITCH ON DISABLED", 0x4F, 0x40),
                ("READY TO SWITCH ON", 0x6F, 0x21), ("SWITCHED ON", 0x6F, 0x23),
                ("OPERATION ENABLED", 0x6F, 0x27), ("QUICK STOP ACTIVE", 0x6F, 0x07),
                ("FAULT REACTION ACTIVE", 0x4F, 0x0F), ("FAULT", 0x4F, 0x08))


class ProbeError(RuntimeError):
    """No node answered, or the bus could not be used."""


@dataclass
class NodeReport:
    """What one node told the probe. Times in s."""

    node_id: int
    device_type: int
    name: str | None = None
    identity: tuple = (None, None, None, None)
    heartbeat_ms: int | None = None
    modes: list[int] = field(default_factory=list)
    mode: int | None = None
    state: str | None = None
    units_per_revolution: int | None = None
    sdo_p50: float | None = None
    sdo_p99: float | None = None

    @property
    def profile(self) -> int:
        """CiA profile number (402 drive, 406 encoder, …) from 0x1000 bits 0–15."""
        return self.device_type & 0xFFFF

    def as_dict(self) -> dict:
        return {"node_id": self.node_id, "device_type": self.device_type, "profile": self.profile,
                "name": self.name, "vendor_id": self.identity[0], "product_code": self.identity[1],
                "revision": self.identity[2], "serial": self.identity[3], "heartbeat_ms": self.heartbeat_ms,
                "modes": [MODE_NAMES.get(m, str(m)) for m in self.modes],
                "mode": MODE_NAMES.get(self.mode) if self.mode is not None else None, "state": self.state,
                "units_per_revolution": self.units_per_revolution, "sdo_p50_s": self.sdo_p50,
                "sdo_p99_s": self.sdo_p99}


def scan(network: canopen.Network, node_ids=range(1, 128), timeout: float = 0.3) -> list[int]:
    """Node-IDs that answer an SDO upload of 0x1000 within ``timeout`` s (abort answers count)."""
    answered: set[int] = set()

    def on_response(can_id, data, timestamp):
        answered.add(can_id - 0x580)

    ids = list(node_ids)
    for node_id in ids:
        network.subscribe(0x580 + node_id, on_response)
    try:
        for node_id in ids:
            network.send_message(0x600 + node_id, struct.pack("<BHB4x", 0x40, 0x1000, 0))
        time.sleep(timeout)
    finally:
        for node_id in ids:
            network.unsubscribe(0x580 + node_id, on_response)
    return sorted(answered)


def _read(node, index, subindex=0, fmt="<I"):
    try:
        data = node.sdo.upload(index, subindex)
    except (SdoAbortedError, SdoCommunicationError):
        return None
    if fmt is None:
        return data.decode("ascii", "replace").rstrip("\0")
    size = struct.calcsize(fmt)
    return struct.unpack(fmt, data[:size])[0] if len(data) >= size else None


def identify(network: canopen.Network, node_id: int, samples: int = 20) -> NodeReport:
    """Read one node's identity, profile objects and SDO response times (module docstring)."""
    node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = 0.2
    network.add_node(node)
    try:
        device_type = _read(node, 0x1000)
        if device_type is None:
            raise ProbeError(f"node {node_id} does not answer an upload of 0x1000")
        report = NodeReport(node_id, device_type, name=_read(node, 0x1008, fmt=None),
                            identity=tuple(_read(node, 0x1018, s) for s in (1, 2, 3, 4)),
                            heartbeat_ms=_read(node, 0x1017, fmt="<H"))
        if report.profile == 402:
            supported = _read(node, 0x6502) or 0
            report.modes = [m for m in range(1, 11) if supported >> (m - 1) & 1]
            report.mode = _read(node, 0x6061, fmt="<b")
            statusword = _read(node, 0x6041, fmt="<H")
            if statusword is not None:
                report.state = next((n for n, mask, value in POWER_STATES if statusword & mask == value), None)
        elif report.profile == 406:
            report.units_per_revolution = _read(node, 0x6001)
        times = []
        for _ in range(samples):
            start = time.perf_counter()
            if _read(node, 0x1000) is not None:
                times.append(time.perf_counter() - start)
        if times:
            report.sdo_p50 = float(np.median(times))
            report.sdo_p99 = float(np.percentile(times, 99))
        return report
    finally:
        del network[node_id]


def probe(bus: can.BusABC, node_ids=range(1, 128), timeout: float = 0.3, samples: int = 20) -> list[NodeReport]:
    """Scan ``bus`` and identify every node that answers.

    Raises:
        ProbeError: no node answered.
    """
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.05
    network.connect()
    try:
        found = scan(network, node_ids, timeout)
        if not found:
            raise ProbeError(f"no node answered an SDO request within {timeout} s")
        return [identify(network, node_id, samples) for node_id in found]
    finally:
        if network.notifier is not None:
            network.notifier.stop(1.0)


def table_rows(reports: list[NodeReport]) -> list[list[str]]:
    """One row of text cells per node: id, profile, name, vendor/product/revision/serial, modes, mode,
    state, SDO p50/p99 [ms]."""
    def hex_or_dash(v):
        return "-" if v is None else f"0x{v:X}"

    def ms(v):
        return "-" if v is None else f"{v * 1e3:.2f}"

    rows = []
    for r in reports:
        rows.append([str(r.node_id), f"CiA {r.profile}", r.name or "-", *map(hex_or_dash, r.identity),
                     " ".join(MODE_SHORT.get(m, str(m)) for m in r.modes) or "-",
                     MODE_SHORT.get(r.mode, str(r.mode)) if r.mode is not None else "-", r.state or "-",
                     ms(r.sdo_p50), ms(r.sdo_p99)])
    return rows


COLUMNS = ("node", "profile", "name", "vendor", "product", "revision", "serial", "modes (0x6502)",
           "mode (0x6061)", "state", "SDO p50 ms", "SDO p99 ms")
