"""CiA 301 slave node on top of :class:`canopen.LocalNode`: the shared machinery of the drive and encoder.

canopen's LocalNode provides the object dictionary (from an EDS), the SDO server, the NMT state and
heartbeat producer and the EMCY producer. This module adds what a real device does beyond that:

* NMT (CiA 301 §7.2.8): boot-up message, reset node / reset communication restore the defaults,
  PDOs only in OPERATIONAL, SDO only in PRE-OPERATIONAL and OPERATIONAL.
* PDOs (CiA 301 §7.2.2) from the communication/mapping objects 0x1400/0x1600 (RPDO) and 0x1800/0x1A00
  (TPDO) of the EDS, so another mapping file just works; mapping changes by SDO follow the CiA 301
  procedure (disable via COB-ID bit 31, sub-index 0 = 0, entries, sub-index 0 = n, enable).
  Synchronous RPDOs (transmission type 0…240) are buffered and applied at the next SYNC; event-driven
  ones (254/255) at once. TPDOs are sent from :meth:`Node301.sync_transmit`: type 1…240 every n-th
  SYNC, type 0/254/255 at a SYNC when their data changed.
* SDO server (CiA 301 §7.2.4, expedited and segmented) with the standard abort codes: object does not
  exist 0x06020000, sub-index does not exist 0x06090011, read of a write-only object 0x06010001, write
  to a read-only one 0x06010002 (refused at the initiate request, also for segmented transfers), data
  type length too high 0x06070012 / too low 0x06070013, value above/below the EDS HighLimit/LowLimit
  0x06090031 / 0x06090032, any other value the device refuses 0x06090030.
* Supervision: SYNC loss (no SYNC for max(``sync_timeout``, 5·0x1006)) and RPDO deadline monitoring
  (RPDO event timer, 0x1400 sub-index 5, CiA 301 §7.5.2.35) raise EMCY 0x8100 / 0x8250; the heartbeat
  consumer (0x1016, CiA 301 §7.2.8.3.2.1: ``node_id << 16 | time_ms`` per sub-index; monitoring starts
  with the first heartbeat of that node) raises EMCY 0x8130 when a heartbeat is overdue. Each sets the
  communication bit of the error register 0x1001 and calls :meth:`Node301.on_communication_lost`.
  Malformed frames (wrong DLC) are dropped; short RPDOs raise EMCY 0x8210, long SYNCs EMCY 0x8240.
* SYNC counter (0x1019, CiA 301 §7.2.5): a SYNC of 0 or 1 data byte is taken whatever 0x1019 holds (a
  stricter device raises EMCY 0x8240 where the length is not the one 0x1019 sets); 0x1019 takes 0 or
  2…240 (else 0x06090030) and changes only while 0x1006 is 0 (else 0x08000022).
* EMCY (CiA 301 §7.2.7) carries the error register 0x1001; every error code other than 0x0000 is also
  pushed onto the pre-defined error field 0x1003 (newest at sub-index 1, at most 8; writing 0 to
  sub-index 0 clears it, any other value is refused with 0x06090030).

SYNC is not subscribed here: whoever hosts the nodes (``qomni.hil.device.server``) calls, under :attr:`lock`,
:meth:`sync_receive` on every node, then the device application, then :meth:`sync_transmit`.
"""
from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import canopen
from canopen import objectdictionary as od
from canopen.nmt import NMT_STATES
from canopen.sdo import SdoAbortedError

from ..cia import (ABORT_DEVICE_STATE, ABORT_NO_DATA, ABORT_READ_ONLY, ABORT_SUBINDEX_MISSING, ABORT_VALUE_HIGH,
                   ABORT_VALUE_LOW, ABORT_VALUE_RANGE, ABORT_WRITE_ONLY, COMMUNICATION_CYCLE_PERIOD,
                   CONSUMER_HEARTBEAT_TIME, INITIALISING, PRE_DEFINED_ERROR_FIELD, SYNC_COUNTER_OVERFLOW,
                   valid_sync_counter)
