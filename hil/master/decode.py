"""Decode a recorded CAN log of the vehicle into one :class:`~qomni.vehicle_interface.Measurement` per SYNC.

Works on any log python-can reads (:class:`can.LogReader`: Vector BLF ``.blf`` and ASC ``.asc``,
candump ``-L`` ``.log``, ``.csv``, PEAK ``.trc``, ``.mf4``), recorded by ``qomni.hil.master.client`` or by other tools,
with the PDO mapping taken from EDS/DCF files (CiA 306) like the devices do (:mod:`qomni.hil.tools.dbc` rules:
DCF ParameterValue, else EDS DefaultValue, ``$NODEID`` resolved).

Per cycle (CiA 301 SYNC semantics, docs/conventions.md):

* the cycle starts at a SYNC (COB-ID from 0x1005, default 0x80); its TPDOs are the frames of the
  drives' and encoders' valid TPDOs until the next SYNC;
* the commanded torque of the cycle is the last target torque 0x6071 each drive received by RPDO
  before that SYNC (what the drive latched at it);
* time = k · T_s with k counted from the last NMT start command (0x000, command 1) before the SYNC,
  as :class:`qomni.hil.master.client.VehicleClient` counts its cycles;
* units as the client: positions unwrapped across the 32-bit counter (:func:`hil.units.unwrap32`),
  torques from per mille of the motor rated torque 0x6076. 0x6076 comes from the log itself (an
  expedited SDO upload response of 0x6076:00, as every master reads it) if present, else from a DCF's
  ParameterValue, else from the caller (data sheet).

A cycle without the TPDO of some node is skipped and counted (:attr:`DecodeReport.incomplete`). A SYNC
missing from the log (the logger lost it) shows as a synchronous TPDO (transmission type 0–240, sent at
most once per SYNC) sent again before the next SYNC: the cycle boundary is restored there and counted
(:attr:`DecodeReport.sync_restored`), so the later cycles keep their time; the same frame logged twice
(identical data and time stamp) is dropped and counted (:attr:`DecodeReport.duplicates`). Whole cycles
missing from the log, SYNC and TPDOs alike, are counted (:attr:`DecodeReport.lost_cycles`) and skipped by
the count, so later cycles keep their time and the readers of the run refuse the gap, naming the line;
the cycle before such a gap is skipped as incomplete too, since a burst that took its last TPDOs, the
SYNCs after it and the next cycle's first TPDOs leaves what looks like one complete cycle of two cycles'
frames.
Where the SYNCs carry a counter (CiA 301 §7.2.5, 0x1019 ≥ 2; it runs to the 0x1019 the log's master
downloaded, else to the largest counter logged), a SYNC whose counter is n past the one due says so,
whatever the time stamps, and fewer than the boundaries restored since the last SYNC says that a frame
logged twice, stamped apart, was taken for a lost SYNC: those are counted as duplicates and the later
cycles keep their time. Without a counter, where the log's SYNC time stamps run on the T_s grid
(:func:`_real_time_clock`: a real-time master's log), a SYNC that comes n + 1 periods after the one
before (within :data:`GRID_TOLERANCE`) says so; a lock-step recording's stamps are not real time, and
its count is then the SYNCs logged, with a warning. A log cut while it was written
(a BLF shorter than its header announces, a text log whose last line has no line end) is decoded up to
the cut, with a warning in :attr:`DecodeReport.warnings`.
"""
from __future__ import annotations

import io
import itertools
import locale
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import can
import numpy as np
from can.io.generic import TextIOMessageReader
from can.io.player import MESSAGE_READERS
from canopen import objectdictionary as od

from ..cia import MEASURED_DRIVE_OBJECTS as _DRIVE_INPUTS, MEASURED_ENCODER_OBJECTS as _ENCODER_INPUTS
from ..cia import NMT_START as _NMT_START
from ..tools.dbc import enabled_pdos, reset_values
from ..layout import DRIVE_EDS, DRIVE_NODE_IDS, ENCODER_EDS, ENCODER_NODE_IDS, SYNC_COB_ID
from qomni.vehicle_interface import Measurement
from ..pdo_codec import PdoCodec, PdoMappingError, build_codec
from ..units import device_measurement, unwrap32



