"""qomni.hil.master.client.VehicleClient against qomni.hil.device.server.VehicleServer with a fake plant, in-process (virtual bus)."""
from __future__ import annotations

import re
import subprocess
import sys
import time
import uuid

import can
import numpy as np
import pytest

from qomni.hil.master.client import CommunicationError, DriveFaultError, VehicleClient
from qomni.hil.device.drive402 import PowerState
from qomni.vehicle_interface import Measurement, VehicleInterface
from qomni.hil.device.server import VehicleServer
from doubles import BITS, INCREMENTS, T_S, FakePlant

RAD_PER_INCREMENT = 2 * np.pi / INCREMENTS


@pytest.fixture
def spec():
    return f"virtual:hil-client-{uuid.uuid4().hex[:10]}"


def make_client(spec, **kwargs):
    return VehicleClient(spec, encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S,
                         **kwargs)


def test_round_trip(spec):
    plant = FakePlant()
    with VehicleServer(plant, spec) as server, make_client(spec) as client:
        assert isinstance(client, VehicleInterface)
        np.testing.assert_allclose(client.rated_torque, 2.0)
        np.testing.assert_allclose(client.max_torque, 6.0)
        assert all(d.state is PowerState.OPERATION_ENABLED for d in server.drives)
        tau = np.array([0.1234, -0.5, 10.0, -1.0])
        m0 = client.exchange(tau)
        assert isinstance(m0, Measurement) and m0.time == 0.0
        expected = np.array([0.124, -0.5, 6.0, -1.0])          # 62 ‰ rounding; clip at 0x6072 = 300 %
        np.testing.assert_allclose(plant.tau, expected)
        np.testing.assert_allclose(m0.motor_torque, expected)  # torque actual = applied from now
        np.testing.assert_allclose(m0.motor_position, 0.0)
        np.testing.assert_allclose(m0.alpha, plant.alpha, atol=np.pi / 2**BITS)
        for k in range(1, 20):
            m = client.exchange(tau)
            assert m.time == pytest.approx(k * T_S)
        assert plant.steps == server.cycles == 20
        # double integrator: ω = τ/J · t, θ = ½ τ/J t² (quantised by the encoder)
        t = 19 * T_S
        np.testing.assert_allclose(m.motor_velocity, expected / plant.inertia * t, atol=RAD_PER_INCREMENT)
        np.testing.assert_allclose(m.motor_position, 0.5 * expected / plant.inertia * t**2,
                                   atol=RAD_PER_INCREMENT)
        assert m.motor_position.shape == (4,) and m.alpha.shape == (2,)


def test_stop_disables_drives(spec):
    plant = FakePlant()
    with VehicleServer(plant, spec) as server:
        client = make_client(spec).connect()
        client.exchange(np.ones(4))
        client.stop()
        client.stop()                                           # idempotent
        assert all(d.state is PowerState.READY_TO_SWITCH_ON for d in server.drives)
        assert all(n.nmt_state == 127 for n in server.nodes)    # PRE-OPERATIONAL
        with pytest.raises(CommunicationError):
            client.exchange(np.zeros(4))


def test_position_unwraps_across_32_bit_counter(spec):
    start = (2**31 - 3000) * RAD_PER_INCREMENT                  # counter wraps during the run
    omega = 1000.0                                              # rad/s → ~20 900 increments per cycle
    plant = FakePlant(theta0=(start, -start, 0, 0), omega0=(omega, -omega, 0, 0))
    with VehicleServer(plant, spec), make_client(spec) as client:
        positions = np.array([client.exchange(np.zeros(4)).motor_position for _ in range(5)])
    steps = np.diff(positions[:, :2], axis=0)
    np.testing.assert_allclose(steps, [[omega * T_S, -omega * T_S]] * 4, atol=2 * RAD_PER_INCREMENT)
    assert positions[-1, 0] > 2**31 * RAD_PER_INCREMENT             # continuous, not wrapped


