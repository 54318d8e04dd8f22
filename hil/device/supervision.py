"""Supervision service of the CiA 301 node: SYNC loss, RPDO deadline monitoring (event timer, §7.5.2.35)
and the heartbeat consumer (0x1016, §7.2.8.3.2.1); each raises its EMCY and sets the communication bit
of the error register."""
from __future__ import annotations

import logging
import time


from ..cia import (CONSUMER_HEARTBEAT_TIME, EMCY_COMMUNICATION, EMCY_HEARTBEAT, EMCY_NO_ERROR,
                   EMCY_RPDO_TIMEOUT, ERROR_REGISTER_COMMUNICATION, ERROR_REGISTER_GENERIC, OPERATIONAL,
                   PRE_OPERATIONAL)

logger = logging.getLogger(__name__)


class SupervisionService:
    """Timeouts of SYNC, RPDOs and consumed heartbeats; mixed into :class:`~.node301.Node301`."""

    def check_timeouts(self, now: float) -> bool:
        """Supervise SYNC and RPDO reception; call periodically from a watchdog thread.

        Args:
            now: s, same monotonic clock as passed to :meth:`sync_receive`.
        Returns:
            True if a loss was detected at this call.
        """
        with self.lock:
            tripped = False
            if self.nmt_state in (PRE_OPERATIONAL, OPERATIONAL):
                for producer, entry in self._consumers.items():
                    if entry[1] is not None and now - entry[1] > entry[0]:
                        entry[1] = None
                        self._heartbeat_lost = True
                        self._communication_lost(EMCY_HEARTBEAT, bytes([producer]))
                        tripped = True
            if self.nmt_state != OPERATIONAL:
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

    def _compile_consumers(self) -> None:
        if CONSUMER_HEARTBEAT_TIME not in self.object_dictionary:
            return
        consumers: dict[int, list] = {}
        for sub in range(1, 128):
            entry = self.values.get((CONSUMER_HEARTBEAT_TIME, sub))
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
