"""SDO server of the CiA 301 node (§7.2.4: expedited, segmented and block transfer) on top of canopen's,
with the device's gating and early checks; the block protocol is :mod:`.sdo_block`."""
from __future__ import annotations

from canopen import objectdictionary as od
from canopen.sdo import SdoAbortedError, SdoServer

from .sdo_block import BlockServer
from ..cia import (ABORT_COMMAND_SPECIFIER, ABORT_LENGTH_HIGH, ABORT_LENGTH_LOW, ABORT_READ_ONLY, OPERATIONAL,
                   PRE_OPERATIONAL)

_SDO_EXPEDITED, _SDO_SIZE_SPECIFIED = 0x02, 0x01
_SDO_SEGMENT_REQUESTS = (0x00, 0x60)     # download / upload segment (client command specifier 0, 3)
_SDO_ABORT_REQUEST = 0x80
_SDO_BLOCK_UPLOAD, _SDO_BLOCK_DOWNLOAD = 0xA0, 0xC0   # client command specifiers 5, 6


class GatedSdoServer(SdoServer):
    """SDO server answering only in PRE-OPERATIONAL/OPERATIONAL and only 8-byte requests.

    Beyond canopen's server: an initiate download (expedited or segmented) is checked at once for an
    existing, writable object and, where the size is indicated, for the data type's length; an
    expedited download without size indication carries the object's own length (CiA 301 §7.2.4.3.3).
    Block download and upload (:mod:`.sdo_block`) with the same checks.
    """

    def __init__(self, rx_cobid, tx_cobid, node):
        super().__init__(rx_cobid, tx_cobid, node)
        self.block = BlockServer(self)

    def on_request(self, can_id, data, timestamp):
        node = self._node
        if len(data) != 8 or node.nmt_state not in (PRE_OPERATIONAL, OPERATIONAL):
            return
        with node.lock:
            if self.block.phase is not None and self._on_block_frame(data):
                return
            ccs = data[0] & 0xE0
            if ccs in (_SDO_BLOCK_UPLOAD, _SDO_BLOCK_DOWNLOAD):
                self._index, self._subindex = data[1] | data[2] << 8, data[3]
                self._buffer = None
                try:
                    if ccs == _SDO_BLOCK_DOWNLOAD and not data[0] & 0x01:
                        self.block.initiate_download(data)
                    elif ccs == _SDO_BLOCK_UPLOAD and not data[0] & 0x03:
                        if not self.block.initiate_upload(data):
                            self.init_upload(data)     # size ≤ protocol switch threshold
                    else:
                        raise SdoAbortedError(ABORT_COMMAND_SPECIFIER)
                except SdoAbortedError as exc:
                    self.block.reset()
                    self.abort(exc.code)
                return
            if ccs in _SDO_SEGMENT_REQUESTS:
                if self._buffer is None:                 # no transfer in progress
                    self.abort(ABORT_COMMAND_SPECIFIER)
                    return
            elif ccs != _SDO_ABORT_REQUEST:
                self._index, self._subindex = data[1] | data[2] << 8, data[3]   # echoed by an abort
                self._buffer = None
            super().on_request(can_id, data, timestamp)

    def abort(self, abort_code=0x08000000):
        """Send an abort with the transfer's multiplexer; 0x0000:0 where no request has named one yet (a
        segment request before any initiate)."""
        if self._index is None:
            self._index, self._subindex = 0, 0
        super().abort(abort_code)

    def _on_block_frame(self, data) -> bool:
        """A frame during a block transfer; False if it ends the transfer and is a request of its own."""
        block = self.block
        if data[0] == _SDO_ABORT_REQUEST:                # the client aborts (no segment has sequence 0)
            block.reset()
            self.request_aborted(data)
            return True
        if block.phase.startswith("upload") and data[0] & 0xE0 != _SDO_BLOCK_UPLOAD:
            block.reset()                                # the client has moved on
            return False
        try:
            if block.phase.startswith("download"):
                block.on_download(data)
            else:
                block.on_upload(data)
        except SdoAbortedError as exc:
            block.reset()
            self.abort(exc.code)
        return True

    def checked_object(self, index: int, subindex: int, writable: bool = False):
        """The object as a download's initiate request finds it (aborts: missing, read-only)."""
        obj = self._node._find_object(index, subindex)
        if writable and not obj.writable:
            raise SdoAbortedError(ABORT_READ_ONLY)
        return obj

    @staticmethod
    def check_size(obj, size: int) -> None:
        """Abort where an indicated size does not fit a numeric object's data type."""
        if obj.data_type in od.NUMBER_TYPES:
            check_length(size, len(obj) // 8)

    def init_download(self, request):
        command = request[0]
        index, subindex = request[1] | request[2] << 8, request[3]
        obj = self.checked_object(index, subindex, writable=True)
        if obj.data_type in od.NUMBER_TYPES:
            size = len(obj) // 8
            if command & _SDO_EXPEDITED and not command & _SDO_SIZE_SPECIFIED and size <= 4:
                request = bytearray(request)
                request[0] = command | _SDO_SIZE_SPECIFIED | (4 - size) << 2
            elif command & _SDO_SIZE_SPECIFIED and not command & _SDO_EXPEDITED:
                self.check_size(obj, int.from_bytes(request[4:8], "little"))
        super().init_download(request)


def check_length(given: int, expected: int) -> None:
    """SDO abort for a data length above or below the object's (0x06070012 / 0x06070013)."""
    if given > expected:
        raise SdoAbortedError(ABORT_LENGTH_HIGH)
    if given < expected:
        raise SdoAbortedError(ABORT_LENGTH_LOW)
