"""SDO block transfer, server side (CiA 301 §7.2.4.3.9–16): block download and block upload with CRC.

Download: initiate (client 0xC0 | CRC 0x04 | size 0x02) → 0xA0 | CRC, block size 127; sub-blocks of
segments numbered 1…blksize (bit 7 on the last segment of the transfer), each acknowledged with 0xA2,
the last in-order sequence number and the next block size (a segment out of order is dropped and the
client repeats from the acknowledged one); end (0xC1 | n << 2, CRC) → the data, less the n unused bytes of
the last segment, is checked against the CRC and written like a segmented download, then 0xA1.

Upload: initiate (0xA0 | CRC, block size, protocol switch threshold) → 0xC6, size (or, when the size is
at most the threshold, the expedited/segmented upload response: CiA 301 allows the switch); start (0xA3)
→ a sub-block; each acknowledgement (0xA2, ackseq, blksize) moves on past the acknowledged segments (a
short ackseq repeats the rest); all acknowledged → end (0xC1 | n << 2, CRC); the client's 0xA1 closes.

CRC: CRC-16-CCITT (XMODEM), canopen's :class:`canopen.sdo.base.CrcXmodem`. Aborts: 0x05040002 block size
invalid (0 or > 127), 0x05040003 invalid sequence number, 0x05040004 CRC error, the object's own aborts.
"""
from __future__ import annotations

import struct

from canopen.sdo import SdoAbortedError
from canopen.sdo.base import CrcXmodem

ABORT_BLOCK_SIZE, ABORT_SEQUENCE, ABORT_CRC = 0x05040002, 0x05040003, 0x05040004
BLOCK_SIZE = 127
_CRC, _SIZE, _LAST = 0x04, 0x02, 0x80


def crc16(data: bytes) -> int:
    """CRC-16-CCITT of ``data`` as CiA 301 block transfer uses it."""
    crc = CrcXmodem()
    crc.process(data)
    return crc.final()


class BlockServer:
    """State of one block transfer of an SDO server (:class:`~.sdo_server.GatedSdoServer`).

    ``phase``: None (idle), 'download', 'download-end', 'upload-start', 'upload', 'upload-end'.
    """

    def __init__(self, server):
        self.server = server
        self.phase = None

    def reset(self) -> None:
        self.phase = None

    # ---------------------------------------------------------- download
    def initiate_download(self, request: bytes) -> None:
        """Client 0xC0: check the object, answer 0xA4 with the block size."""
        command = request[0]
        index, subindex = struct.unpack_from("<HB", request, 1)
        obj = self.server.checked_object(index, subindex, writable=True)
        if command & _SIZE:
            size = struct.unpack_from("<I", request, 4)[0]
            self.server.check_size(obj, size)
        self.crc = bool(command & _CRC)
        self.data = bytearray()
        self.ackseq = 0
        self.phase = "download"
        self.server.send_response(struct.pack("<BHBB3x", 0xA0 | _CRC, index, subindex, BLOCK_SIZE))

    def on_download(self, frame: bytes) -> None:
        """A frame while downloading: a segment, or the end request after the last block."""
        if self.phase == "download-end":
            if frame[0] & 0xE3 != 0xC1:
                raise SdoAbortedError(0x05040001)
            self._end_download(frame)
            return
        seqno, last = frame[0] & 0x7F, frame[0] & _LAST
        if seqno == 0:
            raise SdoAbortedError(ABORT_SEQUENCE)
        if seqno == self.ackseq + 1:
            self.ackseq = seqno
            self.data.extend(frame[1:8])
        if last or seqno == BLOCK_SIZE:
            done = last and seqno == self.ackseq
            self.server.send_response(struct.pack("<BBB5x", 0xA2, self.ackseq, BLOCK_SIZE))
            self.ackseq = 0
            if done:
                self.phase = "download-end"

    def _end_download(self, frame: bytes) -> None:
        unused = (frame[0] >> 2) & 0x7
        if unused:
            del self.data[-unused:]
        if self.crc and struct.unpack_from("<H", frame, 1)[0] != crc16(bytes(self.data)):
            raise SdoAbortedError(ABORT_CRC)
        self.phase = None
        server = self.server
        server._node.set_data(server._index, server._subindex, bytes(self.data), check_writable=True)
        server.send_response(b"\xA1" + bytes(7))

    # ------------------------------------------------------------ upload
    def initiate_upload(self, request: bytes) -> bool:
        """Client 0xA0: answer 0xC6 + size, or return False where the size is at most the protocol
        switch threshold (the caller answers with a normal upload)."""
        index, subindex, blksize, threshold = struct.unpack_from("<HBBB", request, 1)
        if not 0 < blksize <= BLOCK_SIZE:
            raise SdoAbortedError(ABORT_BLOCK_SIZE)
        data = self.server._node.get_data(index, subindex, check_readable=True)
        if threshold and len(data) <= threshold:
            return False
        self.crc = bool(request[0] & _CRC)
        self.data, self.blksize, self.sent_from, self.phase = bytes(data), blksize, 0, "upload-start"
        self.server.send_response(struct.pack("<BHBI", 0xC0 | _CRC | _SIZE, index, subindex, len(data)))
        return True

    def on_upload(self, frame: bytes) -> None:
        """Client start (0xA3), acknowledgement (0xA2) or end (0xA1) of a block upload."""
        cs = frame[0] & 0x03
        if frame[0] & 0xE0 != 0xA0:
            raise SdoAbortedError(0x05040001)
        if cs == 3 and self.phase == "upload-start":
            self.phase = "upload"
            self._send_block()
        elif cs == 2 and self.phase == "upload":
            ackseq, blksize = frame[1], frame[2]
            if not 0 < blksize <= BLOCK_SIZE:
                raise SdoAbortedError(ABORT_BLOCK_SIZE)
            if ackseq > self._block_segments:
                raise SdoAbortedError(ABORT_SEQUENCE)
            self.sent_from = min(len(self.data), self.sent_from + 7 * ackseq)
            self.blksize = blksize
            if self.sent_from >= len(self.data):
                unused = (7 - len(self.data) % 7) % 7
                self.phase = "upload-end"
                self.server.send_response(struct.pack("<BH5x", 0xC1 | unused << 2,
                                                      crc16(self.data) if self.crc else 0))
            else:
                self._send_block()
        elif cs == 1 and self.phase == "upload-end":
            self.phase = None
        else:
            raise SdoAbortedError(0x05040001)

    def _send_block(self) -> None:
        data, start = self.data, self.sent_from
        segments = min(self.blksize, -(-(len(data) - start) // 7))
        for seqno in range(1, segments + 1):
            chunk = data[start + 7 * (seqno - 1): start + 7 * seqno]
            last = _LAST if start + 7 * seqno >= len(data) else 0
            self.server.send_response(bytes([seqno | last]) + chunk.ljust(7, b"\0"))
        self._block_segments = segments
