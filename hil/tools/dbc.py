"""A DBC database of the vehicle's CANopen traffic, generated from the active PDO mapping of EDS/DCF files.

So that candump/CANoe/cantools users can decode a bus log (e.g. the client's BLF recording) without
knowing CANopen, every enabled PDO of every node becomes one DBC message; built with cantools' database
API (:class:`cantools.database.can.Message` / ``Signal``), never as hand-written DBC text.

Content, per node (drives 1…4 = fl, rl, fr, rr from ``drive_eds``; encoders 5, 6 = left, right from
``encoder_eds``; docs/conventions.md "CANopen mapping (hil)"):

* every RPDO / TPDO whose COB-ID (0x1400+n / 0x1800+n sub-index 1) is valid (bit 31 clear) and whose
  mapping (0x1600+n / 0x1A00+n, CiA 301 §7.5.2.36/38) has entries: message ``<node>_RPDO<n>`` /
  ``<node>_TPDO<n>``, frame ID = COB-ID, length = mapped bytes, one signal per mapped object, little
  endian (CANopen byte order), start bit = sum of the preceding entries' lengths (dummy entries leave
  gaps), signed for INTEGERn, IEEE float for REALn. Sender/receiver: the node and ``master``.
  Synchronous PDOs (transmission type 1…240) get the cycle time n · 0x1006.
* ``SYNC`` (COB-ID from 0x1005, default 0x80; length 1 with the signal ``sync_counter`` where every
  node's 0x1019 is the same value 2…240, CiA 301 §7.2.5, else length 0), ``NMT`` (0x000: command, node id),
  ``<node>_heartbeat`` (0x700 + id: NMT state) and ``<node>_EMCY`` (COB-ID 0x1014: error code, error
  register, manufacturer field) with value tables for the NMT command and state.

Signal names: ``<node>_<object>`` with CiA names (``fl_target_torque`` 0x6071, ``fl_position_actual``
0x6064, ``left_position_value`` 0x6004, :data:`qomni.hil.cia.OBJECT_NAMES`), otherwise the EDS ParameterName in
snake case (plus ``_<subindex>`` for sub-indices > 0). Values stay in device units, scale 1, with the
unit where CiA 402/406 define it (:data:`qomni.hil.cia.OBJECT_UNITS`): ``permille`` (of motor rated torque 0x6076, a
device parameter the DBC cannot know), ``inc`` (motor encoder increments), ``inc/s``, ``counts``
(steering sensor measuring units, 0x6001 per revolution). SI conversion: :mod:`hil.units`.

The mapping read is the one a node uses after NMT reset communication: ParameterValue of a DCF if
present, else DefaultValue, ``$NODEID`` resolved per node — the same rules as ``qomni.hil.device.node301`` and the
validation of :func:`hil.pdo_codec.check_entry` (byte-aligned whole objects, at most 8 bytes).
"""
from __future__ import annotations

import re
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path

import cantools
from canopen import objectdictionary as od
from cantools.database.can import Database, Message, Node, Signal
from cantools.database.conversion import BaseConversion

from ..cia import (COB_ID_EXTENDED, COB_ID_INVALID, MODE_NAMES, MODES_OF_OPERATION, MODES_OF_OPERATION_DISPLAY,
                   NMT_COMMAND_NAMES, NMT_STATE_NAMES, OBJECT_NAMES, OBJECT_UNITS, SYNC_COUNTER_OVERFLOW,
                   valid_sync_counter)
from ..layout import DRIVE_EDS, DRIVE_NODE_IDS, ENCODER_EDS, ENCODER_NODE_IDS, SIDES, SYNC_COB_ID, WHEELS
from ..pdo_codec import PdoMappingError, build_codec, check_entry, decode_entry

MASTER = "master"

