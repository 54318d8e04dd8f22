"""SDO server of the CiA 301 node (§7.2.4, expedited and segmented) on top of canopen's, with the device's
gating and early checks."""
from __future__ import annotations

from canopen import objectdictionary as od
from canopen.sdo import SdoAbortedError, SdoServer

from ..cia import (ABORT_COMMAND_SPECIFIER, ABORT_LENGTH_HIGH, ABORT_LENGTH_LOW, ABORT_READ_ONLY, OPERATIONAL,
                   PRE_OPERATIONAL)

_SDO_EXPEDITED, _SDO_SIZE_SPECIFIED = 0x02, 0x01
_SDO_SEGMENT_REQUESTS = (0x00, 0x60)     # download / upload segment (client command specifier 0, 3)
_SDO_ABORT_REQUEST = 0x80


class GatedSdoServer(SdoServer):
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
                check_length(int.from_bytes(request[4:8], "little"), size)
        super().init_download(request)


def check_length(given: int, expected: int) -> None:
    """SDO abort for a data length above or below the object's (0x06070012 / 0x06070013)."""
    if given > expected:
        raise SdoAbortedError(ABORT_LENGTH_HIGH)
    if given < expected:
        raise SdoAbortedError(ABORT_LENGTH_LOW)
