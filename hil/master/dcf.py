"""Concise DCF (CiA 302-3 object 0x1F22 "concise DCF", format of CiA 301 §7.4.8.2.2 / CiA 306-1): the
binary list of object values a CANopen manager downloads to a device when configuring it.

Format (little-endian): UNSIGNED32 number of entries, then per entry UNSIGNED16 index, UNSIGNED8
sub-index, UNSIGNED32 data size in bytes, the data. :func:`from_dcf` builds one from a DCF's (or EDS's)
``ParameterValue`` entries (CiA 306: the configured value, where ``DefaultValue`` is only the default);
:func:`apply` writes one to a device by SDO, in order, as the client does at connect
(``VehicleClient(concise_dcf={node id: bytes})``) before its own configuration.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen import objectdictionary as od
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from .errors import CommunicationError

#: Object of a CANopen manager holding the concise DCF per node-ID (sub-index = node-ID), CiA 302-3.
CONCISE_DCF_OBJECT = 0x1F22


class ConciseDcfError(ValueError):
    """Bytes that are not a concise DCF (truncated, a size beyond the end, bytes after the last entry)."""


@dataclass(frozen=True)
class Entry:
    """One object value of a concise DCF: index, sub-index, raw little-endian data."""

    index: int
    subindex: int
    data: bytes


def build(entries: list[Entry]) -> bytes:
    """The concise DCF of ``entries`` (in the given order).

    Raises:
        ConciseDcfError: an index, sub-index or size out of its field's range.
    """
    out = bytearray(struct.pack("<I", len(entries)))
    for e in entries:
        if not (0 <= e.index <= 0xFFFF and 0 <= e.subindex <= 0xFF):
            raise ConciseDcfError(f"entry 0x{e.index:X}:{e.subindex:X} out of range")
        out += struct.pack("<HBI", e.index, e.subindex, len(e.data)) + bytes(e.data)
    return bytes(out)


def parse(data: bytes) -> list[Entry]:
    """Entries of a concise DCF.

    Raises:
        ConciseDcfError: truncated header or entry, or bytes left after the announced entries.
    """
    data = bytes(data)
    if len(data) < 4:
        raise ConciseDcfError(f"concise DCF of {len(data)} bytes has no entry count")
    count, = struct.unpack_from("<I", data)
    entries, pos = [], 4
    for k in range(count):
        if pos + 7 > len(data):
            raise ConciseDcfError(f"entry {k + 1} of {count}: header beyond the end ({len(data)} bytes)")
        index, subindex, size = struct.unpack_from("<HBI", data, pos)
        pos += 7
        if pos + size > len(data):
            raise ConciseDcfError(f"entry {k + 1} (0x{index:04X}:{subindex:02X}): {size} data bytes, "
                                  f"{len(data) - pos} left")
        entries.append(Entry(index, subindex, data[pos:pos + size]))
        pos += size
    if pos != len(data):
        raise ConciseDcfError(f"{len(data) - pos} bytes after the {count} announced entries")
    return entries


def from_dcf(dcf: str | Path | od.ObjectDictionary, node_id: int | None = None) -> bytes:
    """Concise DCF of the writable objects with a ``ParameterValue`` in a DCF/EDS, in index order.

    Args:
        dcf: DCF/EDS path or an imported object dictionary; ``node_id`` resolves ``$NODEID``.
    Raises:
        ConciseDcfError: the file has no ParameterValue entry for any writable object.
    """
    dictionary = dcf if isinstance(dcf, od.ObjectDictionary) else canopen.import_od(str(dcf), node_id)
    entries = []
    for obj in sorted(dictionary.values(), key=lambda o: o.index):
        for var in [obj] if isinstance(obj, od.ODVariable) else obj.values():
            if var.value is not None and var.writable:
                entries.append(Entry(var.index, var.subindex, var.encode_raw(var.value)))
    if not entries:
        raise ConciseDcfError(f"{dcf}: no writable object has a ParameterValue")
    return build(entries)


def apply(node: canopen.RemoteNode, data: bytes) -> int:
    """Download a concise DCF to ``node`` by SDO (segmented or expedited), entry by entry; returns the
    number of entries.

    Raises:
        ConciseDcfError: ``data`` is not a concise DCF (nothing is written).
        CommunicationError: the device refused an entry or did not answer (the entry and the abort are
            named; the entries before it were written).
    """
    entries = parse(data)
    for k, e in enumerate(entries, 1):
        try:
            node.sdo.download(e.index, e.subindex, e.data)
        except (SdoAbortedError, SdoCommunicationError) as exc:
            raise CommunicationError(f"node {node.id}: concise DCF entry {k} of {len(entries)} "
                                     f"(0x{e.index:04X}:{e.subindex:02X}, {len(e.data)} bytes): {exc}") from exc
    return len(entries)
