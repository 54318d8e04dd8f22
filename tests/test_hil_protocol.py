"""hil devices against independent masters: canopen's BaseNode402 and raw frames on a virtual bus.

Covers CiA 301 (boot-up, NMT gating, SDO, SYNC/TPDO, RPDO, timeouts, malformed frames) and CiA 402
(power state machine, CST torque) of ``qomni.hil.device.server.VehicleServer`` with a fake plant.
"""
from __future__ import annotations

import struct
import threading
import time

import canopen
import numpy as np
import pytest
from canopen.profiles.p402 import BaseNode402

from qomni.hil.device.drive402 import PowerState, decode_controlword, Command
from qomni.hil.layout import DRIVE_EDS
from qomni.hil.device.server import VehicleServer

from doubles import BITS, T_S, FakePlant, Master, enable_by_sdo, rpdo1, wait_for

# --------------------------------------------------------------------------------- CiA 301
def test_boot_up_and_heartbeat(master, server):
    wait_for(lambda: {0x701, 0x702, 0x703, 0x704, 0x705, 0x706} <= set(master.ids()))
    for node_id in range(1, 7):
        first = next(m for m in master.frames if m.arbitration_id == 0x700 + node_id)
        assert bytes(first.data) == b"\x00"                       # boot-up before any heartbeat
    # NMT reset node: boot-up again, then heartbeat state 127 (pre-operational)
    start = len(master.frames)
    master.nmt(0x81, 3)
    wait_for(lambda: [bytes(m.data) for m in master.frames[start:] if m.arbitration_id == 0x703][:2]
             == [b"\x00", b"\x7f"])


def test_nmt_gating_no_pdo_before_start(master, server, plant):
    assert master.cycle() == {}                                  # PRE-OPERATIONAL: no TPDO
    master.nmt(0x01)
    tpdos = master.cycle()
    assert sorted(tpdos) == sorted([0x181, 0x182, 0x183, 0x184, 0x281, 0x282, 0x283, 0x284, 0x185, 0x186])
    assert [len(tpdos[c]) for c in (0x181, 0x281, 0x185)] == [6, 6, 4]
    master.nmt(0x02)                                             # STOPPED: no PDO, no SDO
    start = len(master.frames)
    master.send(0x80)
    master.send(0x601, b"\x40\x00\x10\x00\x00\x00\x00\x00")
    master.nmt(0x80)                                             # back to PRE-OPERATIONAL
    master.barrier()
    assert not [i for i in master.ids(start) if 0x180 <= i < 0x580 or i == 0x581]
    assert plant.steps == 3                                      # the physics ran on every SYNC


def test_sdo_identity_and_segmented_upload(master, server):
    drive = master.drive[1]
    assert drive.sdo[0x6076].raw == 2000                         # mN m, from plant.description
    assert drive.sdo[0x6072].raw == 3000                         # per mille
    assert drive.sdo[0x1000].raw == 0x00020192
    assert drive.sdo[0x1008].raw == "qomni drive402"             # 14 bytes: segmented upload
    assert drive.sdo[0x6502].raw & 0x200
    assert master.encoder[5].sdo[0x6001].raw == 2**BITS
    with pytest.raises(canopen.SdoAbortedError):
        drive.sdo[0x6041].raw = 0                                # read-only
    with pytest.raises(canopen.SdoAbortedError):
        drive.sdo[0x6060].raw = 2                                # velocity mode: not supported


