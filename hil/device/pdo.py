"""PDO service of the CiA 301 node (§7.2.2): PDOs compiled from the communication/mapping objects
0x1400/0x1600 (RPDO) and 0x1800/0x1A00 (TPDO), mapping changes by SDO per the CiA 301 procedure, RPDOs
latched until the SYNC, TPDOs sent on the SYNC per their transmission type, only in OPERATIONAL."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import canopen
from canopen.sdo import SdoAbortedError

from ..cia import (ABORT_PDO_LENGTH, ABORT_UNSUPPORTED_ACCESS, ABORT_VALUE_RANGE, COB_ID_EXTENDED,
                   COB_ID_INVALID, EMCY_PDO_LENGTH, EMCY_SYNC_LENGTH, OPERATIONAL)
from ..virtual_bus import data_frame
from ..pdo_codec import PdoCodec, PdoMappingError, build_codec, check_entry

logger = logging.getLogger(__name__)


@dataclass
class _Pdo:
    number: int          # 1-based
    cob_id: int
    trans_type: int
    event_timer_ms: int
    codec: PdoCodec
    last_rx: float | None = None
    last_data: bytes | None = None


class PdoService:
    """RPDO reception, SYNC latch and TPDO transmission; mixed into :class:`~.node301.Node301`."""

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
                if value & COB_ID_EXTENDED:
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
            if self.nmt_state != OPERATIONAL:
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

    def sync_receive(self, now: float) -> bool:
        """SYNC phase 1 (call with :attr:`lock` held): count the SYNC, apply buffered synchronous RPDOs.

        Args:
            now: s, a monotonic clock reading, used only for SYNC-loss supervision.
        Returns:
            True if the node is OPERATIONAL (takes part in this SYNC).
        """
        if self.nmt_state != OPERATIONAL:
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
        if self.nmt_state != OPERATIONAL:
            return
        count, values, network = self._sync_count, self.values, self.network
        bus, lock = network.bus, network.send_lock
        send_frame = getattr(bus, "send_frame", None)       # the in-process bus's frame lane
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
            with lock:
                if send_frame is not None:
                    send_frame(pdo.cob_id, data)
                else:
                    bus.send(data_frame(pdo.cob_id, data))     # canopen's send_message, less its checks

    def sync_length_error(self) -> None:
        """Report a SYNC frame with a DLC above 1 (EMCY 0x8240); the SYNC is not processed."""
        with self.lock:
            self.emcy_send(EMCY_SYNC_LENGTH)
