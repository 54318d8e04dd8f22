"""hil.bus spec parsing, hil.units conversions, the shipped EDS files and the PDO codec."""
from __future__ import annotations

import numpy as np
import pytest
import canopen

from qomni.hil.bus import BusSpec, DEFAULT_VIRTUAL_CHANNEL, open_bus, parse_bus_spec
from qomni.hil.layout import DRIVE_EDS, ENCODER_EDS
from qomni.hil.pdo_codec import PdoMappingError, build_codec
from qomni.hil import units


@pytest.mark.parametrize("spec, expected", [
    ("virtual", BusSpec("virtual", DEFAULT_VIRTUAL_CHANNEL)),
    ("virtual:rig1", BusSpec("virtual", "rig1")),
    ("socketcan:can0", BusSpec("socketcan", "can0")),
    ("pcan:PCAN_USBBUS1", BusSpec("pcan", "PCAN_USBBUS1")),
    ("pcan:PCAN_USBBUS1@1M", BusSpec("pcan", "PCAN_USBBUS1", 1_000_000)),
    ("kvaser:0@500k", BusSpec("kvaser", "0", 500_000)),
    (" socketcan:can1@250000 ", BusSpec("socketcan", "can1", 250_000)),
])
def test_parse_bus_spec(spec, expected):
    assert parse_bus_spec(spec) == expected


@pytest.mark.parametrize("spec, message", [
    ("", "non-empty"),
    ("nosuchbus:0", "unknown interface"),
    ("socketcan", "missing channel"),
    ("pcan:", "missing channel"),
    ("udp_multicast:239.74.163.2", "not allowed"),
    ("pcan:PCAN_USBBUS1@fast", "bitrate"),
    ("pcan:PCAN_USBBUS1@0", "positive"),
])
def test_bad_bus_spec(spec, message):
    with pytest.raises(ValueError, match=message):
        parse_bus_spec(spec)


def test_open_virtual_bus():
    a, b = open_bus("virtual:hil-bus-test"), open_bus("virtual:hil-bus-test")
    try:
        import can
        a.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        assert b.recv(1.0).arbitration_id == 0x123
    finally:
        a.shutdown()
        b.shutdown()


def test_units():
    bits = 14
    alpha = np.array([0.0, 1.0, -1.0, np.pi, -np.pi + 1e-3, 3.0])
    back = units.counts_to_alpha(units.alpha_to_counts(alpha, bits), bits)
    np.testing.assert_allclose(back, alpha, atol=np.pi / 2**bits)
    assert units.counts_to_alpha(2**13, 14) == pytest.approx(np.pi)       # (−π, π]
    assert units.counts_to_alpha(2**13 + 1, 14) < 0
    assert units.unwrap32([-2**31 + 5], [2**31 - 5], [2**31 - 5])[0] == 2**31 + 5
    np.testing.assert_array_equal(units.torque_to_per_mille([0.1234, 100, -100], 2.0, 3000), [62, 3000, -3000])
    np.testing.assert_allclose(units.per_mille_to_torque(500, 2.0), 1.0)
    with pytest.raises(ValueError):
        units.torque_to_per_mille([np.inf], 2.0)


@pytest.mark.parametrize("node_id", [1, 4])
def test_drive_eds(node_id):
    od = canopen.import_od(str(DRIVE_EDS), node_id)
    assert od[0x1000].default == 0x00020192
    assert od[0x1400][1].default == 0x200 + node_id and od[0x1400][2].default == 1
    assert od[0x1800][1].default == 0x180 + node_id and od[0x1801][1].default == 0x280 + node_id
    assert [od[0x1600][i].default for i in (0, 1, 2)] == [2, 0x60400010, 0x60710010]
    assert [od[0x1A00][i].default for i in (0, 1, 2)] == [2, 0x60410010, 0x60640020]
    assert [od[0x1A01][i].default for i in (0, 1, 2)] == [2, 0x606C0020, 0x60770010]
    assert od[0x1800][2].default == od[0x1801][2].default == 1
    for index in (0x1001, 0x1006, 0x1017, 0x1018, 0x6007, 0x6040, 0x6041, 0x6060, 0x6061, 0x6064,
                  0x606C, 0x6071, 0x6072, 0x6076, 0x6077, 0x6502):
        assert index in od
    assert od[0x6071].data_type == canopen.objectdictionary.INTEGER16
    assert od[0x6076].data_type == canopen.objectdictionary.UNSIGNED32
    codec = build_codec(od, [0x60410010, 0x60640020], receive=False)
    assert codec.size == 6 and codec.unpack(codec.pack([0x27, -5])) == (0x27, -5)