from .emcy import EmcyService
from .nmt import NmtService, NodeNmt
from .pdo import PdoService, _Pdo
from .sdo_server import GatedSdoServer, check_length
from .supervision import SupervisionService

logger = logging.getLogger(__name__)

#: canopen's NMT state names (``NmtBase.state``) → CiA 301 state codes.
_STATE_CODES = {name: code for code, name in NMT_STATES.items()}


class Node301(NmtService, PdoService, SupervisionService, EmcyService, canopen.LocalNode):
    """A CiA 301 device built from an EDS file.

    Object values live in one store (``(index, subindex) → value``) initialised from the EDS
    (ParameterValue, else DefaultValue); SDO reads/writes, PDOs and the application all use it.

    Args:
        node_id: 1…127.
        eds: path of the EDS/DCF file (CiA 306), or a :class:`canopen.ObjectDictionary`.
        lock: lock shared with whoever drives the node (all entry points take it); a new RLock if None.
        sync_timeout: s, minimum SYNC-loss time; ``None`` disables SYNC-loss supervision.
    Raises:
        ValueError: node_id out of range.
    """

    #: SYNC loss is declared after max(sync_timeout, SYNC_LOSS_CYCLES · 0x1006).
    SYNC_LOSS_CYCLES = 5

    def __init__(self, node_id: int, eds: str | Path | od.ObjectDictionary, *,
                 lock: threading.RLock | None = None, sync_timeout: float | None = 0.1):
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id must be 1…127, got {node_id}")
        super().__init__(node_id, eds if isinstance(eds, od.ObjectDictionary) else str(eds))
        self.lock = lock if lock is not None else threading.RLock()
        self.powered = True
        self.sync_timeout = sync_timeout
        self.sdo = GatedSdoServer(0x600 + self.id, 0x580 + self.id, self)
        self.nmt = NodeNmt(self.id, self)
        self._defaults: dict[tuple[int, int], Any] = {}
        for obj in self.object_dictionary.values():
            for var in ([obj] if isinstance(obj, od.ODVariable) else obj.values()):
                value = var.value if var.value is not None else var.default
                if value is not None:
                    self._defaults[(var.index, var.subindex)] = value
        self.values: dict[tuple[int, int], Any] = dict(self._defaults)
        self._pdo_numbers = (
            [n for n in range(512) if 0x1400 + n in self.object_dictionary],
            [n for n in range(512) if 0x1800 + n in self.object_dictionary])
        self._rpdos: dict[int, _Pdo] = {}
        self._tpdos: list[_Pdo] = []
        self._subscribed: list[int] = []
        self._pending: dict[int, tuple[_Pdo, tuple]] = {}
        self._sync_count = 0
        self._last_sync: float | None = None
        self._sync_lost = False
        self._rpdo_lost = False
        self._heartbeat_lost = False
        self._consumers: dict[int, list] = {}       # producer id → [timeout s, last heartbeat | None]
        self._compile_pdos()
        self._compile_consumers()

    # ------------------------------------------------------------------ state
    @property
    def nmt_state(self) -> int:
        """NMT state code: 0 INITIALISING, 4 STOPPED, 5 OPERATIONAL, 127 PRE-OPERATIONAL; INITIALISING while
        the node has no power (:meth:`power_off`)."""
        if not self.powered:
            return INITIALISING
        return _STATE_CODES.get(self.nmt.state, INITIALISING)

    @property
    def sync_count(self) -> int:
        """SYNCs received since the last NMT start."""
        return self._sync_count

    def set_default(self, index: int, subindex: int, value) -> None:
        """Set a parameter as the device's stored default (survives NMT resets) and as current value.

        Raises:
            SdoAbortedError: the value is rejected by the device (e.g. out of range).
        """
        with self.lock:
            self.write_value(index, subindex, value)
            self._defaults[(index, subindex)] = value

    # ------------------------------------------------------- object access
    def _find_object(self, index: int, subindex: int):
        """The object (index, subindex) as an SDO server looks it up (CiA 301 §7.2.4.3.17): a missing index
        aborts 0x06020000, a sub-index other than 0 of a simple variable (VAR) 0x06090011 like a missing
        sub-index of a record or array (canopen's LocalNode would answer with the variable itself)."""
        obj = super()._find_object(index, subindex)
        if isinstance(self.object_dictionary[index], od.ODVariable) and subindex != 0:
            raise SdoAbortedError(ABORT_SUBINDEX_MISSING)
        return obj

    def get_data(self, index: int, subindex: int, check_readable: bool = False) -> bytes:
        """Encoded value of an object (SDO upload). Raises SdoAbortedError like a device would."""
        with self.lock:
            obj = self._find_object(index, subindex)
            if check_readable and not obj.readable:
                raise SdoAbortedError(ABORT_WRITE_ONLY)
            try:
                value = self.values[(obj.index, obj.subindex)]
            except KeyError:
                raise SdoAbortedError(ABORT_NO_DATA) from None
            return obj.encode_raw(value)

    def set_data(self, index: int, subindex: int, data: bytes, check_writable: bool = False) -> None:
        """Decode and write an object (SDO download). Raises SdoAbortedError like a device would."""
        with self.lock:
            obj = self._find_object(index, subindex)
            if check_writable and not obj.writable:
                raise SdoAbortedError(ABORT_READ_ONLY)
            if obj.data_type in od.NUMBER_TYPES:
                check_length(len(data), len(obj) // 8)
            value = obj.decode_raw(bytes(data))
            if obj.max is not None and value > obj.max:
                raise SdoAbortedError(ABORT_VALUE_HIGH)
            if obj.min is not None and value < obj.min:
                raise SdoAbortedError(ABORT_VALUE_LOW)
            self.write_value(obj.index, obj.subindex, value)

    def write_value(self, index: int, subindex: int, value) -> None:
        """Write a decoded value as the device does for SDO and PDO writes: validate, store, react.

        Raises:
            SdoAbortedError: the device rejects the value (the store is unchanged).
        """
        if 0x1400 <= index < 0x1C00:
            self._validate_pdo_parameter(index, subindex, value)
        elif index == PRE_DEFINED_ERROR_FIELD and subindex == 0 and value != 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        elif index == SYNC_COUNTER_OVERFLOW:
            if not valid_sync_counter(value):           # reserved values (CiA 301 §7.5.2.20)
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            if value != self.values.get((index, 0)) and self.values.get((COMMUNICATION_CYCLE_PERIOD, 0)):
                raise SdoAbortedError(ABORT_DEVICE_STATE)   # only while 0x1006 is 0
        self.validate_write(index, subindex, value)
        self.values[(index, subindex)] = value
        if 0x1400 <= index < 0x1C00:
            self._compile_pdos()
        elif index == 0x1017 and self.nmt_state != INITIALISING:
            self.nmt.start_heartbeat(int(value))
        elif index == PRE_DEFINED_ERROR_FIELD:
            self._clear_error_field()
        elif index == CONSUMER_HEARTBEAT_TIME:
            self._compile_consumers()
        self.on_write(index, subindex, value)

    # ------------------------------------------------ application hooks
    def validate_write(self, index: int, subindex: int, value) -> None:
        """Hook: raise SdoAbortedError to reject a write (default accepts everything)."""

    def on_write(self, index: int, subindex: int, value) -> None:
        """Hook: react to a stored write (SDO, or RPDO when applied)."""

    def on_reset_application(self) -> None:
        """Hook: NMT reset node, after the defaults are restored."""

    def on_leave_operational(self) -> None:
        """Hook: the node leaves NMT OPERATIONAL (stop, pre-operational, reset)."""

    def on_communication_lost(self, emcy_code: int) -> None:
        """Hook: SYNC loss (0x8100) or RPDO timeout (0x8250) was detected."""


