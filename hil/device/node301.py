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
* EMCY (CiA 301 §7.2.7) carries the error register 0x1001; every error code other than 0x0000 is also
  pushed onto the pre-defined error field 0x1003 (newest at sub-index 1, at most 8; writing 0 to
  sub-index 0 clears it, any other value is refused with 0x06090030).

SYNC is not subscribed here: whoever hosts the nodes (``qomni.hil.device.server``) calls, under :attr:`lock`,
:meth:`sync_receive` on every node, then the device application, then :meth:`sync_transmit`.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import canopen
from canopen import objectdictionary as od
from canopen.nmt import NmtSlave
from canopen.sdo import SdoAbortedError, SdoServer

from ..cia import (ABORT_COMMAND_SPECIFIER, ABORT_LENGTH_HIGH, ABORT_LENGTH_LOW, ABORT_NO_DATA,
                  ABORT_PDO_LENGTH, ABORT_READ_ONLY,
                  ABORT_UNSUPPORTED_ACCESS, ABORT_VALUE_HIGH, ABORT_VALUE_LOW, ABORT_VALUE_RANGE,
                  ABORT_WRITE_ONLY, EMCY_COMMUNICATION, EMCY_HEARTBEAT, EMCY_NO_ERROR, EMCY_PDO_LENGTH,
                  EMCY_RPDO_TIMEOUT, EMCY_SYNC_LENGTH, ERROR_REGISTER_COMMUNICATION, ERROR_REGISTER_GENERIC,
                  INITIALISING, NMT_PRE_OPERATIONAL, NMT_RESET_COMMUNICATION, NMT_RESET_NODE, NMT_START,
                  NMT_STOP, OPERATIONAL, PRE_OPERATIONAL, STOPPED)
from ..pdo_codec import PdoCodec, PdoMappingError, build_codec, check_entry

logger = logging.getLogger(__name__)

_NMT_TARGET = {NMT_START: OPERATIONAL, NMT_STOP: STOPPED, NMT_PRE_OPERATIONAL: PRE_OPERATIONAL}

COB_ID_INVALID = 1 << 31
_COB_ID_EXTENDED = 1 << 29

_COMM_RANGE = (0x1000, 0x2000)   # reset communication restores these (CiA 301 §7.3.2.2)
_ERROR_FIELD = 0x1003
_HEARTBEAT_CONSUMER = 0x1016
_SDO_EXPEDITED, _SDO_SIZE_SPECIFIED = 0x02, 0x01
_SDO_SEGMENT_REQUESTS = (0x00, 0x60)     # download / upload segment (client command specifier 0, 3)
_SDO_ABORT_REQUEST = 0x80


@dataclass
class _Pdo:
    number: int          # 1-based
    cob_id: int
    trans_type: int
    event_timer_ms: int
    codec: PdoCodec
    last_rx: float | None = None
    last_data: bytes | None = None


class _Nmt(NmtSlave):
    """NMT slave whose commands go to the node (reset behaviour, PDO gating)."""

    def on_command(self, can_id, data, timestamp):
        self._local_node._on_nmt_command(data)


class _GatedSdoServer(SdoServer):
    """SDO server answering only in PRE-OPERATIONAL/OPERATIONAL and only 8-byte requests.

    Beyond canopen's server: an initiate download (expedited or segmented) is checked at once for an
    existing, writable object and, where the size is indicated, for the data type's length; an
    expedited download without size indication carries the object's own length (CiA 301 §7.2.4.3.3).
    """

    def on_request(self, can_id, data, timestamp):
        node = self._node
        if len(data) != 8 or node.nmt_state not in (PRE_OPERATIONAL, OPERATIONAL):
            return
        with node.lock:
            ccs = data[0] & 0xE0
            if ccs in _SDO_SEGMENT_REQUESTS:
                if self._buffer is None:                 # no transfer in progress
                    self.abort(ABORT_COMMAND_SPECIFIER)
                    return
            elif ccs != _SDO_ABORT_REQUEST:
                self._index, self._subindex = data[1] | data[2] << 8, data[3]   # echoed by an abort
                self._buffer = None
            super().on_request(can_id, data, timestamp)

    def init_download(self, request):
        command = request[0]
        index, subindex = request[1] | request[2] << 8, request[3]
        obj = self._node._find_object(index, subindex)
        if not obj.writable:
            raise SdoAbortedError(ABORT_READ_ONLY)
        if obj.data_type in od.NUMBER_TYPES:
            size = len(obj) // 8
            if command & _SDO_EXPEDITED and not command & _SDO_SIZE_SPECIFIED and size <= 4:
                request = bytearray(request)
                request[0] = command | _SDO_SIZE_SPECIFIED | (4 - size) << 2
            elif command & _SDO_SIZE_SPECIFIED and not command & _SDO_EXPEDITED:
                _check_length(int.from_bytes(request[4:8], "little"), size)
        super().init_download(request)