#: Largest TPDO transmission type (0x1800 + n, sub-index 2) that is synchronous: 0 acyclic, 1–240 every
#: n-th SYNC. Such a TPDO is sent only after a SYNC and at most once per SYNC (CiA 301, 7.2.2.2).
MAX_SYNCHRONOUS_TYPE = 240
#: Transmission type of an event-driven TPDO (device profile), taken where a file gives none.
EVENT_DRIVEN = 0xFF
#: Largest difference of time stamps (s) of one frame logged twice: a log's resolution (candump -L: 1 µs).
#: The next cycle's frame is stamped later, even in a lock-step recording whose cycles are not real time.
DUPLICATE_STAMP = 1e-6
#: Largest jitter of a real-time log's SYNC intervals (robust σ, share of T_s): a real-time master's SYNC
#: jitters by a few per cent of T_s (50 µs on 2 ms is 2.5 %), a lock-step master's by whole periods.
CLOCK_JITTER = 0.05
#: Largest distance (share of T_s) from the grid of a SYNC that follows lost cycles: n + 1 periods after
#: the last boundary within it is n cycles lost; farther off (1.6 T_s) is a late SYNC, 5 σ of the jitter.
GRID_TOLERANCE = 0.25
#: SYNC intervals longer than this many periods are pauses between sessions, not judged for the clock.
CLOCK_SPAN = 10


class DecodeError(ValueError):
    """The log or the mapping files cannot be decoded: says which file and what is missing."""


@dataclass
class DecodedCycle:
    """One SYNC of the log: the measurement and the commanded motor torque (4,) [N m motor side]."""

    measurement: Measurement
    motor_torque_cmd: np.ndarray
    statusword: tuple


@dataclass
class DecodeReport:
    """Counts of a decode: frames read, cycles decoded, cycles skipped as incomplete, SYNCs missing from
    the log and restored, whole cycles missing from the log (and whether its SYNC clock is read as real
    time, and the value its SYNC counter runs to: 0 where the SYNCs carry none), a logger's duplicate
    frames dropped, rated torque used."""

    frames: int = 0
    cycles: int = 0
    incomplete: int = 0
    sync_restored: int = 0
    lost_cycles: int = 0
    real_time_clock: bool = False
    sync_counter: int = 0
    duplicates: int = 0
    sessions: int = 0
    rated_torque: list = field(default_factory=list)
    rated_torque_source: str = ""
    warnings: list = field(default_factory=list)


@dataclass(frozen=True)
class _Pdo:
    node_index: int          # 0..3 drives, 4..5 encoders
    codec: PdoCodec


def node_files(drive_eds: str | Path | Sequence = DRIVE_EDS, encoder_eds: str | Path | Sequence = ENCODER_EDS,
               dcf: Sequence[str | Path] = (), eds_dir: str | Path | None = None) -> dict[int, Path]:
    """Node id → EDS/DCF file: defaults, then ``eds_dir`` (``drive402.eds``, ``encoder406.eds`` and any
    ``*.dcf`` with ``[DeviceComissioning] NodeID``), then each ``dcf`` (its NodeID).

    Raises:
        DecodeError: a file is missing, or a DCF names no node id of the vehicle (1…6).
    """
    files: dict[int, Path] = {}
    for ids, given in ((DRIVE_NODE_IDS, drive_eds), (ENCODER_NODE_IDS, encoder_eds)):
        paths = [given] * len(ids) if isinstance(given, (str, Path)) else list(given)
        if len(paths) != len(ids):
            raise DecodeError(f"give one EDS/DCF or {len(ids)} (one per node), got {len(paths)}")
        files.update({i: Path(p) for i, p in zip(ids, paths)})
    dcfs = [Path(p) for p in dcf]
    if eds_dir is not None:
        eds_dir = Path(eds_dir)
        if not eds_dir.is_dir():
            raise DecodeError(f"--eds-dir {eds_dir} is not a directory")
        for name, ids in (("drive402.eds", DRIVE_NODE_IDS), ("encoder406.eds", ENCODER_NODE_IDS)):
            if (eds_dir / name).is_file():
                files.update({i: eds_dir / name for i in ids})
        dcfs = sorted(eds_dir.glob("*.dcf")) + dcfs
    for path in dcfs:
        node_id = _dcf_node_id(path)
        if node_id not in files:
            raise DecodeError(f"{path}: NodeID {node_id} is not a node of the vehicle "
                              f"(drives {DRIVE_NODE_IDS}, encoders {ENCODER_NODE_IDS})")
        files[node_id] = path
    for node_id, path in files.items():
        if not path.is_file():
            raise DecodeError(f"EDS/DCF file {path} of node {node_id} does not exist")
    return files


