"""Recording (BLF + candump -L), decoding a log into a run directory, and replay onto a bus."""
from __future__ import annotations

import json
import re
import time
import uuid
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path

import can
import numpy as np
import pytest
from typer.testing import CliRunner

from qomni.cli import app
from qomni.hil.master.client import VehicleClient
from qomni.hil.master.decode import DecodeError, DecodeReport, decode_log, node_files
from qomni.hil.tools.recorder import replay
from qomni.hil.device.server import VehicleServer
from doubles import BITS, INCREMENTS, T_S, FakePlant

N_CYCLES = 40


def torques(k):
    return np.array([0.5 * np.sin(k / 4), -0.3, 0.8 * np.cos(k / 7), 0.01 * k])


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """One lock-step session recorded in both formats; the client's measurements as reference."""
    tmp = tmp_path_factory.mktemp("rec")
    spec = f"virtual:hil-decode-{uuid.uuid4().hex[:8]}"
    plant = FakePlant(alpha=(0.3, -1.2))     # within the steering stops: the decoded run is read as a vehicle's
    logs = [tmp / "bus.blf", tmp / "bus.log"]
    reference = []
    with VehicleServer(plant, spec), VehicleClient(spec, encoder_increments=INCREMENTS,
                                                   steering_sensor_bits=BITS, cycle_time=T_S,
                                                   record=logs, timeout=5.0) as client:
        for k in range(N_CYCLES):
            reference.append((client.exchange(torques(k)), torques(k)))
    return tmp, logs, reference, plant


def test_candump_log_is_candump_format(session):
    _, logs, _, _ = session
    first = logs[1].read_text().splitlines()[0]
    assert first.startswith("(") and "#" in first                     # "(1700000000.000000) vcan0 701#00"
    assert len(list(can.LogReader(str(logs[0])))) == len(list(can.LogReader(str(logs[1]))))