def test_alpha_range(spec):
    plant = FakePlant(alpha=(np.pi, -np.pi / 2))
    with VehicleServer(plant, spec), make_client(spec) as client:
        alpha = client.exchange(np.zeros(4)).alpha
    assert alpha[0] == pytest.approx(np.pi)                      # π, not −π: α ∈ (−π, π]
    assert alpha[1] == pytest.approx(-np.pi / 2)


def test_blf_records_every_frame(spec, tmp_path):
    spec += "-1234567890"             # python-can's BLF writer would turn these digits into a channel
    path = tmp_path / "bus.blf"
    n = 10
    with VehicleServer(FakePlant(), spec):
        with make_client(spec, record=path) as client:
            for _ in range(n):
                client.exchange(np.full(4, 0.2))
            recorder = client._recorder
    frames = list(can.BLFReader(path))
    assert len(frames) == recorder.frames > 15 * n
    sync = [f for f in frames if f.arbitration_id == 0x80]
    rpdo = [f for f in frames if 0x201 <= f.arbitration_id <= 0x204]
    tpdo = [f for f in frames if 0x181 <= f.arbitration_id <= 0x186 or 0x281 <= f.arbitration_id <= 0x284]
    assert (len(sync), len(rpdo), len(tpdo)) == (n, 4 * n, 10 * n)
    assert not any(f.is_rx for f in sync + rpdo) and all(f.is_rx for f in tpdo)
    assert {f.arbitration_id for f in frames} >= {0x000, 0x601, 0x581, 0x701}   # NMT, SDO, boot-up


def test_blf_flushed_after_exception(spec, tmp_path):
    path = tmp_path / "crash.blf"
    with VehicleServer(FakePlant(), spec):
        with pytest.raises(ZeroDivisionError):
            with make_client(spec, record=path) as client:
                client.exchange(np.zeros(4))
                1 / 0
    frames = list(can.BLFReader(path))
    assert sum(f.arbitration_id == 0x80 for f in frames) == 1


def test_timeout_raises_communication_error(spec):
    plant = FakePlant()
    server = VehicleServer(plant, spec).start()
    client = make_client(spec, timeout=0.1).connect()
    try:
        client.exchange(np.zeros(4))
        server.stop()
        t0 = time.monotonic()
        with pytest.raises(CommunicationError, match=r"no TPDO .* for 6 cycle\(s\) in a row"):
            for _ in range(client.max_missed + 1):          # the last sample is held max_missed times
                client.exchange(np.zeros(4))
        assert time.monotonic() - t0 < (client.max_missed + 1) * client.timeout + 0.5
    finally:
        client.stop()
        server.stop()


def test_no_vehicle_on_bus(spec):
    t0 = time.monotonic()
    with pytest.raises(CommunicationError, match="boot-up"):
        make_client(spec, boot_timeout=0.2).connect()
    assert time.monotonic() - t0 < 1.0


def test_drive_fault_after_master_pause_and_recovery(spec):
    plant = FakePlant()
    with VehicleServer(plant, spec, sync_timeout=0.05, watchdog_period=0.005) as server, \
            make_client(spec) as client:
        client.exchange(np.full(4, 0.5))
        deadline = time.monotonic() + 2
        while plant.tau.tolist() != [0, 0, 0, 0]:                # pause longer than the SYNC timeout
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert all(d.state is PowerState.FAULT for d in server.drives)
        with pytest.raises(DriveFaultError) as info:
            client.exchange(np.full(4, 0.5))
        assert info.value.states[1] == "FAULT"
        np.testing.assert_allclose(info.value.measurement.motor_torque, 0.0)
        for node in server.nodes:                # no second fault while enable() runs on a busy host
            node.sync_timeout = 5.0
        for drive in server.drives:
            drive.write_value(0x1400, 5, 0)      # RPDO1 event timer off
        client.enable()
        m = client.exchange(np.full(4, 0.5))
        np.testing.assert_allclose(m.motor_torque, 0.5)


