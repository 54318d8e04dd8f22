"""qomni.hil.tools.dbc: the DBC generated from the PDO mapping decodes the client's BLF recording to what the client
measured, and follows another mapping (EDS/DCF) like the nodes do."""
from __future__ import annotations

import uuid
from collections import defaultdict

import can
import cantools
import numpy as np
import pytest
from canopen import objectdictionary as od

from qomni.hil.master.client import VehicleClient
from qomni.hil.tools.dbc import build_database, write_dbc
from qomni.hil.layout import DRIVE_EDS, ENCODER_EDS
from qomni.hil.pdo_codec import PdoMappingError, build_codec
from qomni.hil.device.server import VehicleServer
from qomni.hil.units import counts_to_alpha
from doubles import BITS, INCREMENTS, T_S, FakePlant

RATED = 2.0                              # N m, FakePlant's rated torque (0x6076 = 2000 mN m)
RAD_PER_INCREMENT = 2 * np.pi / INCREMENTS


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A short client/server run recorded to BLF: (frames, measurements, torques sent, DBC path)."""
    tmp = tmp_path_factory.mktemp("dbc")
    spec = f"virtual:hil-dbc-{uuid.uuid4().hex[:10]}"
    plant = FakePlant(theta0=(1.0, -2.0, 30.0, -0.5), omega0=(5.0, -7.0, 0.0, 1.0), alpha=(0.3, -3.0))
    torques = [np.array([0.5, -1.25, 10.0, -0.0037]) * np.cos(k / 3) for k in range(12)]
    with VehicleServer(plant, spec):
        with VehicleClient(spec, encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S,
                           record=tmp / "bus.blf") as client:
            measurements = [client.exchange(tau) for tau in torques]
    dbc = tmp / "vehicle.dbc"
    write_dbc(dbc)
    return list(can.BLFReader(tmp / "bus.blf")), measurements, torques, dbc


def decoded_by_id(frames, db):
    """{COB-ID: [decoded dict, ...]} in recording order, for every frame the DBC knows."""
    known = {m.frame_id for m in db.messages}
    out = defaultdict(list)
    for f in frames:
        if f.arbitration_id in known:
            out[f.arbitration_id].append(db.decode_message(f.arbitration_id, bytes(f.data),
                                                           decode_choices=False))
    return out


def test_structure_of_generated_dbc(recording):
    db = cantools.database.load_file(recording[3])           # through the DBC text
    names = {m.name: m for m in db.messages}
    assert names["SYNC"].frame_id == 0x80 and names["SYNC"].length == 1          # 0x1019 = 240: a counter
    counter = names["SYNC"].get_signal_by_name("sync_counter")
    assert (counter.start, counter.length, counter.minimum, counter.maximum) == (0, 8, 1, 240)
    assert names["NMT"].frame_id == 0x000
    rpdo = db.get_message_by_frame_id(0x201)
    assert rpdo.name == "fl_RPDO1" and rpdo.length == 4 and rpdo.senders == ["master"]
    sig = rpdo.get_signal_by_name("fl_target_torque")
    assert (sig.start, sig.length, sig.is_signed, sig.byte_order, sig.unit) == (16, 16, True, "little_endian",
                                                                                 "permille")
    assert (sig.scale, sig.offset) == (1, 0)
    pos = db.get_message_by_frame_id(0x184).get_signal_by_name("rr_position_actual")
    assert (pos.start, pos.length, pos.is_signed, pos.unit) == (16, 32, True, "inc")
    vel = db.get_message_by_frame_id(0x283).get_signal_by_name("fr_velocity_actual")
    assert (vel.start, vel.length, vel.is_signed, vel.unit) == (0, 32, True, "inc/s")
    tq = db.get_message_by_frame_id(0x282).get_signal_by_name("rl_torque_actual")
    assert (tq.start, tq.length, tq.unit) == (32, 16, "permille")
    enc = db.get_message_by_frame_id(0x186).get_signal_by_name("right_position_value")
    assert (enc.start, enc.length, enc.is_signed, enc.unit) == (0, 32, False, "counts")
    sw = db.get_message_by_frame_id(0x181).get_signal_by_name("fl_statusword")
    assert (sw.start, sw.length, sw.is_signed) == (0, 16, False)
    assert db.get_message_by_frame_id(0x281).cycle_time == 2              # 0x1006 = 2000 µs, type 1
    pdo_ids = sorted(m.frame_id for m in db.messages if "PDO" in m.name)
    assert pdo_ids == [0x181, 0x182, 0x183, 0x184, 0x185, 0x186, 0x201, 0x202, 0x203, 0x204,
                       0x281, 0x282, 0x283, 0x284]


def test_recording_decodes_to_the_measurements(recording):
    frames, measurements, torques, dbc = recording
    db = cantools.database.load_file(dbc)
    d = decoded_by_id(frames, db)
    n = len(measurements)
    assert d[0x80] == [{"sync_counter": k % 240 + 1} for k in range(n)]
    assert {"nmt_command": 130, "nmt_node_id": 1} in d[0x000]               # reset communication
    assert {"nmt_command": 1, "nmt_node_id": 6} in d[0x000]                 # start
    assert {"fl_nmt_state": 0} in d[0x701]                                  # boot-up
    # TPDOs: the k-th frame of each COB-ID belongs to the k-th exchange (no PDO before NMT start)
    for cob_id in (0x181, 0x182, 0x183, 0x184, 0x281, 0x282, 0x283, 0x284, 0x185, 0x186):
        assert len(d[cob_id]) == n
    for k, m in enumerate(measurements):
        for i, w in enumerate(("fl", "rl", "fr", "rr")):
            tpdo1, tpdo2 = d[0x181 + i][k], d[0x281 + i][k]
            assert tpdo1[f"{w}_statusword"] & 0x6F == 0x27                  # OPERATION ENABLED
            assert tpdo1[f"{w}_position_actual"] * RAD_PER_INCREMENT == pytest.approx(
                m.motor_position[i], rel=1e-12, abs=1e-12)
            assert tpdo2[f"{w}_velocity_actual"] * RAD_PER_INCREMENT == pytest.approx(
                m.motor_velocity[i], rel=1e-12, abs=1e-12)
            assert tpdo2[f"{w}_torque_actual"] * RATED / 1000 == pytest.approx(m.motor_torque[i], abs=1e-12)
            rpdo = d[0x201 + i][k]
            assert rpdo[f"{w}_controlword"] == 0x000F
            expected = np.clip(np.rint(torques[k][i] * 1000 / RATED), -3000, 3000)
            assert rpdo[f"{w}_target_torque"] == expected
        alpha = [counts_to_alpha(d[0x185 + j][k][f"{s}_position_value"], BITS)
                 for j, s in enumerate(("left", "right"))]
        np.testing.assert_allclose(alpha, m.alpha, rtol=0, atol=1e-12)
    assert any(m.motor_velocity[1] < 0 for m in measurements)            # signed values were exercised
    assert measurements[-1].alpha[1] < 0


def test_every_pdo_frame_agrees_with_the_nodes_codec(recording):
    frames, _, _, dbc = recording
    db = cantools.database.load_file(dbc)
    drive = od.import_od(str(DRIVE_EDS), 1)
    encoder = od.import_od(str(ENCODER_EDS), 5)
    codecs = {}
    for base, dictionary, receive, nodes in ((0x1600, drive, True, range(1, 5)),
                                            (0x1A00, drive, False, range(1, 5)),
                                            (0x1A00, encoder, False, range(5, 7))):
        for n, cob in ((0, 0x180 if not receive else 0x200), (1, 0x280)):
            if base + n not in dictionary:
                continue
            mapping = dictionary[base + n]
            entries = [mapping[s].default for s in range(1, mapping[0].default + 1)]
            codec = build_codec(dictionary, entries, receive)
            for node in nodes:
                codecs[cob + node] = codec
    checked = 0
    for f in frames:
        codec = codecs.get(f.arbitration_id)
        if codec is None:
            continue
        signals = db.get_message_by_frame_id(f.arbitration_id).signals
        decoded = db.decode_message(f.arbitration_id, bytes(f.data), decode_choices=False)
        assert [decoded[s.name] for s in sorted(signals, key=lambda s: s.start)] == list(codec.unpack(f.data))
        checked += 1
    assert checked > 14 * 10


def _edit(text, section, key, value):
    """Replace ``key=...`` inside ``[section]`` of an EDS text."""
    head = f"[{section}]\n"
    start = text.index(head)
    end = text.find("\n[", start + 1)
    block = text[start:end]
    lines = [f"{key}={value}" if line.startswith(f"{key}=") else line for line in block.split("\n")]
    if not any(line.startswith(f"{key}=") for line in block.split("\n")):
        lines.insert(1, f"{key}={value}")
    return text[:start] + "\n".join(lines) + text[end:]


def test_follows_another_mapping_and_dcf_values(tmp_path):
    drive = DRIVE_EDS.read_text()
    lean = _edit(drive, "1A00sub1", "DefaultValue", "0x60770010")             # TPDO1 = torque + position
    lean = _edit(lean, "1801sub1", "DefaultValue", "0x80000000")              # TPDO2 disabled (bit 31)
    lean_path = tmp_path / "lean402.eds"
    lean_path.write_text(lean)
    encoder = ENCODER_EDS.read_text()
    padded = _edit(encoder, "1A00sub0", "DefaultValue", "2")                  # dummy byte, then 0x6004
    padded = _edit(padded, "1A00sub1", "DefaultValue", "0x00050008")
    padded = _edit(padded, "1A00sub2", "DefaultValue", "0x60040020")
    dcf = _edit(padded, "1800sub1", "ParameterValue", "0x1F5")                # DCF value beats default
    (tmp_path / "enc.eds").write_text(padded)
    (tmp_path / "enc.dcf").write_text(dcf)
    db = build_database(drive_eds=lean_path, encoder_eds=[tmp_path / "enc.eds", tmp_path / "enc.dcf"])
    tpdo1 = db.get_message_by_frame_id(0x181)
    assert tpdo1.length == 6
    assert [(s.name, s.start, s.length) for s in sorted(tpdo1.signals, key=lambda s: s.start)] == [
        ("fl_torque_actual", 0, 16), ("fl_position_actual", 16, 32)]
    assert not [m for m in db.messages if m.name.endswith("TPDO2")]
    left = db.get_message_by_frame_id(0x185)
    assert left.length == 5 and [(s.name, s.start) for s in left.signals] == [("left_position_value", 8)]
    right = db.get_message_by_frame_id(0x1F5)
    assert right.name == "right_TPDO1"
    assert db.decode_message(0x1F5, b"\xaa\x01\x02\x00\x00") == {"right_position_value": 0x0201}
    # a server with the lean mapping sends what the DBC says
    spec = f"virtual:hil-dbc-{uuid.uuid4().hex[:10]}"
    with VehicleServer(FakePlant(theta0=(1.0, 0, 0, 0)), spec, drive_eds=lean_path), \
            can.Bus(interface="virtual", channel=spec.split(":", 1)[1]) as bus:
        bus.send(can.Message(arbitration_id=0, data=[1, 0], is_extended_id=False))
        bus.send(can.Message(arbitration_id=0x80, data=[], is_extended_id=False))
        frame = None
        while frame is None or frame.arbitration_id != 0x181:
            frame = bus.recv(2.0)
            assert frame is not None
    assert db.decode_message(0x181, frame.data)["fl_position_actual"] == round(1.0 / RAD_PER_INCREMENT)


def test_errors(tmp_path):
    with pytest.raises(ValueError, match="one file or 4"):
        build_database(drive_eds=[DRIVE_EDS] * 3)
    with pytest.raises(FileNotFoundError):
        build_database(encoder_eds=tmp_path / "missing.eds")
    bad = _edit(ENCODER_EDS.read_text(), "1A00sub1", "DefaultValue", "0x60010020")   # 0x6001 not mappable
    (tmp_path / "bad.eds").write_text(bad)
    with pytest.raises(PdoMappingError, match="node 5 .*TPDO1.*not PDO-mappable"):
        build_database(encoder_eds=tmp_path / "bad.eds")
    clash = _edit(ENCODER_EDS.read_text(), "1800sub1", "DefaultValue", "0x181")      # = drive 1 TPDO1
    (tmp_path / "clash.eds").write_text(clash)
    with pytest.raises(ValueError, match="COB-ID 0x181"):
        build_database(encoder_eds=tmp_path / "clash.eds")


def test_the_sync_has_a_counter_only_where_every_node_sets_the_same_0x1019(tmp_path):
    """CiA 301 §7.2.5: 0x1019 = 0 is a SYNC without data; nodes that disagree get no counter signal."""
    text = DRIVE_EDS.read_text()
    at = text.index("[1019]")
    none = tmp_path / "none.eds"
    none.write_text(text[:at] + text[at:].replace("DefaultValue=240", "DefaultValue=0", 1))
    for drive, encoder in ((none, none), (DRIVE_EDS, none)):
        sync = build_database(drive_eds=drive, encoder_eds=encoder).get_message_by_name("SYNC")
        assert sync.length == 0 and sync.signals == []
