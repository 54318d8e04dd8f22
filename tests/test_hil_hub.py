"""qomni.hil.tools.hub: python-can's unchanged ``socketcand`` client shares one bus through the loopback hub; the
vehicle server and client run lock-step over it; protocol details, bounds and the loopback-only rule."""
from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import time

import can
import numpy as np
import pytest

from qomni.hil.master.client import VehicleClient
from qomni.hil.tools.hub import Hub, hub_bus_spec, open_hub_bus
from qomni.hil.device.server import VehicleServer
from doubles import BITS, INCREMENTS, T_S, FakePlant

RAD_PER_INCREMENT = 2 * np.pi / INCREMENTS


@pytest.fixture
def hub():
    with Hub() as h:
        yield h


def socketcand_bus(port, channel="can0"):
    return can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel=channel)


def recv_all(bus, count, timeout=2.0):
    out, end = [], time.monotonic() + timeout
    while len(out) < count and time.monotonic() < end:
        msg = bus.recv(0.05)
        if msg is not None:
            out.append(msg)
    return out


def test_two_python_can_clients_exchange_frames(hub):
    a, b, c = socketcand_bus(hub.port), socketcand_bus(hub.port), socketcand_bus(hub.port, "can1")
    try:
        sent = [can.Message(arbitration_id=0x123, data=[1, 2, 0xFF], is_extended_id=False),
                can.Message(arbitration_id=0x080, data=[], is_extended_id=False),
                can.Message(arbitration_id=0x1ABCDEF0, data=range(8), is_extended_id=True)]
        before = time.time()
        for msg in sent:
            a.send(msg)
        got = recv_all(b, 3)
        assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in got] == \
            [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in sent]
        assert all(before - 0.01 <= m.timestamp <= time.time() + 0.01 for m in got)
        b.send(can.Message(arbitration_id=0x7FF, data=b"\x05", is_extended_id=False))
        reply = a.recv(2.0)
        assert reply.arbitration_id == 0x7FF and bytes(reply.data) == b"\x05"
        assert a.recv(0.2) is None and b.recv(0.2) is None         # never the sender's own frames
        assert c.recv(0.2) is None                                  # another channel is another bus
        assert hub.frames == 4 and hub.dropped == 0
    finally:
        for bus in (a, b, c):
            bus.shutdown()


def test_every_other_client_receives(hub):
    buses = [socketcand_bus(hub.port) for _ in range(4)]
    try:
        buses[2].send(can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False))
        for i, bus in enumerate(buses):
            got = recv_all(bus, 1, 1.0 if i != 2 else 0.2)
            assert [m.arbitration_id for m in got] == ([] if i == 2 else [0x181])
    finally:
        for bus in buses:
            bus.shutdown()


def test_vehicle_server_and_client_lock_step_over_the_hub(hub):
    plant = FakePlant()
    server_bus, client_bus = open_hub_bus(hub.port), open_hub_bus(hub.port)
    try:
        with VehicleServer(plant, server_bus) as server, \
                VehicleClient(client_bus, encoder_increments=INCREMENTS, steering_sensor_bits=BITS,
                              cycle_time=T_S) as client:
            tau = np.array([0.5, -1.0, 10.0, 0.0])
            expected = np.array([0.5, -1.0, 6.0, 0.0])                 # clipped at 0x6072 = 300 %
            for k in range(20):
                m = client.exchange(tau)
                assert m.time == pytest.approx(k * T_S)
            assert plant.steps == server.cycles == 20
            np.testing.assert_allclose(plant.tau, expected)
            np.testing.assert_allclose(m.motor_torque, expected)
            np.testing.assert_allclose(m.motor_velocity, expected / plant.inertia * 19 * T_S,
                                       atol=RAD_PER_INCREMENT)
            np.testing.assert_allclose(m.alpha, plant.alpha, atol=np.pi / 2**BITS)
    finally:
        server_bus.shutdown()
        client_bus.shutdown()
    assert hub.dropped == 0


def test_loopback_only():
    for host in ("0.0.0.0", "", "192.168.1.10", "::", "localhost", "::1"):
        with pytest.raises(ValueError, match="127.0.0.1 only"):
            Hub(host=host)
        with pytest.raises(ValueError, match="127.0.0.1 only"):
            hub_bus_spec(1234, host=host)
    with Hub() as hub:
        listeners = [s.getsockname() for s in hub._server.sockets]
        assert listeners == [("127.0.0.1", hub.port)]


def test_lifecycle_and_spec():
    hub = Hub()
    with pytest.raises(RuntimeError):
        hub.port
    hub.start()
    try:
        with pytest.raises(RuntimeError):
            hub.start()
        assert hub_bus_spec(hub.port) == f"socketcand:127.0.0.1:{hub.port}/can0" == hub.bus_spec()
        with pytest.raises(OSError):                               # port in use
            Hub(hub.port).start()
    finally:
        hub.stop()
        hub.stop()                                                 # idempotent
    with pytest.raises(ValueError):
        Hub(port=70000)
    with pytest.raises(ValueError):
        hub_bus_spec(0)
    with pytest.raises(ValueError):
        hub_bus_spec(1234, channel="can 0")