_UNIT_NOTES = {
    "permille": "per mille of motor rated torque 0x6076",
    "inc": "motor encoder increments",
    "inc/s": "motor encoder increments per second",
    "counts": "measuring units, 0x6001 per revolution",
}
_CHOICES = {(MODES_OF_OPERATION, 0): MODE_NAMES, (MODES_OF_OPERATION_DISPLAY, 0): MODE_NAMES}
_RANGE = {
    od.BOOLEAN: (0, 1), od.INTEGER8: (-2**7, 2**7 - 1), od.INTEGER16: (-2**15, 2**15 - 1),
    od.INTEGER32: (-2**31, 2**31 - 1), od.INTEGER64: (-2**63, 2**63 - 1), od.UNSIGNED8: (0, 2**8 - 1),
    od.UNSIGNED16: (0, 2**16 - 1), od.UNSIGNED32: (0, 2**32 - 1), od.UNSIGNED64: (0, 2**64 - 1),
}


def build_database(drive_eds: str | Path | Sequence[str | Path] = DRIVE_EDS,
                   encoder_eds: str | Path | Sequence[str | Path] = ENCODER_EDS) -> Database:
    """The vehicle's DBC database from the active PDO mapping (module docstring for the content).

    Args:
        drive_eds: EDS/DCF of the drives: one file for all four (as :class:`qomni.hil.device.server.VehicleServer`
            uses) or a sequence of four, order fl, rl, fr, rr (nodes 1…4).
        encoder_eds: EDS/DCF of the steering encoders: one file or two (left, right; nodes 5, 6).
    Returns:
        A :class:`cantools.database.can.Database` (units: module docstring).
    Raises:
        FileNotFoundError: a file does not exist.
        ValueError: wrong number of files, two messages with one COB-ID, or an enabled PDO whose
            mapping a node cannot use (:class:`hil.pdo_codec.PdoMappingError`, a ValueError).
    """
    devices = [(node_id, name, path) for node_id, name, path in
               zip(DRIVE_NODE_IDS, WHEELS, _per_node(drive_eds, len(DRIVE_NODE_IDS), "drive_eds"))]
    devices += [(node_id, name, path) for node_id, name, path in
                zip(ENCODER_NODE_IDS, SIDES, _per_node(encoder_eds, len(ENCODER_NODE_IDS), "encoder_eds"))]
    messages: list[Message] = []
    sync_cob_id = None
    counters = set()
    for node_id, name, path in devices:
        if not Path(path).is_file():
            raise FileNotFoundError(f"EDS/DCF file {path} does not exist")
        dictionary = od.import_od(str(path), node_id)
        values = reset_values(dictionary)
        if sync_cob_id is None:
            sync_cob_id = values.get((0x1005, 0), SYNC_COB_ID) & 0x7FF
        counters.add(values.get((SYNC_COUNTER_OVERFLOW, 0), 0))
        messages += _pdo_messages(dictionary, values, node_id, name, path)
        messages += _service_messages(values, node_id, name)
    overflow = sync_counter(counters)
    counter = [Signal("sync_counter", 0, 8, is_signed=False, minimum=1, maximum=overflow,
                      comment="1 after NMT start, +1 per SYNC, back to 1 after 0x1019",
                      receivers=[n for _, n, _ in devices])] if overflow else []
    messages.insert(0, Message(
        frame_id=sync_cob_id, name="SYNC", length=len(counter), signals=counter, senders=[MASTER],
        comment=f"CiA 301 SYNC ({f'counter up to 0x1019 = {overflow}' if overflow else 'no counter'}); every "
                "node samples and sends its synchronous TPDOs"))
    messages.insert(0, Message(
        frame_id=0x000, name="NMT", length=2, senders=[MASTER], comment="CiA 301 NMT node control",
        signals=[
            Signal("nmt_command", 0, 8, is_signed=False, minimum=0, maximum=255,
                   conversion=BaseConversion.factory(choices=OrderedDict(NMT_COMMAND_NAMES)),
                   comment="NMT command specifier", receivers=[n for _, n, _ in devices]),
            Signal("nmt_node_id", 8, 8, is_signed=False, minimum=0, maximum=127,
                   comment="addressed node, 0 = all", receivers=[n for _, n, _ in devices])]))
    seen: dict[tuple[int, bool], str] = {}
    for message in messages:
        key = (message.frame_id, message.is_extended_frame)
        if key in seen:
            raise ValueError(f"COB-ID 0x{message.frame_id:03X} used by both {seen[key]} and {message.name}")
        seen[key] = message.name
    nodes = [Node(MASTER, comment="CANopen master (NMT, SYNC, RPDOs)")]
    nodes += [Node(name, comment=f"node {node_id}, {Path(path).name}") for node_id, name, path in devices]
    return Database(messages=messages, nodes=nodes, version="")