def test_the_sync_counter_0x1019_changes_only_while_0x1006_is_0(master, server, plant):
    """CiA 301 §7.5.2.20: 0x1019 takes 0 or 2…240 and is refused with 0x08000022 while the communication
    cycle period 0x1006 is not 0; a SYNC with the counter steps the plant like one without."""
    drive = master.drive[2]
    assert drive.sdo[0x1019].raw == 240 and drive.sdo[0x1006].raw != 0
    with pytest.raises(canopen.SdoAbortedError) as refused:
        drive.sdo[0x1019].raw = 16
    assert refused.value.code == 0x08000022 and drive.sdo[0x1019].raw == 240
    drive.sdo[0x1019].raw = 240                                  # the value it holds: nothing changes
    drive.sdo[0x1006].raw = 0
    with pytest.raises(canopen.SdoAbortedError) as reserved:
        drive.sdo[0x1019].raw = 1
    assert reserved.value.code == 0x06090030
    drive.sdo[0x1019].raw = 16
    drive.sdo[0x1006].raw = 2000
    assert drive.sdo[0x1019].raw == 16
    master.nmt(0x01)
    master.send(0x80, b"\x07")
    master.barrier()
    assert plant.steps == 1


# ------------------------------------------------------------------------------ CiA 402
def test_base_node_402_walks_state_machine(channel, plant):
    """canopen's BaseNode402 (an independent master) drives the drive to OPERATION ENABLED and back."""
    net = canopen.Network()
    net.NOTIFIER_CYCLE = 0.05
    net.connect(interface="virtual", channel=channel)
    node = BaseNode402(1, str(DRIVE_EDS))
    net.add_node(node)
    with VehicleServer(plant, f"virtual:{channel}") as server:
        try:
            booted = threading.Event()       # wait_for_bootup() would race with our fast boot-up
            node.nmt.add_heartbeat_callback(lambda state: state == 0 and booted.set())
            node.nmt.state = "RESET COMMUNICATION"
            assert booted.wait(2)
            assert node.sdo.upload(0x6076, 0) == struct.pack("<I", 2000)   # segmented/expedited SDO
            node.sdo[0x605A].raw = 6                           # quick stop: stay in QUICK STOP ACTIVE
            node.setup_402_state_machine(read_pdos=True)
            node.op_mode = "CYCLIC SYNCHRONOUS TORQUE"
            assert node.sdo[0x6061].raw == 10                  # the setter swallows timeouts: read back
            node.nmt.state = "OPERATIONAL"
            node.rpdo[1].start(0.005)                          # sync RPDOs: the master must send them
            net.sync.start(0.005)
            node.check_statusword()                            # waits for a TPDO1
            assert node.state == "SWITCH ON DISABLED"
            node.state = "OPERATION ENABLED"
            assert server.drives[0].state is PowerState.OPERATION_ENABLED
            node.state = "SWITCHED ON"
            node.state = "OPERATION ENABLED"
            node.state = "QUICK STOP ACTIVE"
            node.state = "SWITCH ON DISABLED"
            assert server.drives[0].state is PowerState.SWITCH_ON_DISABLED
        finally:
            net.sync.stop()
            node.rpdo[1].stop()
            net.disconnect()


def test_controlword_decoding():
    assert decode_controlword(0x06) is Command.SHUTDOWN
    assert decode_controlword(0x07) is Command.SWITCH_ON
    assert decode_controlword(0x0F) is Command.ENABLE_OPERATION
    assert decode_controlword(0x00) is Command.DISABLE_VOLTAGE
    assert decode_controlword(0x02) is Command.QUICK_STOP
    assert decode_controlword(0x8F) is Command.FAULT_RESET


def test_lock_step_advances_exactly_n_cycles(master, server, plant):
    master.nmt(0x01)
    for _ in range(25):
        master.send(0x80)
    master.barrier()
    assert plant.steps == 25 and server.cycles == 25
    assert plant.time == pytest.approx(25 * T_S, abs=1e-12)


