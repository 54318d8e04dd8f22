"""EMCY producer of the CiA 301 node (§7.2.7): the error register 0x1001 in every message and the
pre-defined error field 0x1003 (newest at sub-index 1, at most 8)."""
from __future__ import annotations


from ..cia import OPERATIONAL, PRE_DEFINED_ERROR_FIELD, PRE_OPERATIONAL


class EmcyService:
    """EMCY messages and the error field; mixed into :class:`~.node301.Node301`."""

    def emcy_send(self, code: int, data: bytes = b"") -> None:
        """Send an EMCY frame (CiA 301 §7.2.7) with the current error register; not in STOPPED.

        A non-zero ``code`` is also recorded in the pre-defined error field 0x1003 (if the node has it).
        """
        if code and (PRE_DEFINED_ERROR_FIELD, 1) in self.values:
            size = 1
            while (PRE_DEFINED_ERROR_FIELD, size + 1) in self.values:
                size += 1
            for sub in range(size, 1, -1):
                self.values[(PRE_DEFINED_ERROR_FIELD, sub)] = self.values[(PRE_DEFINED_ERROR_FIELD, sub - 1)]
            self.values[(PRE_DEFINED_ERROR_FIELD, 1)] = code
            self.values[(PRE_DEFINED_ERROR_FIELD, 0)] = min(self.values[(PRE_DEFINED_ERROR_FIELD, 0)] + 1, size)
        if self.nmt_state in (PRE_OPERATIONAL, OPERATIONAL) and self.has_network():
            self.emcy.send(code, self.values.get((0x1001, 0), 0), data)

    def _clear_error_field(self) -> None:
        for key in self.values:
            if key[0] == PRE_DEFINED_ERROR_FIELD:
                self.values[key] = 0