def test_encoder_eds():
    od = canopen.import_od(str(ENCODER_EDS), 5)
    assert od[0x1000].default == 0x00010196
    assert od[0x1800][1].default == 0x185
    assert [od[0x1A00][i].default for i in (0, 1)] == [1, 0x60040020]
    assert od[0x6004].data_type == canopen.objectdictionary.UNSIGNED32 and od[0x6004].pdo_mappable
    assert 0x6001 in od and 0x6002 in od


def test_pdo_codec_rejects_bad_mappings():
    od = canopen.import_od(str(DRIVE_EDS), 1)
    with pytest.raises(PdoMappingError):
        build_codec(od, [0x60760020], receive=False)         # 0x6076 is not PDO-mappable
    with pytest.raises(PdoMappingError):
        build_codec(od, [0x60410010], receive=True)          # statusword is read-only
    with pytest.raises(PdoMappingError):
        build_codec(od, [0x60640020, 0x606C0020, 0x60410010], receive=False)   # 10 bytes
    codec = build_codec(od, [0x00050008, 0x60710010], receive=True)          # dummy byte + torque
    assert codec.keys == ((0x6071, 0),) and codec.size == 3


def test_frame_lane_delivers_what_a_message_would():
    """An inline canopen network takes 11-bit data frames as (can_id, data, timestamp) without a message;
    a plain ``virtual`` peer and a listener without ``on_frame`` still get messages. Same frames, same order,
    whether sent with ``send_frame`` or ``send``, and a frame sent from inside a listener comes after the
    one being delivered everywhere."""
    import can

    from qomni.hil.virtual_bus import InlineVirtualBus, attach_inline, _frame_entry

    channel = "hil-frame-lane-test"
    peer = can.Bus(interface="virtual", channel=channel)
    sender, receiver = InlineVirtualBus(channel), InlineVirtualBus(channel)
    network = canopen.Network(receiver)
    network.connect()
    attach_inline(network)
    assert receiver.queue.deliver_frame is not None
    seen = []

    def on_frame(can_id, data, timestamp):
        seen.append((can_id, bytes(data), timestamp > 0))
        if can_id == 0x80:                               # answer the SYNC from inside the listener
            receiver.send_frame(0x181, b"\x01\x02")

    for cob_id in (0x80, 0x201, 0x7FF):
        network.subscribe(cob_id, on_frame)
    try:
        sender.send_frame(0x201, b"\xAA\xBB")
        sender.send(can.Message(arbitration_id=0x7FF, data=b"\x01", is_extended_id=False))
        sender.send_frame(0x80, b"")
        sender.send(can.Message(arbitration_id=0x201, data=b"\x02", is_extended_id=True))   # 29-bit: message path
        # canopen's own listener passes a 29-bit frame on by its number; the message path keeps that
        assert seen == [(0x201, b"\xAA\xBB", True), (0x7FF, b"\x01", True), (0x80, b"", True),
                        (0x201, b"\x02", True)]
        got = [peer.recv(1.0) for _ in range(5)]
        assert [(m.arbitration_id, bytes(m.data), m.is_extended_id) for m in got] == [
            (0x201, b"\xAA\xBB", False), (0x7FF, b"\x01", False), (0x80, b"", False),
            (0x181, b"\x01\x02", False), (0x201, b"\x02", True)]
        assert peer.recv(0.0) is None
        assert _frame_entry(can.BufferedReader()) is None      # such a listener keeps the message path
    finally:
        network.disconnect()
        sender.shutdown()
        peer.shutdown()


def test_socketcand_frame_lane_writes_what_python_can_writes():
    """``BatchingSocketcandBus.send_frame`` formats a frame exactly as python-can's client formats the
    same frame's message (socketcand ``< send … >``)."""
    import can
    from can.interfaces.socketcand.socketcand import convert_can_message_to_ascii_message

    from qomni.hil.bus import BatchingSocketcandBus

    written = []
    bus = BatchingSocketcandBus.__new__(BatchingSocketcandBus)       # no connection: capture the text
    bus._batches = __import__("threading").local()
    bus._tcp_send = written.append
    cases = [(0x181, bytes([0, 1, 0x0F, 0x10, 0xAB, 0xFF, 7, 8])), (0x80, b""), (0x7FF, b"\x00"), (0x1, b"\xff\x0a")]
    for can_id, data in cases:
        bus.send_frame(can_id, data)
    assert written == [convert_can_message_to_ascii_message(
        can.Message(arbitration_id=i, data=d, is_extended_id=False)) for i, d in cases]
    with bus.batch():
        bus.send_frame(0x181, b"\x01")
        bus.send_frame(0x182, b"\x02")
    assert written[-1] == "< send 181 1 1 >< send 182 1 2 >"
