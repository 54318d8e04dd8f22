"""CiA 406 absolute single-turn rotary encoder node: the steering angle sensor.

Source: CiA 406 (encoder device profile): 0x6004 position value (UNSIGNED32, measuring units),
0x6001 measuring units per revolution, 0x6002 total measuring range, 0x6501 single-turn resolution.
Counts: ``round(α/2π · 0x6001) mod 0x6002`` with α = 0 ↔ 0 (docs/conventions.md). The position value is
sampled at SYNC and sent by the synchronous TPDO1.
"""
from __future__ import annotations

from canopen.sdo import SdoAbortedError

from ..cia import ABORT_VALUE_RANGE
from .lss import LssSlave
from .node301 import Node301


class Encoder406(LssSlave, Node301):
    """Steering angle encoder. Args as :class:`qomni.hil.device.node301.Node301`, plus ``name`` for logs."""

    def __init__(self, node_id, eds, *, lock=None, sync_timeout=0.1, name: str = ""):
        self.name = name or f"encoder{node_id}"
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
        """SYNC phase 2: the sampled position in measuring units (reduced modulo 0x6002)."""
        total = self.values[(0x6002, 0)]
        self.values[(0x6004, 0)] = counts % total if total else counts & 0xFFFFFFFF

    def validate_write(self, index, subindex, value):
        if index in (0x6001, 0x6002) and value <= 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
