"""CiA 406 absolute single-turn rotary encoder node: the steering angle sensor.

Source: CiA 406 (encoder device profile): 0x6004 position value (UNSIGNED32, measuring units),
0x6000 operating parameters (bit 0 code sequence: 1 = counting down for a positive angle; bit 2 scaling
function control: 1 = 0x6001/0x6002 apply, 0 = the physical resolution 0x6501 does), 0x6001 measuring
units per revolution, 0x6002 total measuring range, 0x6003 preset value (writing it makes the current
position read as the preset), 0x6501 single-turn resolution (physical counts per revolution).

Position value: ``(± ⌊c · 0x6001 / 0x6501⌋ + p) mod 0x6002`` with ``c`` the sensor's physical count
(α = 0 ↔ 0, docs/conventions.md), the sign from the code sequence and ``p`` the preset's offset. The
defaults (scaling on, 0x6001 = 0x6002 = 0x6501, no preset) give ``c mod 0x6501``. The position value is
sampled at SYNC and sent by the synchronous TPDO1.
"""
from __future__ import annotations

from canopen.sdo import SdoAbortedError

from ..cia import ABORT_VALUE_RANGE

CODE_SEQUENCE_DOWN, SCALING = 0x0001, 0x0004
from .lss import LssSlave
from .node301 import Node301


class Encoder406(LssSlave, Node301):
    """Steering angle encoder. Args as :class:`qomni.hil.device.node301.Node301`, plus ``name`` for logs."""

    def __init__(self, node_id, eds, *, lock=None, sync_timeout=0.1, name: str = ""):
        self.name = name or f"encoder{node_id}"
        self._scaled = 0            # the last position before the preset's offset, measuring units
        self._offset = 0            # from the preset 0x6003
        super().__init__(node_id, eds, lock=lock, sync_timeout=sync_timeout)

    def set_resolution(self, bits: int) -> None:
        """Configure a ``bits``-bit single-turn sensor (0x6001 = 0x6002 = 0x6501 = 2**bits, as defaults).

        Raises:
            ValueError: bits not in 1…32.
        """
        if not 1 <= bits <= 32:
            raise ValueError(f"steering sensor bits must be 1…32, got {bits}")
        full = 1 << bits
        with self.lock:
            for index in (0x6001, 0x6002):
                self.set_default(index, 0, full)
            self.values[(0x6501, 0)] = self._defaults[(0x6501, 0)] = full

    def set_position(self, counts: int) -> None:
        """SYNC phase 2: the sensor's physical count → position value 0x6004 (module docstring)."""
        values = self.values
        physical = values.get((0x6501, 0)) or 1
        if values.get((0x6000, 0), 0) & SCALING:
            units, total = values[(0x6001, 0)], values[(0x6002, 0)]
        else:
            units = total = physical
        scaled = counts * units // physical
        self._scaled = -scaled if values.get((0x6000, 0), 0) & CODE_SEQUENCE_DOWN else scaled
        values[(0x6004, 0)] = (self._scaled + self._offset) % total if total else scaled & 0xFFFFFFFF

    def validate_write(self, index, subindex, value):
        if index in (0x6001, 0x6002) and value <= 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)

    def on_write(self, index, subindex, value):
        if index == 0x6003:                                   # preset: the current position reads value
            self._offset = value - self._scaled
            self.values[(0x6004, 0)] = value

    def on_reset_application(self):
        self._offset = 0
