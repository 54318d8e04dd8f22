"""Frames per CAN and CiA 301 on both sides of the bus: the devices act on 11-bit data frames only, abort
every SDO request for an object they do not have with the right code, and survive any frame; the hub
forwards only what socketcand can carry, refuses malformed identifiers and sheds idle connections.
Property-based (hypothesis) where the input space is frames."""
from __future__ import annotations

import socket
import time

import can
import pytest
from canopen.sdo import SdoAbortedError
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from doubles import wait_for
from qomni.hil.tools.hub import Hub, _parse_send, open_hub_bus


def _sent_by(master, start, cob_id):
    return [m for m in master.frames[start:] if m.arbitration_id == cob_id and not m.is_extended_id]


def test_a_29_bit_frame_is_not_a_sync_or_an_sdo_request(master, server, plant):
    master.nmt(0x01)
    master.barrier()
    start = len(master.frames)
    master.net.bus.send(can.Message(arbitration_id=0x80, is_extended_id=True, data=b""))
    master.net.bus.send(can.Message(arbitration_id=0x601, is_extended_id=True,
                                    data=bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])))
    master.barrier()
    assert plant.steps == 0 and not any(0x180 <= m.arbitration_id < 0x500 for m in master.frames[start:])
    assert not _sent_by(master, start, 0x581)                       # no SDO answer to the 29-bit request
    assert len(master.cycle()) == 10                                # an 11-bit SYNC is one


def test_a_remote_request_is_ignored_by_the_devices(master, server, plant):
    master.nmt(0x01)
    master.barrier()
    start = len(master.frames)
    master.net.bus.send(can.Message(arbitration_id=0x80, is_remote_frame=True, dlc=0))
    master.net.bus.send(can.Message(arbitration_id=0x181, is_remote_frame=True, dlc=4))
    master.barrier()
    assert plant.steps == 0 and not any(0x180 <= m.arbitration_id < 0x500 for m in master.frames[start:])


@pytest.mark.parametrize("index, subindex", [(0x6041, 9), (0x6041, 1), (0x1000, 3)])
def test_a_subindex_of_a_simple_variable_aborts_0x06090011(master, server, index, subindex):
    with pytest.raises(SdoAbortedError) as info:
        master.drive[1].sdo.upload(index, subindex)
    assert info.value.code == 0x06090011
    with pytest.raises(SdoAbortedError) as info:
        master.drive[1].sdo.download(index, subindex, b"\x00\x00")
    assert info.value.code in (0x06090011, 0x06010002)          # missing, or read-only checked first


_frames = st.builds(
    lambda cob, ext, rtr, data: can.Message(arbitration_id=cob, is_extended_id=ext, is_remote_frame=rtr,
                                            data=b"" if rtr else data, dlc=len(data)),
    st.integers(0, 0x7FF), st.booleans(), st.booleans(), st.binary(max_size=8))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=st.lists(_frames, max_size=12))
def test_the_devices_survive_any_frames_and_keep_answering(master, server, frames):
    for msg in frames:
        master.net.bus.send(msg)
    # a frame on the server's request channel (0x605) is answered too, an abort of its own, which may come in
    # while the client waits for its request's answer: one answer per such frame is read past
    for _ in range(sum(m.arbitration_id == 0x605 and not m.is_extended_id for m in frames)):
        try:
            master.encoder[5].sdo[0x1000].raw
            break
        except SdoAbortedError:
            continue
    assert master.encoder[5].sdo[0x1000].raw is not None             # the SDO server still answers
    assert server.error is None


# ------------------------------------------------------------------------------------------------ hub
@given(st.lists(st.text(alphabet="0123456789abcdefABCDEF-+x ", min_size=1, max_size=9), min_size=2, max_size=10))
@settings(max_examples=300, deadline=None)
def test_send_parsing_accepts_only_unsigned_hex_identifiers_in_range(args):
    out = _parse_send(args)
    if isinstance(out, tuple):
        can_id, extended, data = out
        assert 0 <= can_id <= (0x1FFFFFFF if extended else 0x7FF) and len(data) <= 8
        assert not args[0].startswith(("-", "+"))


def test_negative_identifiers_are_refused():
    assert isinstance(_parse_send(["-80", "0"]), str) and isinstance(_parse_send(["+80", "0"]), str)


def test_a_remote_request_does_not_break_a_python_can_client():
    with Hub(port=0) as hub, open_hub_bus(hub.port) as a, open_hub_bus(hub.port) as b:
        a.send(can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1))
        a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02"))
        got = b.recv(2.0)
        assert got is not None and got.arbitration_id == 0x123 and bytes(got.data) == b"\x01\x02"
        b.send(can.Message(arbitration_id=0x124, data=b"\x03"))       # a's reception is alive too
        back = a.recv(2.0)
        assert back is not None and back.arbitration_id == 0x124
        wait_for(lambda: hub.remote_dropped == 1)


def test_idle_connections_cannot_hold_the_hubs_places():
    with Hub(port=0, max_clients=2, open_timeout=0.2) as hub:
        idle = [socket.create_connection(("127.0.0.1", hub.port)) for _ in range(2)]
        try:
            wait_for(lambda: hub.clients == 2)
            time.sleep(0.4)
            wait_for(lambda: hub.clients == 0)                       # closed: they never opened a channel
            with open_hub_bus(hub.port) as bus:                       # a master gets in
                bus.send(can.Message(arbitration_id=0x80, data=b""))
        finally:
            for s in idle:
                s.close()