def test_torque_arrives_in_newton_metres(master, server, plant):
    master.nmt(0x01)
    enable_by_sdo(master, 1)
    enable_by_sdo(master, 4)
    tpdos = master.cycle([rpdo1(1, 0x0F, 500), rpdo1(4, 0x0F, -1234), rpdo1(2, 0x0F, 700)])
    np.testing.assert_allclose(plant.tau, [1.0, 0.0, 0.0, -2.468])   # drive 2 is not enabled
    sw, _ = struct.unpack("<Hi", tpdos[0x181])
    assert sw & 0x6F == 0x27 and sw & (1 << 12)                      # OPERATION ENABLED, follows CST
    assert struct.unpack("<ih", tpdos[0x281])[1] == 500             # torque actual, per mille
    assert struct.unpack("<ih", tpdos[0x284])[1] == -1234
    assert struct.unpack("<ih", tpdos[0x282])[1] == 0
    tpdos = master.cycle([rpdo1(1, 0x0F, 4000)])                      # clipped to 0x6072 = 3000 ‰
    assert plant.tau[0] == pytest.approx(6.0)
    assert struct.unpack("<Hi", tpdos[0x181])[0] & (1 << 11)          # internal limit active
    # target torque holds without new RPDOs; positions move
    master.cycle()
    assert plant.tau[0] == pytest.approx(6.0)
    assert struct.unpack("<Hi", master.cycle()[0x181])[1] > 0


def test_torque_zero_unless_operation_enabled(master, server, plant):
    master.nmt(0x01)
    master.drive[1].sdo[0x6060].raw = 10
    master.drive[1].sdo[0x605A].raw = 6                                 # quick stop: stay (16 allowed)
    master.drive[1].sdo[0x6087].raw = 10**6                             # ‰/s: ramp 2000 ‰ per cycle
    for cw, state in ((0x00, PowerState.SWITCH_ON_DISABLED), (0x06, PowerState.READY_TO_SWITCH_ON),
                      (0x07, PowerState.SWITCHED_ON)):
        master.cycle([rpdo1(1, cw, 800)])
        assert server.drives[0].state is state
        assert plant.tau[0] == 0.0
    master.cycle([rpdo1(1, 0x0F, 800)])
    assert plant.tau[0] == pytest.approx(1.6)
    master.cycle([rpdo1(1, 0x0B, 800)])                                # quick stop
    assert server.drives[0].state is PowerState.QUICK_STOP_ACTIVE and plant.tau[0] == 0.0
    master.cycle([rpdo1(1, 0x0F, 800)])                                # transition 16
    assert plant.tau[0] == pytest.approx(1.6)
    master.drive[1].sdo[0x6060].raw = 0                                # no mode → no torque
    master.cycle([rpdo1(1, 0x0F, 800)])
    assert plant.tau[0] == 0.0


def test_sync_timeout_stops_torque_and_faults(channel, master, plant):
    with VehicleServer(plant, f"virtual:{channel}", sync_timeout=0.05, watchdog_period=0.005) as server:
        master.nmt(0x01)
        enable_by_sdo(master, 2)
        master.cycle([rpdo1(2, 0x0F, 500)])
        assert plant.tau[1] == pytest.approx(1.0)
        start = len(master.frames)
        wait_for(lambda: plant.tau[1] == 0.0, 1.0)              # the master went silent: watchdog
        assert server.drives[1].state is PowerState.FAULT
        wait_for(lambda: 0x82 in master.ids(start))
        emcy = next(m for m in master.frames[start:] if m.arbitration_id == 0x82)
        assert struct.unpack_from("<H", emcy.data)[0] == 0x8100
        assert master.drive[2].sdo[0x603F].raw == 0x8100
        tpdos = master.cycle([rpdo1(2, 0x0F, 500)])
        assert plant.tau[1] == 0.0 and struct.unpack("<Hi", tpdos[0x182])[0] & 0x4F == 0x08
        master.cycle([rpdo1(2, 0x80, 0)])                                   # fault reset (edge)
        assert server.drives[1].state is PowerState.SWITCH_ON_DISABLED


def test_rpdo_timeout_stops_torque(channel, master, plant):
    with VehicleServer(plant, f"virtual:{channel}", sync_timeout=None, watchdog_period=0.005) as server:
        master.drive[3].sdo[0x1400][5].raw = 20                            # RPDO1 event timer, ms
        master.nmt(0x01)
        enable_by_sdo(master, 3)
        master.cycle([rpdo1(3, 0x0F, -500)])
        assert plant.tau[2] == pytest.approx(-1.0)
        start = len(master.frames)
        end = time.monotonic() + 1.0
        while server.drives[2].state is not PowerState.FAULT:               # SYNC continues, RPDO not
            assert time.monotonic() < end
            master.cycle()
            time.sleep(0.005)
        master.cycle()
        assert plant.tau[2] == 0.0
        codes = [struct.unpack_from("<H", m.data)[0] for m in master.frames[start:] if m.arbitration_id == 0x83]
        assert 0x8250 in codes