def write_dbc(path: str | Path, drive_eds: str | Path | Sequence[str | Path] = DRIVE_EDS,
              encoder_eds: str | Path | Sequence[str | Path] = ENCODER_EDS) -> Database:
    """Generate the DBC (:func:`build_database`) and write it to ``path``.

    Returns:
        The database written.
    Raises:
        FileNotFoundError, ValueError: see :func:`build_database`; OSError: ``path`` not writable.
    """
    database = build_database(drive_eds, encoder_eds)
    cantools.database.dump_file(database, str(path), database_format="dbc")
    return database


# --------------------------------------------------------------------------------------------- internals
def _per_node(files, count: int, what: str) -> list:
    if isinstance(files, (str, Path)):
        return [files] * count
    files = list(files)
    if len(files) != count:
        raise ValueError(f"{what}: give one file or {count} (one per node), got {len(files)}")
    return files


def sync_counter(overflows) -> int:
    """The counter a SYNC carries to nodes whose synchronous counter overflow values 0x1019 (CiA 301
    §7.2.5; 0 where a node has none) are ``overflows``: their common value where they agree on one of
    2…240, else 0 (no counter: a SYNC has one length for every consumer, and 1, 241…255 are reserved)."""
    values = set(overflows)
    value = values.pop() if len(values) == 1 else 0
    return value if valid_sync_counter(value) else 0


def reset_value(variable: od.ODVariable):
    """One object's value after reset: the DCF's ParameterValue, else the EDS' DefaultValue (None: neither)."""
    return variable.value if variable.value is not None else variable.default


def reset_values(dictionary: od.ObjectDictionary) -> dict[tuple[int, int], object]:
    """(index, subindex) → value after reset: DCF ParameterValue, else EDS DefaultValue."""
    values = {}
    for obj in dictionary.values():
        for var in ([obj] if isinstance(obj, od.ODVariable) else obj.values()):
            value = reset_value(var)
            if value is not None:
                values[(var.index, var.subindex)] = value
    return values


def enabled_pdos(dictionary: od.ObjectDictionary, values: dict):
    """The PDOs a node uses: ``(receive, n, comm_index, cob_id, count)`` for every RPDO (receive True)
    then TPDO whose COB-ID is valid (bit 31 clear) and whose mapping has entries; ``n`` is 0-based."""
    for base, receive in ((0x1400, True), (0x1800, False)):
        for n in range(512):
            comm = base + n
            if comm not in dictionary:
                continue
            cob_id = values.get((comm, 1), COB_ID_INVALID)
            count = values.get((comm + 0x200, 0), 0)
            if cob_id & COB_ID_INVALID or comm + 0x200 not in dictionary or not count:
                continue
            yield receive, n, comm, cob_id, count


