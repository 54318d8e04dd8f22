"""The plant-can FMU (fmu.plant_can_spec): the plant behind its CAN bus at an FMI-LS-BUS CAN terminal.
Validated by fmpy and the FMU Manipulation Toolbox; driven with the campaign client's recorded frames
(tests/data/lockstep_trace.npz, the client against the emulator) and compared with the signal-level plant
FMU fed the torques the drives applied: plant outputs equal, TPDO contents equal to the quantized outputs,
statuswords equal to the emulator's drives. CiA 402 quick stop and SYNC loss, FMU state, malformed
operations."""
import shutil
import struct
import subprocess

import numpy as np
import pytest
from can import Message

fmpy = pytest.importorskip("fmpy")
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

import lockstep_trace  # noqa: E402
from doubles import identification  # noqa: E402
from qomni.datasheet import DataSheet  # noqa: E402
from qomni.fmu.cosim import MOTOR_TORQUE, REAL_OUTPUTS, FmuSlave  # noqa: E402
from qomni.fmu.export import export_plant_can_fmu, export_plant_fmu  # noqa: E402
from qomni.fmu.lsbus import CanBusSlave, CanFrame, FormatError, LsBusFormatError, decode, encode  # noqa: E402
from qomni.fmu.plant_can_spec import TORQUE_SLOPE  # noqa: E402
from qomni.hil.tools.recorder import sent_by_master  # noqa: E402
from qomni.hil.units import alpha_to_counts  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

SHEET = DataSheet.load()
TS = SHEET.drive.cycle_time
INC, BITS = SHEET.drive.encoder_increments, SHEET.drive.steering_sensor_bits
RATED = SHEET.drive.rated_torque
TWO_PI = 2 * np.pi


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("plant_can")
    return {"can": export_plant_can_fmu(identification(), SHEET, d / "plant_can.fmu"),
            "plant": export_plant_fmu(identification(), SHEET, d / "plant3.fmu", 3)}


def test_validated_and_fmi3_only(fmus, tmp_path):
    assert validate_fmu(str(fmus["can"])) == []
    check = subprocess.run(["fmutool", "-check", "-input", str(fmus["can"])], capture_output=True, text=True)
    assert "No semantic error" in check.stdout + check.stderr, check.stdout + check.stderr
    import zipfile
    names = zipfile.ZipFile(fmus["can"]).namelist()
    assert "terminalsAndIcons/terminalsAndIcons.xml" in names
    assert "extra/org.fmi-standard.fmi-ls-bus/fmi-ls-manifest.xml" in names
    from qomni.fmu.export import MODELS, export_fmu
    with pytest.raises(ValueError, match="FMI 3.0 only"):
        export_fmu(MODELS["plant-can"], identification(), SHEET, tmp_path / "x.fmu", 2)


def _rpdo(node, controlword, per_mille):
    return CanFrame(0x200 + node, struct.pack("<Hh", controlword, per_mille))


def _enable():
    """The PDO path's enable sequence (shutdown, then enable operation), one SYNC each."""
    return [[_rpdo(i, cw, 0) for i in range(1, 5)] + [CanFrame(0x80)] for cw in (0x06, 0x0F)]


def _client_events():
    """The campaign client's frames of the recorded trace split at its SYNCs: [frames before the first SYNC],
    then per SYNC [RPDOs..., SYNC]; and the emulator drives' statuswords (4,) per SYNC."""
    trace = np.load(lockstep_trace.REFERENCE)
    events, current, status = [], [], []
    for cob, dlc, data in zip(trace["arbitration_id"], trace["dlc"], trace["data"]):
        frame = CanFrame(int(cob), bytes(data[:dlc]))
        if 0x181 <= cob <= 0x184:
            status[-1][cob - 0x181] = int.from_bytes(frame.data[:2], "little")
        if not sent_by_master(Message(arbitration_id=int(cob), is_extended_id=False)):
            continue
        current.append(frame)
        if cob == 0x80:
            events.append(current)
            current = []
            status.append([None] * 4)
    first = events[0]
    k = len(first) - 1 - next(j for j, f in enumerate(reversed(first)) if f.can_id != 0x80 and not
                              0x201 <= f.can_id <= 0x204)
    return [first[:k + 1], first[k + 1:]] + events[1:], np.array(status)


