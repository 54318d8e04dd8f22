"""One PDO's byte layout compiled from its mapping entries into a ``struct`` codec.

Mapping entry format and rules: CiA 301 §7.5.2.36 (RPDO mapping 0x1600…) and §7.5.2.38 (TPDO mapping
0x1A00…): ``index << 16 | subindex << 8 | length_in_bits``, at most 64 bits per PDO; indices
0x0001…0x0007 are dummy entries (padding). Only byte-aligned, whole-object mappings are supported,
which covers the usual drive and encoder mappings.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

from canopen import objectdictionary as od

from .cia import ABORT_CANNOT_MAP, ABORT_PDO_LENGTH


_FORMAT = {
    od.INTEGER8: "b", od.UNSIGNED8: "B", od.INTEGER16: "h", od.UNSIGNED16: "H",
    od.INTEGER32: "i", od.UNSIGNED32: "I", od.INTEGER64: "q", od.UNSIGNED64: "Q",
    od.REAL32: "f", od.REAL64: "d",
}
_DUMMY = range(0x0001, 0x0008)


class PdoMappingError(ValueError):
    """A mapping entry or a whole mapping is not acceptable; ``code`` is the CiA 301 SDO abort code."""

    def __init__(self, message: str, code: int = ABORT_CANNOT_MAP):
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class PdoCodec:
    """Encoder/decoder of one PDO.

    Attributes:
        keys: mapped objects in frame order as (index, subindex); dummy entries are left out.
        codec: little-endian ``struct.Struct`` of the frame (pad bytes for dummies).
    """

    keys: tuple[tuple[int, int], ...]
    codec: struct.Struct

    @property
    def size(self) -> int:
        """Frame length in bytes (the DLC the PDO is sent with)."""
        return self.codec.size

    def pack(self, values: Sequence) -> bytes:
        """Values in ``keys`` order → frame data. Raises ``struct.error`` if a value does not fit."""
        return self.codec.pack(*values)

    def pack_from(self, store: Mapping[tuple[int, int], object]) -> bytes:
        """Frame data from a ``{(index, subindex): value}`` store."""
        return self.codec.pack(*[store[k] for k in self.keys])

    def unpack(self, data) -> tuple:
        """Frame data (at least ``size`` bytes; extra bytes ignored) → values in ``keys`` order."""
        return self.codec.unpack_from(data)


def decode_entry(entry: int) -> tuple[int, int, int]:
    """Mapping entry (UNSIGNED32) → (index, subindex, length in bits)."""
    return (entry >> 16) & 0xFFFF, (entry >> 8) & 0xFF, entry & 0xFF


def encode_entry(index: int, subindex: int, bits: int) -> int:
    """(index, subindex, length in bits) → mapping entry (UNSIGNED32)."""
    return (index << 16) | (subindex << 8) | bits


def check_entry(dictionary: od.ObjectDictionary, entry: int, receive: bool) -> tuple[int, int, str]:
    """Validate one mapping entry against an object dictionary.

    Args:
        receive: True for an RPDO (object must be writable), False for a TPDO (readable).
    Returns:
        (index, subindex, struct format characters).
    Raises:
        PdoMappingError: unknown object, not PDO-mappable, wrong access, length mismatch, or not
            byte aligned (abort code 0x06040041).
    """
    index, subindex, bits = decode_entry(entry)
    if index in _DUMMY and subindex == 0:
        if bits == 0 or bits % 8:
            raise PdoMappingError(f"dummy entry 0x{entry:08X} is not byte aligned")
        return index, subindex, "x" * (bits // 8)
    try:
        obj = dictionary[index]
        if not isinstance(obj, od.ODVariable):
            obj = obj[subindex]
    except KeyError:
        raise PdoMappingError(f"0x{index:04X}:{subindex:02X} does not exist") from None
    if not obj.pdo_mappable:
        raise PdoMappingError(f"0x{index:04X}:{subindex:02X} ({obj.name}) is not PDO-mappable")
    if receive and not obj.writable or not receive and not obj.readable:
        raise PdoMappingError(f"0x{index:04X}:{subindex:02X} ({obj.name}) has access '{obj.access_type}'")
    fmt = _FORMAT.get(obj.data_type)
    if fmt is None or bits != len(obj):
        raise PdoMappingError(
            f"0x{index:04X}:{subindex:02X} ({obj.name}) mapped with {bits} bits; supported is its full "
            f"size for 8/16/32/64-bit numbers")
    return index, subindex, fmt


def build_codec(dictionary: od.ObjectDictionary, entries: Iterable[int], receive: bool) -> PdoCodec:
    """Compile mapping entries (in frame order) into a :class:`PdoCodec`.

    Raises:
        PdoMappingError: bad entry (0x06040041) or more than 8 bytes in total (0x06040042).
    """
    keys: list[tuple[int, int]] = []
    fmt = "<"
    for entry in entries:
        index, subindex, chars = check_entry(dictionary, entry, receive)
        fmt += chars
        if chars[0] != "x":
            keys.append((index, subindex))
    codec = struct.Struct(fmt)
    if codec.size > 8:
        raise PdoMappingError(f"mapping needs {codec.size} bytes, a CAN frame has 8", ABORT_PDO_LENGTH)
    return PdoCodec(tuple(keys), codec)