def _dcf_node_id(path: Path) -> int:
    import configparser

    if not path.is_file():
        raise DecodeError(f"DCF file {path} does not exist")
    parser = configparser.RawConfigParser()
    parser.optionxform = str
    try:
        parser.read(path, encoding="utf-8")
        return int(parser.get("DeviceComissioning", "NodeID"), 0)
    except (configparser.Error, ValueError) as exc:
        raise DecodeError(f"{path}: no [DeviceComissioning] NodeID (needed to know the node): {exc}") from None


class _Mapping:
    """TPDO codecs, RPDO target-torque slots and 0x6076 of all nodes from their EDS/DCF files."""

    def __init__(self, files: dict[int, Path]):
        self.tpdos: dict[int, tuple[_Pdo, list]] = {}
        self.synchronous: set[int] = set()          # TPDOs sent at most once per SYNC (transmission type ≤ 240)
        self.rpdo_torque: dict[int, tuple[int, PdoCodec, int]] = {}
        self.rated_mnm: dict[int, int] = {}
        self.sync_cob_id = SYNC_COB_ID
        self.cycle_time_us: int | None = None
        nodes = list(DRIVE_NODE_IDS) + list(ENCODER_NODE_IDS)
        for index, node_id in enumerate(nodes):
            path = files[node_id]
            try:
                dictionary = od.import_od(str(path), node_id)
            except Exception as exc:                 # noqa: BLE001 - canopen raises many kinds
                raise DecodeError(f"{path}: not a readable EDS/DCF: {exc}") from None
            values = reset_values(dictionary)
            if index == 0:
                self.sync_cob_id = values.get((0x1005, 0), SYNC_COB_ID) & 0x7FF
                self.cycle_time_us = values.get((0x1006, 0)) or None
            inputs = _DRIVE_INPUTS if node_id in DRIVE_NODE_IDS else _ENCODER_INPUTS
            found = set()
            for receive, n, comm, cob_id, count in enabled_pdos(dictionary, values):
                try:
                    codec = build_codec(dictionary, [values[(comm + 0x200, s)] for s in range(1, count + 1)],
                                        receive)
                except (KeyError, PdoMappingError) as exc:
                    raise DecodeError(f"{path}: node {node_id} {'R' if receive else 'T'}PDO{n + 1} "
                                      f"mapping unusable: {exc}") from None
                if receive:
                    if (0x6071, 0) in codec.keys:
                        self.rpdo_torque[cob_id & 0x7FF] = (index, codec, codec.keys.index((0x6071, 0)))
                    continue
                sinks = [(inputs[k], index) if k in inputs else None for k in codec.keys]
                found.update(k for k in codec.keys if k in inputs)
                self.tpdos[cob_id & 0x7FF] = (_Pdo(index, codec), sinks)
                if values.get((comm, 2), EVENT_DRIVEN) <= MAX_SYNCHRONOUS_TYPE:
                    self.synchronous.add(cob_id & 0x7FF)
            needed = set(inputs) - {(0x6041, 0)} - found
            if needed:
                raise DecodeError(f"{path}: node {node_id} maps "
                                  f"{', '.join(f'0x{k[0]:04X}' for k in sorted(needed))} in no valid TPDO")
            if node_id in DRIVE_NODE_IDS and dictionary.get(0x6076) is not None and \
                    dictionary[0x6076].value is not None:
                self.rated_mnm[node_id] = int(dictionary[0x6076].value)      # a DCF's ParameterValue


