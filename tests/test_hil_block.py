"""SDO block transfer of the emulated nodes against canopen's SdoClient (block upload and download with
CRC) and raw frames (sequence errors, CRC errors, protocol switch, aborts)."""
from __future__ import annotations

import struct

import canopen
import pytest

from qomni.hil.device.drive402 import USER_DATA_SIZE
from qomni.hil.device.sdo_block import crc16
from qomni.hil.layout import DRIVE_EDS

from doubles import wait_for


def _block_upload(node, index, subindex=0):
    with node.sdo.open(index, subindex, mode="rb", block_transfer=True) as stream:
        return stream.read()


def _block_download(node, index, data, subindex=0):
    with node.sdo.open(index, subindex, mode="wb", block_transfer=True, size=len(data)) as stream:
        stream.write(data)


def test_block_upload_of_the_stored_eds(master, server):
    """0x1021 Store EDS: the drive's own EDS file, ~30 kB, several sub-blocks of 127 segments."""
    data = _block_upload(master.drive[1], 0x1021)
    assert data == DRIVE_EDS.read_bytes()
    assert len(data) > 3 * 127 * 7
    assert _block_upload(master.drive[2], 0x1008) == b"qomni drive402"          # one short block


@pytest.mark.parametrize("size", [1, 7, 8, 889, 890, 2000, USER_DATA_SIZE])
def test_block_download_round_trip(master, server, size):
    node = master.drive[3]
    data = bytes((i * 37 + size) & 0xFF for i in range(size))
    _block_download(node, 0x2020, data)
    assert node.sdo.upload(0x2020, 0) == data                                    # segmented upload
    assert _block_upload(node, 0x2020) == data


def test_block_download_of_a_number_is_checked_like_any_download(master, server):
    node = master.drive[1]
    _block_download(node, 0x6081, struct.pack("<I", 123456))
    assert node.sdo[0x6081].raw == 123456
    with pytest.raises(canopen.SdoAbortedError) as err:
        _block_download(node, 0x6041, b"\x00\x00")                              # read-only
    assert err.value.code == 0x06010002
    with pytest.raises(canopen.SdoAbortedError) as err:
        _block_download(node, 0x6081, b"\x01\x02")                              # too short
    assert err.value.code == 0x06070013
    with pytest.raises(canopen.SdoAbortedError) as err:
        _block_download(node, 0x2020, bytes(USER_DATA_SIZE + 1))
    assert err.value.code == 0x06070012
    assert node.sdo[0x6081].raw == 123456                                       # still works after


def _request(master, frame, answers=1, cob=0x601):
    start = len(master.frames)
    master.send(cob, frame)
    wait_for(lambda: len([m for m in master.frames[start:] if m.arbitration_id == 0x581]) >= answers)
    return [bytes(m.data) for m in master.frames[start:] if m.arbitration_id == 0x581]


def test_raw_block_download_repeats_after_a_lost_segment_and_checks_crc(master, server):
    data = bytes(range(20))                                                      # 3 segments
    master.drive[1].sdo.download(0x2020, 0, b"before")
    init = _request(master, struct.pack("<BHBI", 0xC6, 0x2020, 0, len(data)))[0]
    assert init[0] == 0xA4 and init[4] == 127                                    # CRC, block size 127
    master.send(0x601, bytes([1]) + data[0:7])
    # segment 2 is lost on the bus; segment 3 (last) arrives: ack says 1 in order
    ack = _request(master, bytes([0x83]) + data[14:20] + b"\0")[0]
    assert ack[:2] == b"\xA2\x01"
    master.send(0x601, bytes([1]) + data[7:14])
    ack = _request(master, bytes([0x82]) + data[14:20] + b"\0")[0]
    assert ack[:2] == b"\xA2\x02"
    bad = (crc16(data) ^ 1).to_bytes(2, "little")
    end = _request(master, bytes([0xC1 | 1 << 2]) + bad + bytes(5))[0]
    assert end[0] == 0x80 and struct.unpack_from("<I", end, 4)[0] == 0x05040004  # CRC error
    assert master.drive[1].sdo.upload(0x2020, 0) == b"before"                    # nothing written


def test_raw_block_upload_protocol_switch_and_abort(master, server):
    # size 14 ≤ threshold 20: the server answers with a normal (segmented) upload instead
    response = _request(master, struct.pack("<BHBBB2x", 0xA4, 0x1008, 0, 127, 20))[0]
    assert response[0] & 0xE0 == 0x40 and struct.unpack_from("<I", response, 4)[0] == 14
    # a block upload aborted by the client mid-way leaves the server ready for the next request
    response = _request(master, struct.pack("<BHBBB2x", 0xA4, 0x1021, 0, 4, 0))[0]
    assert response[0] == 0xC6
    segments = _request(master, b"\xA3" + bytes(7), answers=4)
    assert [s[0] for s in segments] == [1, 2, 3, 4]
    master.send(0x601, struct.pack("<BHBI", 0x80, 0x1021, 0, 0x05040000))
    assert master.drive[1].sdo[0x1000].raw == 0x00020192
    # block size 0 is invalid
    response = _request(master, struct.pack("<BHBBB2x", 0xA4, 0x1021, 0, 0, 0))[0]
    assert response[0] == 0x80 and struct.unpack_from("<I", response, 4)[0] == 0x05040002