def test_bad_torque_arguments(spec):
    with VehicleServer(FakePlant(), spec), make_client(spec) as client:
        with pytest.raises(ValueError):
            client.exchange(np.zeros(3))
        with pytest.raises(ValueError):
            client.exchange([0, np.nan, 0, 0])


def test_lean_mapping_from_eds(spec, tmp_path):
    """Server and client with the same non-default EDS mapping (torque actual moved into TPDO1)."""
    from qomni.hil.layout import DRIVE_EDS
    text = DRIVE_EDS.read_text()
    lean = text.replace("DefaultValue=0x60410010", "DefaultValue=0x60770010", 1)   # TPDO1: 0x6077 + 0x6064
    path = tmp_path / "lean402.eds"
    path.write_text(lean)
    plant = FakePlant()
    with VehicleServer(plant, spec, drive_eds=path), make_client(spec, drive_eds=path) as client:
        m = client.exchange(np.full(4, 0.3))
    np.testing.assert_allclose(m.motor_torque, 0.3)


def test_deterministic_round_trip():
    def run():
        spec = f"virtual:hil-det-{uuid.uuid4().hex[:8]}"
        plant = FakePlant()
        with VehicleServer(plant, spec), make_client(spec) as client:
            out = [client.exchange(np.sin(np.arange(4) + k / 7)) for k in range(50)]
        return np.array([m.motor_position for m in out]), plant.theta
    (a, ta), (b, tb) = run(), run()
    assert np.array_equal(a, b) and np.array_equal(ta, tb)