def _sensors(y):
    """The TPDO contents the signal-level plant's outputs y (REAL_OUTPUTS order) imply."""
    out = dict(zip(REAL_OUTPUTS, y))
    mp = np.array([out[f"motor_position.{w}"] for w in ("fl", "rl", "fr", "rr")])
    mv = np.array([out[f"motor_velocity.{w}"] for w in ("fl", "rl", "fr", "rr")])
    position = ((np.floor(mp / TWO_PI * INC).astype(np.int64) + 2**31) % 2**32 - 2**31)
    velocity = np.rint(mv / TWO_PI * INC).astype(np.int64)
    return position, velocity, alpha_to_counts([out["alpha_l"], out["alpha_r"]], BITS)


def _tpdos(frames):
    by = {f.can_id: f.data for f in frames if isinstance(f, CanFrame)}
    status = [struct.unpack_from("<H", by[0x181 + i])[0] for i in range(4)]
    position = [struct.unpack_from("<i", by[0x181 + i], 2)[0] for i in range(4)]
    velocity = [struct.unpack_from("<i", by[0x281 + i])[0] for i in range(4)]
    torque = [struct.unpack_from("<h", by[0x281 + i], 4)[0] for i in range(4)]
    counts = [struct.unpack_from("<I", by[0x185 + j])[0] for j in range(2)]
    return np.array(status), np.array(position), np.array(velocity), np.array(torque), np.array(counts)


def _lockstep(fmus, events):
    """Drive the plant-can FMU with events (one Event Mode each, a step of T_s after each SYNC) and the
    signal-level plant FMU with the torques its drives applied; compare at every SYNC and step."""
    can = CanBusSlave(fmus["can"])
    plant = FmuSlave(fmus["plant"])
    assert [f.can_id for f in can.booted] == [0x701, 0x702, 0x703, 0x704, 0x705, 0x706]
    y_refs_can, y_refs = can.refs(REAL_OUTPUTS), plant.refs(REAL_OUTPUTS)
    u_refs = plant.refs(MOTOR_TORQUE)
    statuses, torques, worst = [], [], 0.0
    try:
        for frames in events:
            tx = can.exchange(frames)
            if not frames or frames[-1].can_id != 0x80:
                continue
            status, position, velocity, torque, counts = _tpdos(tx)
            y = plant.get_real(y_refs)
            assert np.array_equal(can.get_real(y_refs_can), y)
            p, v, c = _sensors(y)
            assert np.array_equal(position, p) and np.array_equal(velocity, v) and np.array_equal(counts, c)
            statuses.append(status)
            torques.append(torque)
            u = torque * (RATED / 1000.0)
            assert np.array_equal(can.get_real(can.refs(MOTOR_TORQUE)), u)
            plant.set_real(u_refs, u)
            can.step(TS)
            plant.step(TS)
            worst = max(worst, float(np.max(np.abs(can.get_real(y_refs_can) - plant.get_real(y_refs)))))
    finally:
        can.close()
        plant.close()
    return np.array(statuses), np.array(torques), worst


def test_campaign_client_frames_reproduce_the_signal_level_plant(fmus):
    events, emulator_status = _client_events()
    prefix, cycles = events[0], events[1:]
    statuses, torques, worst = _lockstep(fmus, [prefix] + _enable() + cycles)
    assert worst <= 1e-12
    assert np.all(statuses[2:] == emulator_status[:len(cycles)])     # the emulator's drives, same frames
    commanded = np.array([[struct.unpack("<h", f.data[2:4])[0] for f in ev if 0x201 <= f.can_id <= 0x204]
                          for ev in cycles])
    assert np.array_equal(torques[2:], commanded)                    # 0x6077 = the applied 0x6071
    assert np.any(commanded != 0)