class Raw:
    """A hand-driven socketcand client (raw TCP) for protocol details."""

    def __init__(self, port, rcvbuf=None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        if rcvbuf:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.connect(("127.0.0.1", port))
        self.sock.settimeout(2.0)
        self.buffer = ""

    def send(self, text):
        self.sock.sendall(text.encode("ascii"))

    def element(self):
        while ">" not in self.buffer:
            data = self.sock.recv(4096)
            if not data:
                raise ConnectionError("closed")
            self.buffer += data.decode("ascii")
        end = self.buffer.index(">") + 1
        element, self.buffer = self.buffer[:end], self.buffer[end:]
        return element.strip()

    def close(self):
        self.sock.close()


def test_protocol_details(hub):
    raw = Raw(hub.port)
    listener = socketcand_bus(hub.port)
    try:
        assert raw.element() == "< hi >"
        raw.send("< send 123 1 01 >")
        assert raw.element().startswith("< error")                 # no channel open yet
        raw.send("< echo >")
        assert raw.element() == "< echo >"
        raw.send("< open can0 >")
        assert raw.element() == "< ok >"
        raw.send("< bogus >< send 800 0 >< send 12 2 01 >< send 123 9 0 0 0 0 0 0 0 0 0 >")
        assert [raw.element().startswith("< error") for _ in range(4)] == [True] * 4
        raw.send("< send 123 0  >")                                # BCM mode may send; DLC 0
        raw.send("< send 00000123 2 a b >")                        # extended, unpadded lowercase bytes
        got = recv_all(listener, 2)
        assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in got] == \
            [(0x123, False, b""), (0x123, True, b"\x0a\x0b")]
        raw.send("< rawmode >")
        assert raw.element() == "< ok >"
        listener.send(can.Message(arbitration_id=0x80, data=[], is_extended_id=False))
        listener.send(can.Message(arbitration_id=0x181, data=[0xAB, 0], is_extended_id=False))
        frames = [raw.element(), raw.element()]
        assert re.fullmatch(r"< frame 080 \d+\.\d{6}  >", frames[0])
        assert re.fullmatch(r"< frame 181 \d+\.\d{6} AB00 >", frames[1])
        raw.send("< " + "x" * 300)                                 # over-long element: closed
        with pytest.raises(ConnectionError):
            while True:
                raw.element()
    finally:
        raw.close()
        listener.shutdown()


def test_bounded_clients_and_buffers():
    with Hub(max_clients=2, max_buffer=4096) as hub:
        slow = Raw(hub.port, rcvbuf=4096)                          # never reads its frames
        sender = Raw(hub.port)
        try:
            for r in (slow, sender):
                assert r.element() == "< hi >"
                r.send("< open can0 >< rawmode >")
                assert [r.element(), r.element()] == ["< ok >", "< ok >"]
            third = Raw(hub.port)
            assert third.element() == "< error too many clients >"
            third.close()
            time.sleep(hub.handshake_grace + 0.05)
            n = 80000                                              # ~3 MB: more than the kernel buffers
            sender.send("< send 181 8 1 2 3 4 5 6 7 8 >" * n)
            end = time.monotonic() + 10
            while hub.frames < n and time.monotonic() < end:
                time.sleep(0.01)
            assert hub.frames == n
            assert hub.dropped > 0                                 # the slow client overran, the hub did not grow
            sender.send("< echo >")
            assert sender.element() == "< echo >"                  # the hub still serves
        finally:
            slow.close()
            sender.close()


def test_separate_processes_share_the_hub():
    """``python -m qomni.hil.tools.hub`` in its own process; a frame from this process reaches a client process."""
    with subprocess.Popen([sys.executable, "-m", "qomni.hil.tools.hub", "--port", "0"], stdout=subprocess.PIPE,
                          text=True) as hub:
        try:
            port = int(re.search(r"127\.0\.0\.1:(\d+)", hub.stdout.readline()).group(1))
            code = (f"import can; b = can.Bus(interface='socketcand', host='127.0.0.1', port={port}, "
                    f"channel='can0'); print('ready', flush=True); m = b.recv(10); "
                    f"print(hex(m.arbitration_id), bytes(m.data).hex(), flush=True); b.shutdown()")
            with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True) as peer:
                try:
                    assert peer.stdout.readline().strip() == "ready"
                    with open_hub_bus(port) as bus:
                        time.sleep(0.1)                            # the peer's raw-mode grace period
                        bus.send(can.Message(arbitration_id=0x201, data=b"\x0f\x00\xf4\x01",
                                             is_extended_id=False))
                        out, _ = peer.communicate(timeout=10)
                    assert out.strip() == "0x201 0f00f401"
                finally:
                    if peer.poll() is None:
                        peer.kill()
        finally:
            hub.send_signal(signal.SIGINT)
            try:
                hub.wait(timeout=5)
            except subprocess.TimeoutExpired:
                hub.kill()


def test_bus_spec_reaches_the_hub_and_refuses_other_hosts():
    import can as _can

    from qomni.hil.bus import open_bus, parse_bus_spec
    from qomni.hil.tools.hub import Hub, hub_bus_spec

    with pytest.raises(ValueError, match="127.0.0.1"):
        parse_bus_spec("socketcand:10.0.0.1:29536/can0")
    with pytest.raises(ValueError, match="socketcand needs"):
        parse_bus_spec("socketcand:can0")
    with Hub(port=0) as hub:
        spec = hub_bus_spec(hub.port)
        assert str(parse_bus_spec(spec)) == spec
        a, b = open_bus(spec), open_bus(spec)
        try:
            import time
            time.sleep(0.1)
            a.send(_can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
            msg = b.recv(timeout=2.0)
            assert msg is not None and msg.arbitration_id == 0x123 and bytes(msg.data) == b"\x01\x02"
        finally:
            a.shutdown()
            b.shutdown()