def _pdo_messages(dictionary, values, node_id: int, name: str, path) -> list[Message]:
    messages = []
    period_us = values.get((0x1006, 0), 0)
    for receive, n, comm, cob_id, count in enabled_pdos(dictionary, values):
        kind = "RPDO" if receive else "TPDO"
        where = f"node {node_id} ({name}) {kind}{n + 1} in {Path(path).name}"
        try:
            entries = [values[(comm + 0x200, s)] for s in range(1, count + 1)]
            codec = build_codec(dictionary, entries, receive)      # the nodes' own validation
        except KeyError:
            raise PdoMappingError(f"{where}: mapping has {count} entries but not all are defined") \
                from None
        except PdoMappingError as exc:
            raise PdoMappingError(f"{where}: {exc}", exc.code) from None
        signals, start, used = [], 0, set()
        for entry in entries:
            index, subindex, bits = decode_entry(entry)
            _, _, fmt = check_entry(dictionary, entry, receive)
            if fmt[0] != "x":
                signals.append(_signal(dictionary, index, subindex, bits, start, name, used,
                                       receivers=[name] if receive else [MASTER]))
            start += bits
        trans_type = values.get((comm, 2), 255)
        cycle_ms = None
        if 1 <= trans_type <= 240 and period_us and (trans_type * period_us) % 1000 == 0:
            cycle_ms = trans_type * period_us // 1000
        extended = bool(cob_id & COB_ID_EXTENDED)
        messages.append(Message(
            frame_id=cob_id & (0x1FFFFFFF if extended else 0x7FF), name=f"{name}_{kind}{n + 1}",
            length=codec.size, signals=signals, senders=[MASTER if receive else name],
            is_extended_frame=extended, cycle_time=cycle_ms,
            comment=f"node {node_id} ({name}) {kind}{n + 1}, transmission type {trans_type}"))
    return messages


def _signal(dictionary, index: int, subindex: int, bits: int, start: int, node: str, used: set,
            receivers: list[str]) -> Signal:
    obj = dictionary[index]
    var = obj if isinstance(obj, od.ODVariable) else obj[subindex]
    stem = OBJECT_NAMES.get((index, subindex))
    if stem is None:
        stem = re.sub(r"[^0-9a-z]+", "_", var.name.lower()).strip("_") or f"obj_{index:04x}"
        if subindex:
            stem += f"_{subindex}"
    name = f"{node}_{stem}"
    if name in used:
        name = f"{name}_{index:04X}_{subindex}"
    used.add(name)
    unit = OBJECT_UNITS.get((index, subindex))
    is_float = var.data_type in (od.REAL32, od.REAL64)
    low, high = _RANGE.get(var.data_type, (None, None))
    choices = _CHOICES.get((index, subindex))
    comment = f"0x{index:04X}:{subindex:02X} {var.name}"
    if unit:
        note = "per mille of motor rated current 0x6075" if index == 0x6078 else _UNIT_NOTES[unit]
        comment += f" [{note}]"
    return Signal(name, start, bits, byte_order="little_endian",
                  is_signed=var.data_type in od.SIGNED_TYPES, minimum=low, maximum=high, unit=unit,
                  conversion=BaseConversion.factory(
                      choices=OrderedDict(choices) if choices else None, is_float=is_float),
                  comment=comment, receivers=receivers)


def _service_messages(values, node_id: int, name: str) -> list[Message]:
    messages = [Message(
        frame_id=0x700 + node_id, name=f"{name}_heartbeat", length=1, senders=[name],
        comment=f"node {node_id} ({name}) heartbeat / boot-up (CiA 301 error control)",
        signals=[Signal(f"{name}_nmt_state", 0, 7, is_signed=False, minimum=0, maximum=127,
                        conversion=BaseConversion.factory(choices=OrderedDict(NMT_STATE_NAMES)),
                        receivers=[MASTER], comment="NMT state")])]
    emcy = values.get((0x1014, 0))
    if emcy is not None and not emcy & COB_ID_INVALID:
        messages.append(Message(
            frame_id=emcy & 0x7FF, name=f"{name}_EMCY", length=8, senders=[name],
            comment=f"node {node_id} ({name}) emergency (CiA 301 EMCY)",
            signals=[
                Signal(f"{name}_emcy_error_code", 0, 16, is_signed=False, minimum=0, maximum=0xFFFF,
                       receivers=[MASTER], comment="emergency error code (CiA 301 Table 26 / CiA 402)"),
                Signal(f"{name}_emcy_error_register", 16, 8, is_signed=False, minimum=0, maximum=0xFF,
                       receivers=[MASTER], comment="error register 0x1001"),
                Signal(f"{name}_emcy_manufacturer", 24, 40, is_signed=False, minimum=0,
                       maximum=2**40 - 1, receivers=[MASTER], comment="manufacturer-specific error field")]))
    return messages