def test_driving_quick_stop_and_sync_loss(fmus):
    drive = [[_rpdo(i, 0x0F, 750) for i in range(1, 5)] + [CanFrame(0x80)] for _ in range(250)]
    stop = [[_rpdo(i, 0x0B, 750) for i in range(1, 5)] + [CanFrame(0x80)] for _ in range(45)]
    statuses, torques, worst = _lockstep(fmus, [[CanFrame(0, b"\x01\x00")]] + _enable() + drive + stop)
    assert worst <= 1e-12
    ramp = torques[2 + 250:, 0]
    step = int(TORQUE_SLOPE * TS)
    assert ramp[0] == 750 - step and np.all(np.diff(ramp[ramp > 0]) == -step)   # 0x6087 ramp per SYNC
    assert statuses[2 + 250, 0] == 0x0217 and statuses[-1, 0] == 0x0260          # QUICK STOP ACTIVE → SOD

    can = CanBusSlave(fmus["can"])
    try:
        for frames in [[CanFrame(0, b"\x01\x00")]] + _enable() + drive[:10]:
            can.exchange(frames)
            can.step(TS)
        pending = [can.step(TS) for _ in range(int(0.1 / TS) + 2)]
        assert any(pending)
        tx = can.exchange([])
        emcy = [f for f in tx if isinstance(f, CanFrame) and 0x81 <= f.can_id <= 0x86]
        assert sorted(f.can_id for f in emcy) == list(range(0x81, 0x87))
        assert all(f.data[:3] == b"\x00\x81\x11" for f in emcy)
        assert np.all(can.get_real(can.refs(MOTOR_TORQUE)) == 0.0)
        status = _tpdos(can.exchange([CanFrame(0x80)]))[0]
        assert np.all(status == 0x0208)                                            # FAULT
    finally:
        can.close()



def test_fmu_state_carries_the_bus(fmus):
    frames = [[CanFrame(0, b"\x01\x00")]] + _enable() + [
        [_rpdo(i, 0x0F, 400 * (-1) ** i) for i in range(1, 5)] + [CanFrame(0x80)] for _ in range(30)]
    a = CanBusSlave(fmus["can"])
    b = CanBusSlave(fmus["can"], instance_name="restored")
    try:
        for f in frames[:20]:
            a.exchange(f)
            a.step(TS)
        a.exchange([_rpdo(1, 0x0F, 100)])                      # an RPDO waiting for the next SYNC
        state = a.fmu.serializeFMUState(a.fmu.getFMUState())
        b.fmu.setFMUState(b.fmu.deserializeFMUState(state))
        b.time = a.time
        for f in frames[20:]:
            assert a.exchange(f) == b.exchange(f)
            a.step(TS)
            b.step(TS)
        assert np.array_equal(a.get_real(a.refs(REAL_OUTPUTS)), b.get_real(b.refs(REAL_OUTPUTS)))
    finally:
        a.close()
        b.close()


def test_malformed_operations_are_answered_and_misuse_is_an_error(fmus):
    can = CanBusSlave(fmus["can"])
    try:
        good = encode([CanFrame(0, b"\x01\x00")])
        truncated = struct.pack("<II", 0x10, 40) + b"\x00" * 8
        tx = can.exchange_raw(good + struct.pack("<II", 0x99, 8) + truncated)
        errors = [f for f in tx if isinstance(f, FormatError)]
        assert [e.data[:4] for e in errors] == [struct.pack("<I", 0x99), struct.pack("<I", 0x10)]
        status = _tpdos(can.exchange([CanFrame(0x80)]))[0]                        # NMT start was taken
        assert np.all(status == 0x0260)
        can.fmu.enterEventMode()                               # no UpdateDiscreteStates: EnterStepMode processes
        can.fmu.setClock([can.rx_clock], [True])
        can.fmu.setBinary([can.rx_data], [encode([CanFrame(0x80)])])
        can.fmu.enterStepMode()
        assert can.step(TS)                                    # the SYNC's TPDOs wait: eventHandlingNeeded
        assert np.all(_tpdos(can.exchange([]))[0] == 0x0260)
        can.fmu.enterEventMode()
        with pytest.raises(FMICallException):                                      # Rx_Clock not active
            can.fmu.setBinary([can.rx_data], [good])
        with pytest.raises(FMICallException):                                      # an output clock
            can.fmu.setClock([can.tx_clock], [True])
        can.fmu.enterStepMode()
    finally:
        can.close()
    with pytest.raises(LsBusFormatError):
        decode(struct.pack("<II", 0x10, 12) + b"\x00" * 4)
    with pytest.raises(ValueError):
        CanFrame(0x800)