@pytest.mark.parametrize("which", [0, 1], ids=["blf", "candump"])
def test_decode_reproduces_the_client_measurements(session, which):
    _, logs, reference, _ = session
    report = DecodeReport()
    cycles = list(decode_log(logs[which], encoder_increments=INCREMENTS, steering_sensor_bits=BITS,
                             cycle_time=T_S, report=report))
    assert report.cycles == N_CYCLES and report.incomplete == 0 and report.sessions == 1
    assert report.rated_torque == [2.0] * 4 and "SDO upload" in report.rated_torque_source
    for cycle, (m, cmd) in zip(cycles, reference):
        d = cycle.measurement
        assert d.time == pytest.approx(m.time)
        np.testing.assert_allclose(d.motor_position, m.motor_position, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(d.motor_velocity, m.motor_velocity, rtol=1e-12)
        np.testing.assert_allclose(d.motor_torque, m.motor_torque, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(d.alpha, m.alpha)
        np.testing.assert_allclose(cycle.motor_torque_cmd, np.clip(cmd, -6, 6), atol=0.5e-3 * 2.0)
        assert all(sw & 0x6F == 0x27 for sw in cycle.statusword)


def test_decode_with_another_mapping_needs_its_eds(session, tmp_path):
    _, logs, _, _ = session
    from qomni.hil.layout import DRIVE_EDS

    lean = tmp_path / "drive402.eds"
    lean.write_bytes(DRIVE_EDS.read_bytes().replace(b"DefaultValue=0x60640020", b"DefaultValue=0x60770010"))
    with pytest.raises(DecodeError, match="0x6064"):
        list(decode_log(logs[0], encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S,
                        files=node_files(eds_dir=tmp_path)))
    with pytest.raises(DecodeError, match="NodeID"):
        node_files(dcf=[lean])


def _run_metadata(tmp_path, segments: list[dict]):
    """A run's metadata.json for ``qomni decode --metadata``: the prototype's data sheet with the session's
    drives (encoder, steering sensor, T_s, rated torque) and ``segments``; returns its path."""
    from qomni.datasheet import DataSheet

    sheet = DataSheet.load()
    drive = replace(sheet.drive, encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S,
                    rated_torque=2.0)
    meta = {"format": "qomni-run/1", "vehicle": sheet.name, "status": "complete",
            "datasheet": {"geometry": asdict(sheet.geometry), "drive": asdict(drive),
                          "nominal": asdict(sheet.nominal)},
            "segments": segments}
    path = tmp_path / "metadata.json"
    path.write_text(json.dumps(meta))
    return path


def test_qomni_decode_writes_a_run_directory(session, tmp_path):
    from qomni.ident.rundir import load_run
    from qomni.cli import app

    _, logs, reference, _ = session
    metadata = _run_metadata(tmp_path, [{"name": "steer_left", "k": 1, "t_start": 0.0, "t_end": 20 * T_S},
                                        {"name": "steer_right", "k": 1, "t_start": 20 * T_S, "t_end": 39 * T_S}])
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["decode", str(logs[1]), "--out", str(out), "--metadata", str(metadata)])
    assert result.exit_code == 0, result.output
    signals, loaded_sheet, loaded_meta = load_run(out)
    assert signals.steps() == ["steer_left", "steer_right"] and len(signals) == 39   # t = 0 is in no segment
    np.testing.assert_allclose(signals.motor_position[0], reference[1][0].motor_position, atol=1e-12)
    assert loaded_meta["decoded"]["cycles"] == N_CYCLES and loaded_sheet.drive.cycle_time == T_S
    assert loaded_meta["decoded"]["cycles_outside_segments"] == N_CYCLES - 39
    assert f"{N_CYCLES - 39} cycle(s) outside the segments" in " ".join(result.output.split())
    again = CliRunner().invoke(app, ["decode", str(logs[1]), "--out", str(out)])
    assert again.exit_code == 2 and "--force" in again.output
    bad = CliRunner().invoke(app, ["decode", str(tmp_path / "missing.blf"), "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "does not exist" in " ".join(bad.output.split())
    assert not (tmp_path / "x").exists()


def test_a_log_that_lost_a_tpdo_decodes_and_its_run_is_refused_where_the_cycle_is_missing(session, tmp_path):
    """The cycle without node 3's TPDO is skipped; its row is missing between two rows of one step, which
    every reader of the run refuses, naming the line (never an acceleration across a hidden gap)."""
    from qomni.ident.recording import RecordingError
    from qomni.ident.rundir import load_run

    _, logs, _, _ = session
    lines = logs[1].read_text().splitlines()
    drops = [i for i, line in enumerate(lines) if " 183#" in line]
    log = tmp_path / "lossy.log"
    log.write_text("\n".join(lines[:drops[10]] + lines[drops[10] + 1:]) + "\n")
    metadata = _run_metadata(tmp_path, [{"name": "steer_left", "k": 1, "t_start": 0.0, "t_end": 39 * T_S}])
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["decode", str(log), "--out", str(out), "--metadata", str(metadata)])
    assert result.exit_code == 0 and "1 incomplete skipped" in result.output
    assert "every reader of the run refuses it" in " ".join(result.output.split())
    with pytest.raises(RecordingError, match=r"signals.csv:\d+: time .* follows .*: 1 row\(s\) missing before it"):
        load_run(out)


def _decode_lines(log: Path, lines: list[str]) -> tuple[list, DecodeReport]:
    """``lines`` written to ``log`` and decoded: the cycles and the decode's report."""
    log.write_text("\n".join(lines) + "\n")
    report = DecodeReport()
    return list(decode_log(log, encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S,
                           report=report)), report


def test_a_log_that_lost_a_sync_decodes_every_cycle_at_its_time(session, tmp_path):
    """A SYNC frame the logger lost: the next cycle's synchronous TPDOs come a second time before any SYNC,
    which CiA 301 forbids, so the cycle boundary is restored there and every later row keeps its time (not
    one cycle early). The same frame logged twice is dropped, not taken for a cycle."""
    _, logs, _, _ = session
    decode = partial(_decode_lines, tmp_path / "edited.log")
    lines = logs[1].read_text().splitlines()
    intact, _ = decode(lines)
    syncs = [i for i, line in enumerate(lines) if " 080#" in line]
    lossy = lines[:syncs[10]] + lines[syncs[10] + 1:]
    again = [i for i, line in enumerate(lossy) if " 183#" in line][20]
    lossy = lossy[:again + 1] + [lossy[again]] + lossy[again + 1:]
    cycles, report = decode(lossy)
    assert report.sync_restored == 1 and report.duplicates == 1 and report.incomplete == 0
    assert len(cycles) == len(intact) == N_CYCLES
    for got, want in zip(cycles, intact):
        assert got.measurement.time == want.measurement.time
        np.testing.assert_array_equal(got.measurement.motor_position, want.measurement.motor_position)
        np.testing.assert_array_equal(got.motor_torque_cmd, want.motor_torque_cmd)
    result = CliRunner().invoke(app, ["decode", str(tmp_path / "edited.log"), "--out", str(tmp_path / "run")])
    assert result.exit_code == 0 and "1 SYNC missing from the log restored" in " ".join(result.output.split())


def _real_time(lines: list[str]) -> list[str]:
    """The candump -L lines restamped as a real-time master's: each cycle's frames T_s after the last's."""
    out, cycle, within = [], 0, 0
    for line in lines:
        sync = " 080#" in line
        cycle, within = cycle + sync, 0 if sync else within + 1
        out.append(f"({1700000000.0 + cycle * T_S + 1e-5 * within:.6f}) {line.split(' ', 1)[1]}")
    return out


TPDOS = {0x181, 0x182, 0x183, 0x184, 0x185, 0x186, 0x281, 0x282, 0x283, 0x284}


def _cob(line: str) -> int:
    """COB-ID of a candump -L line."""
    return int(line.split()[2].split("#")[0], 16)


def _without_counter(lines: list[str]) -> list[str]:
    """The candump -L lines with the SYNC's counter taken out: a master that sends none."""
    return [re.sub(r" 080#[0-9A-F]{2}\b", " 080#", line) for line in lines]


def test_a_lock_step_log_that_lost_whole_cycles_counts_them_by_the_sync_counter(session, tmp_path):
    """A logger that lost SYNCs with every TPDO of their cycles: a lock-step log's stamps are wall time,
    but the SYNC's counter (CiA 301, 0x1019) says how many are missing, so the later cycles keep their
    time and the missing rows are there to be refused. Without a counter the same log is counted as logged."""
    _, logs, _, _ = session
    decode = partial(_decode_lines, tmp_path / "edited.log")
    lines = logs[1].read_text().splitlines()
    syncs = [i for i, line in enumerate(lines) if " 080#" in line]
    assert [lines[i].split()[2] for i in syncs[:3]] == ["080#01", "080#02", "080#03"]
    intact, report = decode(lines)
    assert not report.real_time_clock and report.sync_counter == N_CYCLES and len(intact) == N_CYCLES
    cycles, report = decode(lines[:syncs[10]] + lines[syncs[12]:])
    assert report.lost_cycles == 2 and report.incomplete == 1 and len(cycles) == N_CYCLES - 3
    times = [round(c.measurement.time, 9) for c in cycles]
    assert times == [round(c.measurement.time, 9) for c in intact[:9] + intact[12:]]   # 9: before the gap
    for got, want in zip(cycles[9:], intact[12:]):
        np.testing.assert_array_equal(got.measurement.motor_position, want.measurement.motor_position)
    assert report.warnings == []
    _, report = decode(_without_counter(lines[:syncs[10]] + lines[syncs[12]:]))
    assert report.sync_counter == 0 and report.lost_cycles == 0
    assert len(report.warnings) == 1 and "whole cycles the logger lost" in report.warnings[0]


def test_a_frame_logged_twice_stamped_apart_is_not_taken_for_a_lost_sync_where_the_sync_counts(session, tmp_path):
    """A logger that wrote cycle 10's last TPDO a second time, 0.1 ms later: it looks like the next cycle's
    frame after a lost SYNC, but SYNC 11's counter says none was lost, so it is a duplicate, and every row
    keeps its time; without the counter it is taken for a lost SYNC (every later row a cycle late), which
    is why the decode then warns that it cannot count."""
    _, logs, _, _ = session
    lines = logs[1].read_text().splitlines()
    syncs = [i for i, line in enumerate(lines) if " 080#" in line]
    last = max(i for i in range(syncs[10], syncs[11]) if _cob(lines[i]) in TPDOS)
    stamp, rest = lines[last].split(" ", 1)
    again = lines[:last + 1] + [f"({float(stamp[1:-1]) + 1e-4:.6f}) {rest}"] + lines[last + 1:]
    intact, _ = _decode_lines(tmp_path / "intact.log", lines)
    cycles, report = _decode_lines(tmp_path / "again.log", again)
    assert report.duplicates == 1 and report.sync_restored == 0 and report.lost_cycles == 0
    assert [c.measurement.time for c in cycles] == [c.measurement.time for c in intact]
    for got, want in zip(cycles, intact):
        np.testing.assert_array_equal(got.measurement.motor_position, want.measurement.motor_position)
    _, report = _decode_lines(tmp_path / "plain.log", _without_counter(again))
    assert report.sync_restored == 1 and report.warnings


def test_a_burst_that_left_one_complete_looking_cycle_of_two_is_not_decoded_as_one(session, tmp_path):
    """A logger's burst loss takes cycle 10's last TPDOs, SYNC 11 and cycle 11's first TPDOs: what is left
    between SYNC 10 and SYNC 12 is one frame of each COB-ID, two cycles' frames that look like one complete
    cycle. The SYNC counter shows SYNC 11 missing, so that cycle is skipped as well, never decoded as
    cycle 10's row."""
    _, logs, _, _ = session
    lines = logs[1].read_text().splitlines()
    syncs = [i for i, line in enumerate(lines) if " 080#" in line]
    tpdo = [i for i in range(syncs[10], syncs[12]) if _cob(lines[i]) in TPDOS]
    first_half = tpdo[:len(tpdo) // 4]                          # cycle 10's first TPDOs stay
    kept_11 = [i for i in tpdo if i > syncs[11]][len(first_half):]    # cycle 11's other TPDOs stay
    burst = set(range(syncs[10] + 1, syncs[12])) - set(first_half) - set(kept_11)
    burst = {i for i in burst if i == syncs[11] or i in tpdo}
    cobs = [lines[i].split()[2].split("#")[0] for i in sorted(set(tpdo) - burst)]
    assert sorted(cobs) == sorted(set(cobs)) and len(cobs) == len(tpdo) // 2   # one complete-looking set
    cycles, report = _decode_lines(tmp_path / "burst.log", [l for i, l in enumerate(lines) if i not in burst])
    assert report.lost_cycles == 1 and report.incomplete == 1 and report.sync_restored == 0
    assert [round(c.measurement.time / T_S) for c in cycles] == [k for k in range(N_CYCLES) if k not in (10, 11)]


def test_a_real_time_log_that_lost_whole_cycles_keeps_the_later_times(session, tmp_path):
    """A logger that lost a SYNC with every TPDO of its cycle, from a master that sends no SYNC counter: a
    real-time log's SYNC clock shows the gap, so the later cycles keep their time and the missing rows are
    there to be refused; a lock-step log's stamps are not real time and its cycles are counted as logged."""
    _, logs, _, _ = session
    decode = partial(_decode_lines, tmp_path / "edited.log")
    lines = _real_time(_without_counter(logs[1].read_text().splitlines()))
    intact, report = decode(lines)
    assert report.real_time_clock and report.lost_cycles == 0 and len(intact) == N_CYCLES and not report.warnings
    syncs = [i for i, line in enumerate(lines) if " 080#" in line]
    stamp, rest = lines[syncs[20]].split(" ", 1)                   # a SYNC 0.6 T_s late: jitter, not a loss
    late = lines[:syncs[20]] + [f"({float(stamp[1:-1]) + 0.6 * T_S:.6f}) {rest}"] + lines[syncs[20] + 1:]
    cycles, report = decode(late)
    assert report.real_time_clock and report.lost_cycles == 0 and len(cycles) == N_CYCLES
    lossy = lines[:syncs[10]] + lines[syncs[12]:]                  # two SYNCs and their TPDOs gone
    at = syncs[10]                                                 # the next SYNC, logged three times
    lossy = lossy[:at] + [lossy[at]] * 2 + lossy[at:]
    cycles, report = decode(lossy)
    assert report.lost_cycles == 2 and report.duplicates == 2 and len(cycles) == N_CYCLES - 3
    times = {round(c.measurement.time, 9) for c in cycles}
    assert times == {round(c.measurement.time, 9) for c in intact} - {round(c.measurement.time, 9) for c in
                                                                       intact[9:12]}
    lockstep = _without_counter(logs[1].read_text().splitlines())
    syncs = [i for i, line in enumerate(lockstep) if " 080#" in line]
    _, report = decode(lockstep[:syncs[10]] + lockstep[syncs[12]:])
    assert not report.real_time_clock and report.lost_cycles == 0


def test_a_cycle_time_other_than_the_one_the_master_set_is_refused(session):
    """The time is the SYNC count × T_s; the log holds the 0x1006 the master wrote to its nodes, and a T_s
    from another data sheet would stretch every time and rate."""
    _, logs, _, _ = session
    with pytest.raises(DecodeError, match=r"set the communication cycle period 0x1006 of node 1 to 2000 µs; the "
                                          r"cycle time given is 4000 µs"):
        list(decode_log(logs[1], encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=2 * T_S))


def test_replay_of_the_master_frames_reproduces_the_run(session):
    """The recorded master frames, replayed onto a fresh emulator, drive it through the same states."""
    from qomni.hil.tools.recorder import sent_by_master as _sent_by_master

    _, logs, _, original = session
    spec = f"virtual:hil-replay-{uuid.uuid4().hex[:8]}"
    plant = FakePlant()
    with VehicleServer(plant, spec) as server:
        bus = can.Bus(interface="virtual", channel=spec.split(":")[1])
        try:
            sent = replay(logs[1], bus, realtime=False, only=_sent_by_master)
        finally:
            bus.shutdown()
        end = time.monotonic() + 5
        while server.cycles < N_CYCLES and time.monotonic() < end:
            time.sleep(0.01)
    assert sent > N_CYCLES * 5
    assert server.cycles == N_CYCLES
    np.testing.assert_array_equal(plant.theta, original.theta)


def test_a_bad_candump_line_names_the_file_and_frame(session, tmp_path):
    _, logs, _, _ = session
    lines = logs[1].read_text().splitlines()
    bad = tmp_path / "bad.log"
    bad.write_text("\n".join([*lines[:50], "(17000 garbage line", *lines[50:]]) + "\n")
    with pytest.raises(DecodeError, match=r"bad.log: cannot read frame 51 \(after 50 good frames\)"):
        list(decode_log(bad, encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S))


def test_a_cut_blf_decodes_its_first_part_with_a_warning(session, tmp_path):
    _, logs, _, _ = session
    data = logs[0].read_bytes()
    cut = tmp_path / "cut.blf"
    cut.write_bytes(data[: len(data) // 2])
    report = DecodeReport()
    cycles = list(decode_log(cut, encoder_increments=INCREMENTS, steering_sensor_bits=BITS, cycle_time=T_S,
                             report=report))
    assert len(cycles) < N_CYCLES and any("the file is cut" in w for w in report.warnings)
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["decode", str(cut), "--out", str(out)])
    assert result.exit_code == 0 and "the file is cut" in " ".join(result.output.split())
    assert json.loads((out / "metadata.json").read_text())["decoded"]["warnings"]


def test_a_candump_log_cut_within_a_line_decodes_its_complete_lines_with_a_warning(session, tmp_path):
    """A line cut inside its data would parse into a frame with part of its bytes (a wrong last cycle):
    the cut line is left out, and the rest decodes as the same log ended at its last complete line."""
    _, logs, _, _ = session
    text = logs[1].read_text()
    lines = text.splitlines(keepends=True)
    keep = len(lines) // 2
    while "#" not in lines[keep] or len(lines[keep].split("#", 1)[1].strip()) < 4:   # a line with data
        keep += 1
    whole = tmp_path / "whole.log"
    whole.write_text("".join(lines[:keep]))
    cut = tmp_path / "cut.log"
    cut.write_text("".join(lines[:keep]) + lines[keep].rstrip("\n")[:-3])      # within the data field
    decoded = {}
    for path in (whole, cut):
        report = DecodeReport()
        decoded[path] = (list(decode_log(path, encoder_increments=INCREMENTS, steering_sensor_bits=BITS,
                                         cycle_time=T_S, report=report)), report)
    (cycles, report), (reference, ref_report) = decoded[cut], decoded[whole]
    assert 0 < len(cycles) == len(reference) < N_CYCLES and report.frames == ref_report.frames
    for a, b in zip(cycles, reference):
        np.testing.assert_array_equal(a.measurement.motor_position, b.measurement.motor_position)
        np.testing.assert_array_equal(a.measurement.motor_torque, b.measurement.motor_torque)
    assert any("has no line end: the file is cut" in w for w in report.warnings) and not ref_report.warnings
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["decode", str(cut), "--out", str(out)])
    assert result.exit_code == 0 and "the file is cut" in " ".join(result.output.split())


def test_a_failed_decode_leaves_nothing_that_blocks_its_rerun(session, tmp_path):
    _, logs, _, _ = session
    bad = tmp_path / "bad.log"
    bad.write_text("(17000 garbage line\n")
    out = tmp_path / "run"
    failed = CliRunner().invoke(app, ["decode", str(bad), "--out", str(out)])
    assert failed.exit_code == 2 and "bad.log" in failed.output
    again = CliRunner().invoke(app, ["decode", str(logs[1]), "--out", str(out)])
    assert again.exit_code == 0, again.output
