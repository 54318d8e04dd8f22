"""NMT slave service of the CiA 301 node (§7.2.8, §7.3.2.2): boot-up, reset node / reset communication
restoring the defaults, state changes on NMT commands, power loss and return (fault injection)."""
from __future__ import annotations

from canopen.nmt import NmtSlave

from ..cia import (INITIALISING, NMT_PRE_OPERATIONAL, NMT_RESET_COMMUNICATION, NMT_RESET_NODE, NMT_START,
                   NMT_STOP, OPERATIONAL, PRE_OPERATIONAL, STOPPED)

_NMT_TARGET = {NMT_START: OPERATIONAL, NMT_STOP: STOPPED, NMT_PRE_OPERATIONAL: PRE_OPERATIONAL}
_COMM_RANGE = (0x1000, 0x2000)   # reset communication restores these (CiA 301 §7.3.2.2)


class NodeNmt(NmtSlave):
    """NMT slave whose commands go to the node (reset behaviour, PDO gating)."""

    def on_command(self, can_id, data, timestamp):
        self._local_node._on_nmt_command(data)


class NmtService:
    """The node's NMT state machine; mixed into :class:`~.node301.Node301`."""

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
            self.powered = False                         # nmt_state reads INITIALISING from now on
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