def test_leaving_operational_disables_torque(master, server, plant):
    master.nmt(0x01)
    enable_by_sdo(master, 1)
    master.cycle([rpdo1(1, 0x0F, 500)])
    assert plant.tau[0] == pytest.approx(1.0)
    master.nmt(0x80)
    master.barrier()
    assert server.drives[0].state is PowerState.FAULT                       # 0x6007 = 1
    master.send(0x80)
    master.barrier()
    assert plant.tau[0] == 0.0


def test_malformed_frames_do_not_crash(master, server, plant):
    master.nmt(0x01)
    enable_by_sdo(master, 1)
    master.cycle([rpdo1(1, 0x0F, 300)])
    start = len(master.frames)
    master.send(0x201, b"\x0f\x00")                       # RPDO too short (DLC 2 instead of 4)
    master.send(0x80, b"\x01\x02\x03")                    # SYNC with DLC 3
    master.send(0x000, b"\x01")                           # NMT with DLC 1
    master.send(0x601, b"\x40\x41")                       # SDO with DLC 2
    master.send(0x201, b"")                               # empty RPDO
    master.barrier()
    emcy = [struct.unpack_from("<H", m.data)[0] for m in master.frames[start:] if m.arbitration_id == 0x81]
    assert 0x8210 in emcy and 0x8240 in emcy
    assert plant.steps == 1                               # the bad SYNC did not step the plant
    assert server.error is None
    tpdos = master.cycle([rpdo1(1, 0x0F, 600)])          # still works
    assert plant.tau[0] == pytest.approx(1.2) and len(tpdos) == 10


def test_pdo_remapping_by_sdo(master, server):
    """The CiA 301 mapping procedure with canopen's PdoMap.save(): TPDO1 = statusword + torque actual."""
    node = master.drive[1]
    node.tpdo.read()
    node.tpdo[1].clear()
    node.tpdo[1].add_variable(0x6041)
    node.tpdo[1].add_variable(0x6077)
    node.tpdo[1].save()
    master.nmt(0x01)
    tpdos = master.cycle()
    assert len(tpdos[0x181]) == 4 and len(tpdos[0x182]) == 6
    with pytest.raises(canopen.SdoAbortedError):          # mapping a valid PDO is refused
        node.sdo[0x1A00][1].raw = 0x60640020
    master.nmt(0x82, 1)                                   # reset communication restores the EDS mapping
    master.barrier(1)
    master.nmt(0x01)
    assert len(master.cycle()[0x181]) == 6


def test_mapping_from_another_eds_file(tmp_path, channel, master, plant):
    text = DRIVE_EDS.read_text()
    lean = text.replace("DefaultValue=0x60410010", "DefaultValue=0x60770010", 1)  # TPDO1: torque + position
    assert lean != text
    path = tmp_path / "lean402.eds"
    path.write_text(lean)
    with VehicleServer(plant, f"virtual:{channel}", drive_eds=path):
        master.nmt(0x01)
        data = master.cycle()[0x181]
        assert len(data) == 6 and struct.unpack("<hi", data) == (0, 0)


def test_deterministic(channel):
    def run(chan):
        m = Master(chan)
        p = FakePlant()
        try:
            with VehicleServer(p, f"virtual:{chan}"):
                m.nmt(0x01)
                enable_by_sdo(m, 1)
                out = [m.cycle([rpdo1(1, 0x0F, int(300 * np.sin(k / 5)))]) for k in range(30)]
        finally:
            m.close()
        return out, p.theta.copy()
    a, b = run(channel), run(channel + "b")
    assert a[0] == b[0] and np.array_equal(a[1], b[1])
