"""What the client watches besides the cycle: boot-up messages (a node lost power or was reset), EMCY, and
the causes it names when the cycle fails (silent nodes, EMCY since the last complete cycle, a faulted
drive's error code 0x603F)."""
from __future__ import annotations

import logging
import time

from ..cia import EMCY_BUS_OFF, ERROR_CODE
from ..layout import DRIVE_NODE_IDS

logger = logging.getLogger(__name__)


class ClientSupervision:
    """Node supervision of :class:`~.client.VehicleClient` (mixed in)."""

    def _error_code(self, node_id: int) -> str:
        """`` (error code 0x….)`` of a drive's 0x603F, read by SDO as a master does when a drive leaves
        OPERATION ENABLED; '' if it does not answer."""
        node = self.drives[DRIVE_NODE_IDS.index(node_id)]
        timeout, node.sdo.RESPONSE_TIMEOUT = node.sdo.RESPONSE_TIMEOUT, min(node.sdo.RESPONSE_TIMEOUT, 0.1)
        try:
            code = int(node.sdo[ERROR_CODE].raw)
        except Exception:                                 # noqa: BLE001 - the report must not fail
            return ""
        finally:
            node.sdo.RESPONSE_TIMEOUT = timeout
        return f" (error code 0x{code:04X}{' bus-off' if code == EMCY_BUS_OFF else ''})" if code else ""

    def _lost_cause(self) -> str:
        """Why TPDOs stopped, where the bus tells: a node's boot-up (power loss or reset) or EMCY since the
        last complete cycle (bus-off 0x8140 named as such); '' when the bus does not say."""
        if self._rebooted:
            return (f"; node(s) {sorted(set(self._rebooted))} sent a boot-up message (power loss or reset): "
                    "their configuration is gone")
        since = [(n, c) for n, c, _, t in self.emcy if c and t >= self._last_good - 0.01]
        if not since:
            return ""
        codes = ", ".join(f"node {n}: 0x{c:04X}{' (bus-off)' if c == EMCY_BUS_OFF else ''}" for n, c in since[-12:])
        return f"; EMCY since the last complete cycle: {codes}"

    def _recent_emcy(self, seconds: float = 2.0) -> str:
        now = time.time()
        recent = [(n, c) for n, c, _, t in self.emcy[-12:] if c and now - t < seconds]
        return "; EMCY " + ", ".join(f"node {n}: 0x{c:04X}" for n, c in recent) if recent else ""

    def _watch_nodes(self) -> None:
        """Boot-up and EMCY supervision (module docstring)."""
        def on_state(node_id):
            def callback(state):
                if state == 0 and self._operational:
                    self._rebooted.append(node_id)
            return callback

        def on_emcy(node_id):
            def callback(error):
                self.emcy.append((node_id, error.code, error.register, time.time()))
                if error.code:
                    logger.warning("EMCY from node %d: 0x%04X (%s)", node_id, error.code, error.get_desc())
            return callback

        for node in self.drives + self.encoders:
            node.nmt.add_heartbeat_callback(on_state(node.id))
            node.emcy.add_callback(on_emcy(node.id))