def decode_log(path: str | Path, *, encoder_increments: int, steering_sensor_bits: int,
               cycle_time: float | None = None, rated_torque: Sequence[float] | float | None = None,
               files: dict[int, Path] | None = None, report: DecodeReport | None = None
               ) -> Iterator[DecodedCycle]:
    """Decode a bus log cycle by cycle (module docstring).

    Args:
        path: the log (any format of :class:`can.LogReader`).
        encoder_increments: motor encoder increments per revolution (data sheet).
        steering_sensor_bits: steering sensor resolution (data sheet).
        cycle_time: s, T_s; default: 0x1006 of the mapping files.
        rated_torque: N m motor side, one or four (fl, rl, fr, rr): used where neither the log nor a
            DCF gives 0x6076.
        files: node id → EDS/DCF (:func:`node_files`); default: the shipped EDS files.
        report: filled in while decoding.
    Returns:
        An iterator of :class:`DecodedCycle`, one per complete SYNC cycle (checks run at once, the
        log is read while iterating).
    Raises:
        FileNotFoundError: no such log. DecodeError: unknown log format, unusable mapping, no 0x6076
            anywhere, no T_s, or a T_s other than the 0x1006 the log's master wrote.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"log file {path} does not exist")
    mapping = _Mapping(files if files is not None else node_files())
    period = cycle_time if cycle_time is not None else (
        mapping.cycle_time_us * 1e-6 if mapping.cycle_time_us else None)
    if not period or period <= 0:
        raise DecodeError("no cycle time: give the data sheet's T_s (0x1006 is not in the mapping files)")
    report = report if report is not None else DecodeReport()
    logged = _scan_log(path, mapping.sync_cob_id)
    _check_period(path, logged, period)
    rated = _rated_torques(path, mapping, rated_torque, report, logged)
    report.real_time_clock = _real_time_clock(np.asarray(logged.sync_stamps), period)
    report.sync_counter = logged.counter_overflow
    if logged.sync_stamps and not report.real_time_clock and not report.sync_counter:
        report.warnings.append(f"{path}: its SYNCs carry no counter (0x1019) and their time stamps do not run on "
                               f"the {period * 1e3:g} ms grid (a lock-step log): whole cycles the logger lost, "
                               "SYNC and TPDOs, cannot be counted, and every row after them would be early")
    reader = _open_log(path, report)
    return _cycles(_frames(reader, path), mapping, period, rated, report, encoder_increments,
                   steering_sensor_bits)


def _real_time_clock(stamps: np.ndarray, period: float) -> bool:
    """Whether SYNC time stamps (s, in log order) run on the ``period`` grid: the median interval within
    :data:`CLOCK_JITTER` of ``period`` and the intervals' robust σ (1.4826 × MAD of those within half a
    period of it) at most :data:`CLOCK_JITTER` × ``period``. Intervals over :data:`CLOCK_SPAN` periods
    (sessions) and backwards ones are left out."""
    intervals = np.diff(stamps) / period
    intervals = intervals[(intervals > 0) & (intervals <= CLOCK_SPAN)]
    if len(intervals) < 2 or abs(float(np.median(intervals)) - 1.0) > CLOCK_JITTER:
        return False
    near = intervals[np.abs(intervals - 1.0) < 0.5]
    return 1.4826 * float(np.median(np.abs(near - np.median(near)))) <= CLOCK_JITTER


def _open_log(path: Path, report: DecodeReport | None = None):
    """python-can's reader of the log's format; DecodeError naming the file if it cannot read it.

    A log cut while it was written is read up to the cut, with a warning in ``report``: a BLF shorter than
    its header announces ends at its last whole object; a text log (candump ``-L``, ASC, CSV, TRC) whose
    last line has no line end is given to its reader up to its last complete line, since the cut line may
    still parse, into a frame with part of its data."""
    size = path.stat().st_size
    reader_class = MESSAGE_READERS.get(path.suffix.lower())
    complete = size
    if reader_class is not None and issubclass(reader_class, TextIOMessageReader):
        complete = _complete_lines_size(path)
    try:
        reader = reader_class(_text_head(path, complete)) if complete < size else can.LogReader(str(path))
    except ValueError as exc:
        raise DecodeError(f"{path}: {exc} (python-can reads .blf, .asc, .log, .csv, .trc, .mf4)") from None
    except Exception as exc:                                         # noqa: BLE001 - a format's own parse error
        raise DecodeError(f"{path}: not a readable log: {type(exc).__name__}: {exc}") from None
    announced = getattr(reader, "file_size", None)                   # BLF: the size its header announces
    if report is not None and complete < size:
        report.warnings.append(f"{path}: its last line (from byte {complete}) has no line end: the file is "
                               "cut; only the lines before it are decoded")
    elif report is not None and announced and size < announced:
        report.warnings.append(f"{path}: {size} of the {announced} bytes the BLF header announces: the file "
                               "is cut; only the frames before the cut are decoded")
    return reader


def _complete_lines_size(path: Path, chunk: int = 1 << 16) -> int:
    """Bytes of ``path`` up to and including its last line end (its size when it ends with one)."""
    size = path.stat().st_size
    with path.open("rb") as f:
        end = size
        while end > 0:
            start = max(0, end - chunk)
            f.seek(start)
            block = f.read(end - start)
            if end == size and block.endswith(b"\n"):
                return size
            i = block.rfind(b"\n")
            if i >= 0:
                return start + i + 1
            end = start
    return 0


class _Head(io.RawIOBase):
    """The first ``size`` bytes of a binary file, as a raw stream."""

    def __init__(self, raw, size: int):
        self._raw, self._left = raw, size

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        view = memoryview(buffer)[: self._left]
        n = self._raw.readinto(view) if len(view) else 0
        self._left -= n
        return n

    def close(self) -> None:
        self._raw.close()
        super().close()


def _text_head(path: Path, size: int) -> io.TextIOWrapper:
    """The first ``size`` bytes of ``path`` as text, in the encoding python-can reads text logs in."""
    return io.TextIOWrapper(io.BufferedReader(_Head(path.open("rb"), size)),
                            encoding=locale.getpreferredencoding(False))


def _frames(reader, path: Path):
    """The log's frames; a frame the reader cannot parse ends the decode naming file and frame number
    (for line-based formats such as candump ``-L`` the line is the frame number, less any header)."""
    count = 0
    iterator = iter(reader)
    while True:
        try:
            msg = next(iterator)
        except StopIteration:
            return
        except Exception as exc:                                     # noqa: BLE001 - any reader's parse error
            raise DecodeError(f"{path}: cannot read frame {count + 1} (after {count} good frames): "
                              f"{type(exc).__name__}: {exc}") from None
        count += 1
        yield msg


def _cycles(reader, mapping, period, rated, report, encoder_increments, steering_sensor_bits):
    sync_id = mapping.sync_cob_id
    boundary = None       # time stamp of the last cycle boundary (a SYNC, or a restored one), real-time logs
    last_sync = None      # time stamp of the last SYNC frame
    expected = len(mapping.tpdos)
    cmd = np.zeros(4)
    pending_cmd = np.zeros(4)
    cycle = None          # cycles since NMT start; None before the first start
    rx: dict[int, bytes] = {}
    seen_at: dict[int, float] = {}
    unwrap = None
    overflow = report.sync_counter
    last_counter = None   # the counter of the last SYNC logged, None where unknown (before the first)
    restored = 0          # boundaries restored since that SYNC

    for msg in itertools.chain(reader, [None]):          # None: the end closes the last cycle
        if msg is not None:
            report.frames += 1
            if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                continue
        cob = sync_id if msg is None else msg.arbitration_id
        if cob == sync_id and msg is not None:
            if not rx and last_sync is not None and abs(msg.timestamp - last_sync) <= DUPLICATE_STAMP:
                report.duplicates += 1                   # the logger wrote the SYNC twice
                continue
            last_sync = msg.timestamp
        lost_sync = False
        if cycle is not None and cob in rx and cob in mapping.synchronous:
            if bytes(msg.data) == rx[cob] and abs(msg.timestamp - seen_at[cob]) <= DUPLICATE_STAMP:
                report.duplicates += 1                   # the logger wrote one frame twice
                continue
            lost_sync = True                             # sent again: the SYNC between the two is not in the log
            report.sync_restored += 1
            restored += 1
        lost = 0              # whole cycles missing from the log before this SYNC
        if cob == sync_id and msg is not None and overflow:
            if len(msg.data) == 1 and cycle is not None and last_counter is not None:
                missing = (msg.data[0] - last_counter - 1) % overflow   # SYNCs between the two not logged
                lost = missing - restored        # beyond those restored; below: restored for a frame logged twice
                if lost < 0:
                    report.sync_restored += lost
                    report.duplicates -= lost
            last_counter, restored = (msg.data[0] if len(msg.data) == 1 else None), 0
        elif cob == sync_id and msg is not None and cycle is not None and boundary is not None and \
                report.real_time_clock and not overflow:
            periods = (msg.timestamp - boundary) / period
            if round(periods) > 1 and abs(periods - round(periods)) <= GRID_TOLERANCE:
                lost = int(round(periods)) - 1
        if cob == sync_id or lost_sync:
            if lost > 0 and rx:
                report.incomplete += 1                   # a burst may have left two cycles' frames in it
            if lost:
                rx = {}                                  # below 0: the rest of a cycle already decoded
            if cycle is not None and rx:
                out = _emit(rx, mapping, expected, cycle - 1, period, cmd, rated, unwrap, encoder_increments,
                            steering_sensor_bits)
                if out is None:
                    report.incomplete += 1
                else:
                    decoded, unwrap = out
                    report.cycles += 1
                    yield decoded
            rx = {}
            cmd = pending_cmd.copy()
            if cycle is not None:
                cycle += 1 + lost
                report.lost_cycles += max(lost, 0)
                if report.real_time_clock and msg is not None and not overflow:
                    boundary = msg.timestamp if cob == sync_id or boundary is None else boundary + period
        if cob == sync_id:
            pass
        elif cob == 0x000 and len(msg.data) == 2 and msg.data[0] == _NMT_START:
            if cycle is None or cycle > 0:
                report.sessions += 1
            cycle, unwrap, rx, boundary, last_counter, restored = 0, None, {}, None, None, 0
        elif cob in mapping.tpdos:
            rx[cob] = bytes(msg.data)
            seen_at[cob] = msg.timestamp
        elif cob in mapping.rpdo_torque:
            drive, codec, slot = mapping.rpdo_torque[cob]
            if len(msg.data) >= codec.size:
                pending_cmd[drive] = codec.unpack(msg.data)[slot] * rated[drive] * 1e-3


def _emit(rx, mapping, expected, k, period, cmd, rated, unwrap, increments, bits):
    if len(rx) < expected:
        return None
    fields = {"status": [0] * 4, "position": [0] * 4, "velocity": [0] * 4, "torque": [0] * 4, "counts": [0] * 2}
    for cob, data in rx.items():
        pdo, sinks = mapping.tpdos[cob]
        if len(data) < pdo.codec.size:
            return None
        for sink, value in zip(sinks, pdo.codec.unpack(data)):
            if sink is not None:
                name, index = sink
                fields[name][index if name != "counts" else index - 4] = value
    raw = np.array(fields["position"], dtype=np.int64)
    total = raw if unwrap is None else unwrap32(raw, unwrap[0], unwrap[1])
    measurement = device_measurement(k * period, total, fields["velocity"], fields["torque"], fields["counts"],
                                     encoder_increments=increments, rated_torque=rated, steering_sensor_bits=bits)
    return DecodedCycle(measurement, cmd.copy(), tuple(fields["status"])), (raw, total)


#: An expedited SDO frame: command specifier, index, sub-index, up to four data bytes (CiA 301, 7.2.4.3).
_SDO_EXPEDITED = struct.Struct("<BHBI")


@dataclass
class _LogScan:
    """What the log's expedited SDO frames say: 0x6076 uploaded from each drive (mN m, node id → value),
    0x1006 the master downloaded to each node (µs) and the 0x1019 it downloaded; and the SYNC frames' time
    stamps (s) and counters."""

    rated_mnm: dict[int, int] = field(default_factory=dict)
    cycle_period_us: dict[int, int] = field(default_factory=dict)
    sync_stamps: list[float] = field(default_factory=list)
    sync_counter_overflow: int = 0      # the last 0x1019 downloaded (0: none in the log)
    sync_counter_max: int = 0           # the largest SYNC counter logged (0: no SYNC has one)

    @property
    def counter_overflow(self) -> int:
        """The value a SYNC counter runs to: the 0x1019 the master wrote, else the largest counter logged
        (a log shorter than one round of the counter never needs the wrap)."""
        return max(self.sync_counter_overflow, self.sync_counter_max)


def _scan_log(path: Path, sync_id: int = SYNC_COB_ID) -> _LogScan:
    """One pass over the log for the SDO values and SYNC time stamps the decode uses."""
    logged = _LogScan()
    for msg in _frames(_open_log(path), path):
        cob = msg.arbitration_id
        if cob == sync_id and not msg.is_extended_id and not msg.is_remote_frame and not msg.is_error_frame:
            logged.sync_stamps.append(float(msg.timestamp))
            if len(msg.data) == 1:
                logged.sync_counter_max = max(logged.sync_counter_max, msg.data[0])
        if msg.is_extended_id or len(msg.data) != 8:
            continue
        command, index, sub, value = _SDO_EXPEDITED.unpack(bytes(msg.data))
        if 0x581 <= cob <= 0x584 and command & 0xE3 == 0x43 and index == 0x6076 and sub == 0:
            logged.rated_mnm[cob - 0x580] = value                        # expedited upload response
        elif 0x601 <= cob <= 0x67F and command == 0x23 and index == 0x1006 and sub == 0:
            logged.cycle_period_us.setdefault(cob - 0x600, value)       # expedited download, 4 bytes
        elif 0x601 <= cob <= 0x67F and command == 0x2F and index == 0x1019 and sub == 0 and value & 0xFF:
            logged.sync_counter_overflow = value & 0xFF                 # expedited download, 1 byte
    return logged


def _check_period(path: Path, logged: _LogScan, period: float) -> None:
    """The decoded time is the SYNC count × ``period``: a ``period`` other than the communication cycle
    period 0x1006 the log's master wrote to its nodes would stretch every time and rate by their ratio.

    Raises: DecodeError: names the node and both values."""
    for node_id, us in sorted(logged.cycle_period_us.items()):
        if us and abs(us * 1e-6 - period) > 0.5e-6:
            raise DecodeError(f"{path}: the log's master set the communication cycle period 0x1006 of node "
                              f"{node_id} to {us} µs; the cycle time given is {period * 1e6:g} µs: give the data "
                              "sheet of the vehicle and settings this log was recorded with")


def _rated_torques(path: Path, mapping: _Mapping, given, report: DecodeReport,
                   logged: _LogScan) -> np.ndarray:
    """0x6076 per drive [N m]: from the log's SDO upload responses, else the DCFs, else ``given``.

    Raises: DecodeError: no 0x6076 anywhere."""
    seen = logged.rated_mnm
    out, sources = np.zeros(4), set()
    fallback = None if given is None else np.broadcast_to(np.asarray(given, dtype=float), (4,))
    for i, node_id in enumerate(DRIVE_NODE_IDS):
        if node_id in seen and seen[node_id] > 0:
            out[i], source = seen[node_id] * 1e-3, "SDO upload of 0x6076 in the log"
        elif node_id in mapping.rated_mnm and mapping.rated_mnm[node_id] > 0:
            out[i], source = mapping.rated_mnm[node_id] * 1e-3, "DCF ParameterValue of 0x6076"
        elif fallback is not None:
            out[i], source = fallback[i], "data sheet"
        else:
            raise DecodeError(f"{path}: motor rated torque 0x6076 of drive {node_id} is neither read in the "
                              "log nor in a DCF: give the data sheet")
        sources.add(source)
    report.rated_torque = out.tolist()
    report.rated_torque_source = ", ".join(sorted(sources))
    return out