@pytest.mark.parametrize("module", ["qomni.hil", "qomni.hil.master.client", "qomni.hil.device.server", "qomni.hil.bus", "qomni.vehicle_interface"])
def test_hil_does_not_import_emulator(module):
    code = (f"import sys, {module}; bad = [m for m in sys.modules if m.split('.')[:2] == ['qomni', 'emulator']];"
            f"assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_cycle_cost(spec, capsys):
    """Lock-step cost of one cycle, client + server + fake plant in one process (printed, loosely bounded)."""
    with VehicleServer(FakePlant(), spec), make_client(spec) as client:
        tau = np.full(4, 0.1)
        for _ in range(50):
            client.exchange(tau)
        n = 1000
        t0 = time.perf_counter()
        for _ in range(n):
            client.exchange(tau)
        us = (time.perf_counter() - t0) / n * 1e6
    with capsys.disabled():
        print(f"\nhil lock-step cycle: {us:.0f} µs (client + server + fake plant, virtual bus)")
    assert us < 5000


def test_new_master_takes_over_after_a_crashed_one(spec):
    plant = FakePlant()
    with VehicleServer(plant, spec) as server:
        crashed = make_client(spec).connect()
        crashed.exchange(np.full(4, 0.5))
        crashed._network.notifier.stop(1.0)          # the process dies: no stop(), drives stay enabled
        crashed._bus.shutdown()
        with make_client(spec) as client:            # reset communication faults the drives (0x6007)
            m = client.exchange(np.full(4, 0.25))   # enable() did the fault reset
            np.testing.assert_allclose(m.motor_torque, 0.25)
            assert m.time == 0.0
        assert all(d.state is PowerState.READY_TO_SWITCH_ON for d in server.drives)


def _with_counter(text: str, overflow: int | None) -> str:
    """An EDS whose 0x1019 default is ``overflow`` (None: the object left out)."""
    start = text.index("[1019]")
    end = text.index("[", start + 1)
    if overflow is None:
        return text[:start] + text[end:]         # canopen reads every object section, not the lists
    return text[:start] + text[start:end].replace("DefaultValue=240", f"DefaultValue={overflow}") + text[end:]


def test_the_sync_carries_the_counter_0x1019_sets_and_a_log_counts_lost_cycles_across_its_wrap(spec, tmp_path):
    """The client writes the files' 0x1019 to every node (0x1006 cleared first: CiA 301 lets 0x1019 change
    only while 0x1006 is 0) and counts its SYNCs 1…0x1019; a lock-step log that lost whole cycles across
    the counter's wrap is decoded with every later row at its time."""
    from qomni.hil.layout import DRIVE_EDS, ENCODER_EDS
    from qomni.hil.master.decode import DecodeReport, decode_log

    drive, encoder = tmp_path / "drive.eds", tmp_path / "encoder.eds"
    drive.write_text(_with_counter(DRIVE_EDS.read_text(), 8))
    encoder.write_text(_with_counter(ENCODER_EDS.read_text(), 8))
    log = tmp_path / "bus.log"
    with VehicleServer(FakePlant(), spec) as server, \
            make_client(spec, drive_eds=drive, encoder_eds=encoder, record=log) as client:
        assert client.sync_counter_overflow == 8
        assert all(node.values[(0x1019, 0)] == 8 and node.values[(0x1006, 0)] == T_S * 1e6
                   for node in server.nodes)
        intact = [client.exchange(np.full(4, 0.01 * k)) for k in range(30)]
    lines = log.read_text().splitlines()
    syncs = [i for i, line in enumerate(lines) if " 080#" in line]
    assert [int(lines[i].split()[2].split("#")[1], 16) for i in syncs] == [k % 8 + 1 for k in range(30)]
    lossy = tmp_path / "lossy.log"
    lossy.write_text("\n".join(lines[:syncs[6]] + lines[syncs[9]:syncs[20]] + lines[syncs[27]:]) + "\n")
    report = DecodeReport()
    cycles = list(decode_log(lossy, encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S,
                             report=report))
    assert report.sync_counter == 8 and report.lost_cycles == 10 and report.incomplete == 2
    kept = intact[:5] + intact[9:19] + intact[27:]                    # the cycle before each gap is skipped
    assert [c.measurement.time for c in cycles] == pytest.approx([m.time for m in kept])
    for got, want in zip(cycles, kept):
        np.testing.assert_array_equal(got.measurement.motor_position, want.motor_position)


def test_a_node_without_0x1019_makes_the_sync_carry_no_counter(spec, tmp_path):
    """One node whose files have no 0x1019: the SYNC has one length for every consumer, so the client
    writes 0 to the others' 0x1019 and sends its SYNC without data."""
    from qomni.hil.layout import ENCODER_EDS

    encoder = tmp_path / "encoder.eds"
    encoder.write_text(_with_counter(ENCODER_EDS.read_text(), None))
    sent = []
    with VehicleServer(FakePlant(), spec) as server, make_client(spec, encoder_eds=encoder) as client, \
            can.Bus(interface="virtual", channel=spec.split(":", 1)[1]) as spy:
        assert client.sync_counter_overflow == 0
        assert all(drive.values[(0x1019, 0)] == 0 for drive in server.drives)    # the encoders have none here
        client.exchange(np.zeros(4))
        while (msg := spy.recv(0)) is not None:            # the virtual bus queues every frame at once
            sent.append(msg)
    assert [bytes(m.data) for m in sent if m.arbitration_id == 0x80] == [b""]


def test_files_that_give_the_nodes_different_counters_are_refused(spec, tmp_path):
    from qomni.hil.layout import DRIVE_EDS

    drive = tmp_path / "drive.eds"
    drive.write_text(_with_counter(DRIVE_EDS.read_text(), 16))
    with VehicleServer(FakePlant(), spec), pytest.raises(CommunicationError, match=r"0x1019: .*\[16, 240\]"):
        make_client(spec, drive_eds=drive).connect()


def test_a_client_that_reads_the_devices_configuration_takes_their_counter(spec):
    with VehicleServer(FakePlant(), spec) as server, make_client(spec, configure_pdos=False) as client:
        assert client.sync_counter_overflow == 240 == server.drives[0].values[(0x1019, 0)]
        client.exchange(np.zeros(4))
