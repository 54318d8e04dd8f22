"""FMI-LS-BUS CAN operations in Python, and a driver of the plant-can FMU through fmpy: what a co-simulation
tool with LS-BUS support does at the FMU's bus terminal, so tests and users exchange CAN frames with it.

Operations (FMI-LS-BUS 1.0, "Layered Standard Bus Protocol" and "CAN"): little-endian {op code u32, total
length u32, arguments}; CAN Transmit (0x10) = id u32, ide u8, rtr u8, data length u16, data; Format Error
(0x01) = data length u16, data (the offending operation's bytes).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Iterable

from .cosim import FmuSlave
from .plant_can_spec import TERMINAL

OP_FORMAT_ERROR, OP_CAN_TRANSMIT = 0x01, 0x10
_HEADER = struct.Struct("<II")
_TRANSMIT = struct.Struct("<IIIBBH")


class LsBusFormatError(ValueError):
    """Bytes that are not a sequence of well-formed bus operations (names the offset and the field)."""


@dataclass(frozen=True)
class CanFrame:
    """One classic CAN data frame: 11-bit identifier, 0..8 data bytes."""

    can_id: int
    data: bytes = b""

    def __post_init__(self):
        if not 0 <= self.can_id <= 0x7FF or len(self.data) > 8:
            raise ValueError(f"not a classic CAN frame with an 11-bit id: 0x{self.can_id:X}, {len(self.data)} bytes")


@dataclass(frozen=True)
class FormatError:
    """A Format Error operation: the node could not parse ``data``."""

    data: bytes


def encode(frames: Iterable[CanFrame]) -> bytes:
    """The frames as consecutive CAN Transmit operations (standard id, data frames)."""
    return b"".join(_TRANSMIT.pack(OP_CAN_TRANSMIT, _TRANSMIT.size + len(f.data), f.can_id, 0, 0, len(f.data))
                    + bytes(f.data) for f in frames)


def decode(buffer: bytes) -> list[CanFrame | FormatError]:
    """Operations → frames and format errors, in order. Raises :class:`LsBusFormatError` on a truncated
    operation, a length that does not match the arguments, an extended/remote/over-long frame or an
    operation code other than CAN Transmit and Format Error."""
    out: list[CanFrame | FormatError] = []
    at = 0
    while at < len(buffer):
        if len(buffer) - at < _HEADER.size:
            raise LsBusFormatError(f"offset {at}: {len(buffer) - at} bytes are not an operation header")
        code, length = _HEADER.unpack_from(buffer, at)
        if length < _HEADER.size or at + length > len(buffer):
            raise LsBusFormatError(f"offset {at}: operation 0x{code:04X} declares {length} bytes, "
                                   f"{len(buffer) - at} are left")
        op = buffer[at:at + length]
        if code == OP_CAN_TRANSMIT:
            if length < _TRANSMIT.size:
                raise LsBusFormatError(f"offset {at}: CAN Transmit of {length} bytes")
            _, _, can_id, ide, rtr, n = _TRANSMIT.unpack_from(op)
            if length != _TRANSMIT.size + n or ide or rtr or n > 8 or can_id > 0x7FF:
                raise LsBusFormatError(f"offset {at}: CAN Transmit id 0x{can_id:X} ide {ide} rtr {rtr} data length "
                                       f"{n} in {length} bytes is not a classic data frame")
            out.append(CanFrame(can_id, bytes(op[_TRANSMIT.size:])))
        elif code == OP_FORMAT_ERROR:
            (n,) = struct.unpack_from("<H", op, _HEADER.size)
            out.append(FormatError(bytes(op[_HEADER.size + 2:_HEADER.size + 2 + n])))
        else:
            raise LsBusFormatError(f"offset {at}: operation code 0x{code:04X} is not CAN Transmit or Format Error")
        at += length
    return out


class CanBusSlave(FmuSlave):
    """A plant-can FMU instance in fmpy, driven at its bus terminal (FMI 3.0 Event Mode, FMI-LS-BUS):

    * construction: instantiate with event mode, initialize; the nodes' boot-up frames are in :attr:`booted`;
    * :meth:`exchange`: one Event Mode at the current time: activate ``CAN.Rx_Clock``, set ``CAN.Rx_Data``
      to the frames, update the discrete states, collect ``CAN.Tx_Data`` when ``CAN.Tx_Clock`` ticks;
    * :meth:`step`: one communication step; returns whether Tx data wait (eventHandlingNeeded).

    Args: as :class:`qomni.fmu.cosim.FmuSlave` (``start_values``: e.g. the drive data or the initial state).
    """

    def __init__(self, path, start_values: dict | None = None, start_time: float = 0.0,
                 instance_name: str = "plant_can"):
        super().__init__(path, start_values, start_time, instance_name, event_mode=True)
        self.rx_clock, self.rx_data, self.tx_clock, self.tx_data = self.refs(
            [f"{TERMINAL}.{m}" for m in ("Rx_Clock", "Rx_Data", "Tx_Clock", "Tx_Data")])
        self.fmu.updateDiscreteStates()
        self.booted = self._collect()
        self.fmu.enterStepMode()

    def _collect(self) -> list[CanFrame | FormatError]:
        if not self.fmu.getClock([self.tx_clock])[0]:
            return []
        return decode(self.fmu.getBinary([self.tx_data])[0])

    def exchange(self, frames: Iterable[CanFrame]) -> list[CanFrame | FormatError]:
        """Deliver ``frames`` (may be empty: an event without Rx, e.g. to fetch pending Tx) and return what the
        nodes transmit in this event."""
        return self.exchange_raw(encode(frames))

    def exchange_raw(self, operations: bytes | None) -> list[CanFrame | FormatError]:
        """:meth:`exchange` with the Rx_Data bytes as given (``None``: Rx_Clock stays inactive)."""
        self.fmu.enterEventMode()
        if operations is not None:
            self.fmu.setClock([self.rx_clock], [True])
            self.fmu.setBinary([self.rx_data], [bytes(operations)])
        self.fmu.updateDiscreteStates()
        out = self._collect()
        self.fmu.enterStepMode()
        return out

    def step(self, h: float) -> bool:
        """One communication step of ``h`` s; True if transmitted frames wait for an Event Mode."""
        pending = self.fmu.doStep(currentCommunicationPoint=self.time, communicationStepSize=h)[0]
        self.time += h
        return bool(pending)


__all__ = ["CanBusSlave", "CanFrame", "FormatError", "LsBusFormatError", "decode", "encode"]
