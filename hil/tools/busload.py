"""Bus load of the vehicle's cyclic CANopen traffic, from the active PDO mapping of the EDS/DCF files.

Per SYNC cycle T_s (0x1006): one SYNC (DLC 1 with the counter where every node's 0x1019 sets the same
one, else 0; :func:`qomni.hil.tools.dbc.sync_counter`), every valid RPDO once (the master sends each drive's
commands every cycle), every valid TPDO with transmission type n ∈ 1…240 once every n cycles and with
type 0/254/255 once per cycle (worst case), plus the heartbeats (0x1017 ms). Frame length: the worst
case with bit stuffing for a standard (11-bit) data frame with n data bytes (Davis, Burns, Bril, Lukkien,
"Controller Area Network (CAN) schedulability analysis", 2007), including the 3-bit interframe space::

    bits(n) = 8n + 47 + floor((34 + 8n − 1) / 4)

so a SYNC without counter is 55 bits, with one 65, a 4-byte PDO 95 bits, an 8-byte PDO 135 bits.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from canopen import objectdictionary as od

from .dbc import enabled_pdos, reset_values, sync_counter
from ..cia import COMMUNICATION_CYCLE_PERIOD, SYNC_COUNTER_OVERFLOW
from ..layout import DRIVE_EDS, DRIVE_NODE_IDS, ENCODER_EDS, ENCODER_NODE_IDS
from ..pdo_codec import build_codec


def frame_bits(data_bytes: int) -> int:
    """Worst-case length [bit] of a standard CAN data frame with ``data_bytes`` (0…8), stuffing and IFS."""
    if not 0 <= data_bytes <= 8:
        raise ValueError(f"a classical CAN frame carries 0…8 data bytes, got {data_bytes}")
    return 8 * data_bytes + 47 + (34 + 8 * data_bytes - 1) // 4


@dataclass
class BusLoad:
    """Result of :func:`bus_load`.

    Attributes:
        bitrate: bit/s. cycle_time: s.
        frames: (name, data bytes, frames per cycle, bits per cycle) per message kind.
        bits_per_cycle: worst-case bits per SYNC cycle.
        load: fraction of the bitrate (0…1+; above 1 the mapping does not fit the cycle).
    """

    bitrate: int
    cycle_time: float
    frames: list = field(default_factory=list)

    @property
    def bits_per_cycle(self) -> float:
        return sum(bits for *_, bits in self.frames)

    @property
    def load(self) -> float:
        return self.bits_per_cycle / (self.bitrate * self.cycle_time)


def bus_load(bitrate: int, cycle_time: float | None = None, files: dict[int, Path] | None = None) -> BusLoad:
    """Worst-case bus load of the cyclic traffic (module docstring).

    Args:
        bitrate: bit/s, e.g. 1_000_000.
        cycle_time: s, T_s; default: 0x1006 of the first node's file.
        files: node id → EDS/DCF (:func:`qomni.hil.master.decode.node_files`); default: the shipped EDS files.
    Raises:
        ValueError: non-positive bitrate or cycle time, or an unusable mapping.
    """
    if bitrate <= 0:
        raise ValueError(f"bitrate must be > 0 bit/s, got {bitrate}")
    if files is None:
        files = {**{i: DRIVE_EDS for i in DRIVE_NODE_IDS}, **{i: ENCODER_EDS for i in ENCODER_NODE_IDS}}
    result = BusLoad(bitrate, cycle_time or 0.0)
    counters = []
    for node_id in sorted(files):
        dictionary = od.import_od(str(files[node_id]), node_id)
        values = reset_values(dictionary)
        counters.append(values.get((SYNC_COUNTER_OVERFLOW, 0), 0))
        if not result.cycle_time:
            result.cycle_time = values.get((COMMUNICATION_CYCLE_PERIOD, 0), 0) * 1e-6
        for receive, n, comm, cob_id, count in enabled_pdos(dictionary, values):
            codec = build_codec(dictionary, [values[(comm + 0x200, s)] for s in range(1, count + 1)], receive)
            trans = values.get((comm, 2), 255)
            per_cycle = 1.0 / trans if 1 <= trans <= 240 and not receive else 1.0
            name = f"node {node_id} {'RPDO' if receive else 'TPDO'}{n + 1} (0x{cob_id & 0x7FF:03X})"
            result.frames.append((name, codec.size, per_cycle, per_cycle * frame_bits(codec.size)))
        heartbeat_ms = values.get((0x1017, 0), 0)
        if heartbeat_ms:
            per_cycle = result.cycle_time / (heartbeat_ms * 1e-3) if result.cycle_time else 0.0
            result.frames.append((f"node {node_id} heartbeat", 1, per_cycle, per_cycle * frame_bits(1)))
    if not result.cycle_time > 0:
        raise ValueError("no cycle time: give T_s (0x1006 is not in the mapping files)")
    sync_bytes = 1 if sync_counter(counters) else 0
    result.frames.insert(0, ("SYNC", sync_bytes, 1.0, float(frame_bits(sync_bytes))))
    return result