def _check_length(given: int, expected: int) -> None:
    if given > expected:
        raise SdoAbortedError(ABORT_LENGTH_HIGH)
    if given < expected:
        raise SdoAbortedError(ABORT_LENGTH_LOW)


class Node301(canopen.LocalNode):
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
        self.sync_timeout = sync_timeout
        self.sdo = _GatedSdoServer(0x600 + self.id, 0x580 + self.id, self)
        self.nmt = _Nmt(self.id, self)
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
        self.powered = True
        self._compile_pdos()
        self._compile_consumers()

    # ------------------------------------------------------------------ state
    @property
    def nmt_state(self) -> int:
        """NMT state code: 0 INITIALISING, 4 STOPPED, 5 OPERATIONAL, 127 PRE-OPERATIONAL."""
        return self.nmt._state

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
                _check_length(len(data), len(obj) // 8)
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
        elif index == _ERROR_FIELD and subindex == 0 and value != 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        self.validate_write(index, subindex, value)
        self.values[(index, subindex)] = value
        if 0x1400 <= index < 0x1C00:
            self._compile_pdos()
        elif index == 0x1017 and self.nmt_state != INITIALISING:
            self.nmt.start_heartbeat(int(value))
        elif index == _ERROR_FIELD:
            self._clear_error_field()
        elif index == _HEARTBEAT_CONSUMER:
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

    # -------------------------------------------------------------- NMT
    def boot(self, application: bool = True) -> None:
        """Power-on / NMT reset: restore defaults, send the boot-up message, enter PRE-OPERATIONAL.

        Args:
            application: True for reset node (all objects), False for reset communication
                (0x1000…0x1FFF only).
        """
        with self.lock:
            self.nmt.stop_heartbeat()
            if self.nmt_state == OPERATIONAL:
                self._leave_operational()
            for key, value in self._defaults.items():
                if application or _COMM_RANGE[0] <= key[0] < _COMM_RANGE[1]:
                    self.values[key] = value
            self._sync_lost = self._rpdo_lost = self._heartbeat_lost = False
            self.values[(0x1001, 0)] = 0
            if application:
                self._clear_error_field()
            self._compile_pdos()
            self._compile_consumers()
            if application:
                self.on_reset_application()
            self.nmt.send_command(NMT_RESET_NODE)        # state INITIALISING, sends boot-up
            self.nmt.send_command(NMT_PRE_OPERATIONAL)   # starts the heartbeat producer (0x1017)

    def shutdown(self) -> None:
        """Stop the heartbeat producer (power off); the node stays attached to its network."""
        with self.lock:
            self.nmt.stop_heartbeat()

    def power_off(self) -> None:
        """Lose power (fault injection): silent on the bus, deaf to every frame, until :meth:`power_on`."""
        with self.lock:
            self.nmt.stop_heartbeat()
            if self.nmt_state == OPERATIONAL:
                self._leave_operational()
            self.nmt._state = INITIALISING
            self.powered = False
            self.on_power_off()

    def power_on(self) -> None:
        """Power returns: the node boots like at power-on (defaults, boot-up message, PRE-OPERATIONAL)."""
        with self.lock:
            self.powered = True
            self.boot(application=True)

    def on_power_off(self) -> None:
        """Hook: the node lost power (its outputs go dead)."""

    def _on_nmt_command(self, data) -> None:
        if len(data) != 2:
            return
        command, node_id = data[0], data[1]
        if node_id not in (0, self.id) or not self.powered:
            return
        with self.lock:
            if command == NMT_RESET_NODE:
                self.boot(application=True)
            elif command == NMT_RESET_COMMUNICATION:
                self.boot(application=False)
            elif command in _NMT_TARGET and self.nmt_state != INITIALISING:
                old, new = self.nmt_state, _NMT_TARGET[command]
                if old == new:
                    return
                if old == OPERATIONAL:
                    self._leave_operational()
                if new == OPERATIONAL:
                    self._sync_count = 0
                    self._last_sync = None
                    self._pending.clear()
                    for pdo in self._tpdos:
                        pdo.last_data = None
                    for pdo in self._rpdos.values():
                        pdo.last_rx = None
                self.nmt.send_command(command)

    def _leave_operational(self) -> None:
        self._pending.clear()
        self._last_sync = None
        self.on_leave_operational()

    # -------------------------------------------------------------- PDO
    def associate_network(self, network: canopen.Network) -> None:
        super().associate_network(network)
        self._subscribe_rpdos()
        self._subscribe_consumers()

    def remove_network(self) -> None:
        if self.has_network():
            for cob_id in self._subscribed:
                self.network.unsubscribe(cob_id, self._on_rpdo)
            self._subscribed = []
            for producer in self._consumers:
                self.network.unsubscribe(0x700 + producer, self._on_heartbeat)
        super().remove_network()

    def _validate_pdo_parameter(self, index: int, subindex: int, value) -> None:
        receive = index < 0x1800
        if 0x1400 <= index < 0x1600 or 0x1800 <= index < 0x1A00:          # communication parameter
            if subindex == 1:
                current = self.values[(index, 1)]
                if value & _COB_ID_EXTENDED:
                    raise SdoAbortedError(ABORT_VALUE_RANGE)
                if not value & COB_ID_INVALID:
                    if not current & COB_ID_INVALID and (value ^ current) & 0x7FF:
                        raise SdoAbortedError(ABORT_VALUE_RANGE)   # change COB-ID only while invalid
                    self._check_mapping(index + 0x200, receive)
            elif subindex == 2 and not (0 <= value <= 240 or value >= 254):
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            return
        comm = index - 0x200                                                # mapping parameter
        if comm not in self.object_dictionary:
            return
        if not self.values[(comm, 1)] & COB_ID_INVALID:
            raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)        # mapping of a valid PDO
        if subindex == 0:
            if value > 8:
                raise SdoAbortedError(ABORT_VALUE_RANGE)
            self._check_mapping(index, receive, count=value)
        else:
            if self.values[(index, 0)] != 0:
                raise SdoAbortedError(ABORT_UNSUPPORTED_ACCESS)    # sub-index 0 must be 0 first
            if value:
                try:
                    check_entry(self.object_dictionary, value, receive)
                except PdoMappingError as exc:
                    raise SdoAbortedError(exc.code) from None

    def _check_mapping(self, map_index: int, receive: bool, count: int | None = None) -> PdoCodec:
        if count is None:
            count = self.values[(map_index, 0)]
        try:
            entries = [self.values[(map_index, s)] for s in range(1, count + 1)]
            return build_codec(self.object_dictionary, entries, receive)
        except KeyError:
            raise SdoAbortedError(ABORT_PDO_LENGTH) from None
        except PdoMappingError as exc:
            raise SdoAbortedError(exc.code) from None

    def _compile_pdos(self) -> None:
        rpdos: dict[int, _Pdo] = {}
        tpdos: list[_Pdo] = []
        for base, receive, numbers in ((0x1400, True, self._pdo_numbers[0]),
                                       (0x1800, False, self._pdo_numbers[1])):
            for n in numbers:
                comm = base + n
                cob_id = self.values.get((comm, 1), COB_ID_INVALID)
                if cob_id & COB_ID_INVALID or comm + 0x200 not in self.object_dictionary:
                    continue
                try:
                    codec = self._check_mapping(comm + 0x200, receive)
                except SdoAbortedError:
                    logger.warning("node %d: %s PDO %d has an invalid mapping, not used",
                                   self.id, "receive" if receive else "transmit", n + 1)
                    continue
                pdo = _Pdo(n + 1, cob_id & 0x7FF, self.values.get((comm, 2), 255),
                           self.values.get((comm, 5), 0), codec)
                if receive:
                    rpdos[pdo.cob_id] = pdo
                else:
                    tpdos.append(pdo)
        self._rpdos, self._tpdos = rpdos, tpdos
        self._pending.clear()
        if self.has_network():
            self._subscribe_rpdos()

    def _subscribe_rpdos(self) -> None:
        for cob_id in self._subscribed:
            self.network.unsubscribe(cob_id, self._on_rpdo)
        self._subscribed = list(self._rpdos)
        for cob_id in self._subscribed:
            self.network.subscribe(cob_id, self._on_rpdo)

    def _on_rpdo(self, can_id: int, data, timestamp: float) -> None:
        with self.lock:
            if self.nmt._state != OPERATIONAL:
                return
            pdo = self._rpdos.get(can_id)
            if pdo is None:
                return
            if len(data) < pdo.codec.size:
                self.emcy_send(EMCY_PDO_LENGTH, bytes(data[:5]))
                return
            values = pdo.codec.unpack(data)
            pdo.last_rx = time.monotonic()
            if self._rpdo_lost:
                self._rpdo_lost = False
                self._maybe_clear_communication_error()
            if pdo.trans_type <= 240:
                self._pending[can_id] = (pdo, values)
            else:
                self._apply(pdo, values)

    def _apply(self, pdo: _Pdo, values: tuple) -> None:
        for key, value in zip(pdo.codec.keys, values):
            try:
                self.write_value(key[0], key[1], value)
            except SdoAbortedError as exc:
                logger.debug("node %d: RPDO %d value 0x%04X:%02X = %r rejected (0x%08X)",
                             self.id, pdo.number, key[0], key[1], value, exc.code)

    # ------------------------------------------------------------- SYNC
    def sync_receive(self, now: float) -> bool:
        """SYNC phase 1 (call with :attr:`lock` held): count the SYNC, apply buffered synchronous RPDOs.

        Args:
            now: s, a monotonic clock reading, used only for SYNC-loss supervision.
        Returns:
            True if the node is OPERATIONAL (takes part in this SYNC).
        """
        if self.nmt._state != OPERATIONAL:
            return False
        self._sync_count += 1
        self._last_sync = now
        if self._sync_lost:
            self._sync_lost = False
            self._maybe_clear_communication_error()
        if self._pending:
            for pdo, values in list(self._pending.values()):
                self._apply(pdo, values)
            self._pending.clear()
        return True

    def sync_transmit(self) -> None:
        """SYNC phase 3 (call with :attr:`lock` held): send the TPDOs due at this SYNC (OPERATIONAL only)."""
        if self.nmt._state != OPERATIONAL:
            return
        count, values, send = self._sync_count, self.values, self.network.send_message
        for pdo in self._tpdos:
            trans = pdo.trans_type
            if 1 <= trans <= 240:
                if count % trans:
                    continue
                data = pdo.codec.pack_from(values)
            else:
                data = pdo.codec.pack_from(values)
                if data == pdo.last_data:
                    continue
                pdo.last_data = data
            send(pdo.cob_id, data)

    def sync_length_error(self) -> None:
        """Report a SYNC frame with a DLC above 1 (EMCY 0x8240); the SYNC is not processed."""
        with self.lock:
            self.emcy_send(EMCY_SYNC_LENGTH)

    # ------------------------------------------------------- supervision
    def check_timeouts(self, now: float) -> bool:
        """Supervise SYNC and RPDO reception; call periodically from a watchdog thread.

        Args:
            now: s, same monotonic clock as passed to :meth:`sync_receive`.
        Returns:
            True if a loss was detected at this call.
        """
        with self.lock:
            tripped = False
            if self.nmt._state in (PRE_OPERATIONAL, OPERATIONAL):
                for producer, entry in self._consumers.items():
                    if entry[1] is not None and now - entry[1] > entry[0]:
                        entry[1] = None
                        self._heartbeat_lost = True
                        self._communication_lost(EMCY_HEARTBEAT, bytes([producer]))
                        tripped = True
            if self.nmt._state != OPERATIONAL:
                return tripped
            if self.sync_timeout is not None and self._last_sync is not None:
                period = self.values.get((0x1006, 0), 0) * 1e-6
                if now - self._last_sync > max(self.sync_timeout, self.SYNC_LOSS_CYCLES * period):
                    self._last_sync = None
                    self._sync_lost = True
                    self._communication_lost(EMCY_COMMUNICATION)
                    tripped = True
            # The RPDO deadline never trips before the node's SYNC-loss time: a lock-step host sets a
            # long sync_timeout because a loaded machine may pause its master, which is no bus fault.
            floor = self.sync_timeout or 0.0
            for pdo in self._rpdos.values():
                if pdo.event_timer_ms and pdo.last_rx is not None and \
                        now - pdo.last_rx > max(pdo.event_timer_ms * 1e-3, floor):
                    pdo.last_rx = None
                    self._rpdo_lost = True
                    self._communication_lost(EMCY_RPDO_TIMEOUT)
                    tripped = True
            return tripped

    def _communication_lost(self, code: int, data: bytes = b"") -> None:
        self.values[(0x1001, 0)] |= ERROR_REGISTER_GENERIC | ERROR_REGISTER_COMMUNICATION
        logger.warning("node %d: communication lost (EMCY 0x%04X)", self.id, code)
        self.emcy_send(code, data)
        self.on_communication_lost(code)

    def _maybe_clear_communication_error(self) -> None:
        if not (self._sync_lost or self._rpdo_lost or self._heartbeat_lost) and self.values[(0x1001, 0)]:
            self.values[(0x1001, 0)] &= ~(ERROR_REGISTER_GENERIC | ERROR_REGISTER_COMMUNICATION)
            self.emcy_send(EMCY_NO_ERROR)

    # ---------------------------------------------------- heartbeat consumer
    def _compile_consumers(self) -> None:
        if _HEARTBEAT_CONSUMER not in self.object_dictionary:
            return
        consumers: dict[int, list] = {}
        for sub in range(1, 128):
            entry = self.values.get((_HEARTBEAT_CONSUMER, sub))
            if entry is None:
                break
            producer, time_ms = (entry >> 16) & 0xFF, entry & 0xFFFF
            if 1 <= producer <= 127 and time_ms:
                consumers[producer] = [time_ms * 1e-3, None]
        if self.has_network():
            for producer in self._consumers:
                self.network.unsubscribe(0x700 + producer, self._on_heartbeat)
        self._consumers = consumers
        if self._heartbeat_lost:
            self._heartbeat_lost = False
            self._maybe_clear_communication_error()
        if self.has_network():
            self._subscribe_consumers()

    def _subscribe_consumers(self) -> None:
        for producer in self._consumers:
            self.network.subscribe(0x700 + producer, self._on_heartbeat)

    def _on_heartbeat(self, can_id: int, data, timestamp: float) -> None:
        if len(data) != 1:
            return
        with self.lock:
            entry = self._consumers.get(can_id - 0x700)
            if entry is None:
                return
            entry[1] = time.monotonic()
            if self._heartbeat_lost and all(e[1] is not None for e in self._consumers.values()):
                self._heartbeat_lost = False
                self._maybe_clear_communication_error()

    # ------------------------------------------------------------- EMCY
    def emcy_send(self, code: int, data: bytes = b"") -> None:
        """Send an EMCY frame (CiA 301 §7.2.7) with the current error register; not in STOPPED.

        A non-zero ``code`` is also recorded in the pre-defined error field 0x1003 (if the node has it).
        """
        if code and (_ERROR_FIELD, 1) in self.values:
            size = 1
            while (_ERROR_FIELD, size + 1) in self.values:
                size += 1
            for sub in range(size, 1, -1):
                self.values[(_ERROR_FIELD, sub)] = self.values[(_ERROR_FIELD, sub - 1)]
            self.values[(_ERROR_FIELD, 1)] = code
            self.values[(_ERROR_FIELD, 0)] = min(self.values[(_ERROR_FIELD, 0)] + 1, size)
        if self.nmt._state in (PRE_OPERATIONAL, OPERATIONAL) and self.has_network():
            self.emcy.send(code, self.values.get((0x1001, 0), 0), data)

    def _clear_error_field(self) -> None:
        for key in self.values:
            if key[0] == _ERROR_FIELD:
                self.values[key] = 0
