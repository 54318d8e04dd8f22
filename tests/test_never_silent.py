"""Never a silent wrong result: partial runs, bad files and ordinary mistakes end in one clear error (file,
line or section, key), and the CLI prints it plainly with a non-zero exit and no traceback."""
from __future__ import annotations

import gzip
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qomni.cli import app
from qomni.datasheet import DataSheet, DataSheetError
from qomni.emulator.description import DescriptionError, VehicleDescription
from qomni.ident.identify import identify_run
from qomni.ident.recording import RecordingError, SignalWriter, read_signals
from qomni.ident.rundir import (RunDirectoryError, b_w_source, read_lifted,
                                load_identification, load_run)
from qomni.vehicle_interface import Measurement

DATA = Path(__file__).parent / "data" / "fmu_accuracy_run"
PROTOTYPE = Path(__file__).resolve().parents[1] / "emulator" / "data" / "prototype.toml"
runner = CliRunner()


@pytest.fixture
def run_dir(tmp_path):
    """A recorded run (straight and rotation steps; the campaign stopped in the lane change)."""
    d = tmp_path / "run"
    d.mkdir()
    shutil.copy(DATA / "metadata.json", d)
    shutil.copy(DATA / "identification.json", d)
    with gzip.open(DATA / "signals.csv.gz", "rb") as f:
        (d / "signals.csv").write_bytes(f.read())
    return d


def _edit_metadata(run: Path, **changes) -> dict:
    meta = json.loads((run / "metadata.json").read_text())
    meta.update(changes)
    (run / "metadata.json").write_text(json.dumps(meta))
    return meta


def _cli(*args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return result


# --- 1. a partial run ---------------------------------------------------------------------------------
def test_identification_refuses_a_run_that_stopped_in_an_identification_step(run_dir):
    meta = json.loads((run_dir / "metadata.json").read_text())
    cut = [s for s in meta["segments"] if s["name"] != "rotation"]            # stopped during the rotation
    _edit_metadata(run_dir, segments=cut, status="aborted: KeyboardInterrupt: ")
    with pytest.raises(RunDirectoryError, match=r"did not complete .*rotation.*aborted"):
        identify_run(run_dir)
    signals, _, _ = load_run(run_dir)
    assert "rotation" not in signals.steps() and "straight" in signals.steps()   # its rows are left out
    result = _cli("identify", run_dir)
    assert result.exit_code == 2 and "rotation" in result.output and "Traceback" not in result.output


def test_validation_refuses_a_run_without_its_lane_change(run_dir):
    result = _cli("validate", run_dir)
    assert result.exit_code == 2 and "lane_change" in result.output


# --- 2. rows reversed or duplicated -------------------------------------------------------------------
@pytest.mark.parametrize("damage", ["reverse", "duplicate"])
def test_signals_with_rows_out_of_time_order_are_refused_with_their_line(run_dir, damage):
    lines = (run_dir / "signals.csv").read_text().splitlines()
    body = lines[1:]
    block = body[100:400]
    body = body[:100] + (block[::-1] if damage == "reverse" else block + block) + body[400:]
    (run_dir / "signals.csv").write_text("\n".join([lines[0], *body]) + "\n")
    with pytest.raises(RecordingError, match=r"signals.csv:\d+: time .* does not increase"):
        read_signals(run_dir / "signals.csv")


# --- 3. never appended; B_w from a single-axis run checked ----------------------------------------------
def test_a_recording_is_never_appended_to(tmp_path):
    m = Measurement(0.0, np.zeros(4), np.zeros(4), np.zeros(4), np.zeros(2))
    with SignalWriter(tmp_path / "signals.csv") as writer:
        writer.write("steer_left", 1, m, np.zeros(4))
    with pytest.raises(RecordingError, match="never appended"):
        SignalWriter(tmp_path / "signals.csv")


def test_single_axis_into_a_directory_that_holds_one_is_refused_without_force(tmp_path):
    (tmp_path / "single_axis").mkdir()
    (tmp_path / "single_axis" / "signals.csv").write_text("old run\n")
    result = _cli("single-axis", "--out", tmp_path)
    assert result.exit_code == 2 and "--force" in result.output
    assert (tmp_path / "single_axis" / "signals.csv").read_text() == "old run\n"


def test_a_single_axis_recording_with_a_frozen_encoder_is_refused_and_glitches_are_reported(tmp_path):
    from qomni.ident.single_axis import identify_single_axis

    assert _cli("single-axis", "--out", tmp_path).exit_code == 0
    assert json.loads((tmp_path / "single_axis.json").read_text())["spikes"]["total_corrupt"] == 0
    recording = tmp_path / "single_axis"
    _edit_column(recording, "motor_position_rr [rad motor]", lambda v: 1.0)
    with pytest.raises(RecordingError, match=r"single_axis/signals.csv: motor_position_rr does not move with"):
        identify_single_axis(tmp_path, DataSheet.load())


@pytest.mark.parametrize("value", [-0.121, 0.0, float("nan")])
def test_an_impossible_single_axis_b_w_is_refused(run_dir, value):
    (run_dir / "single_axis.json").write_text(json.dumps({"pooled": {"B_w": {"value": value}}}))
    with pytest.raises(RunDirectoryError, match="single_axis.json: pooled.B_w must be a finite, positive value"):
        b_w_source(run_dir, DataSheet.load())


_LIFTED = {"d_vw": {"value": 0.73, "std": 0.002}, "d_cw": {"value": 3.95, "std": 0.014}}


def _single_axis(pooled: dict | None = None, wheels: dict | None = None) -> str:
    """A complete single_axis.json, with ``pooled`` or ``wheels`` replaced."""
    return json.dumps({"pooled": pooled if pooled is not None else _LIFTED,
                       "wheels": wheels if wheels is not None else {
                           w: {"B_w": {"value": 0.12, "std": 0.0008}, **_LIFTED} for w in ("fl", "rl", "fr", "rr")}})


def test_lifted_wheels_of_another_vehicle_are_refused(run_dir, tmp_path):
    # a campaign replaced with --force --no-single-axis keeps single_axis.json beside it: another vehicle's
    # wheels would set B_w and the wheels' friction
    meta = json.loads((run_dir / "metadata.json").read_text())
    lifted = {**json.loads(_single_axis()), "vehicle": meta["vehicle"],
              "datasheet": {k: meta["datasheet"][k] for k in ("geometry", "drive")}}
    (run_dir / "single_axis.json").write_text(json.dumps(lifted))
    assert read_lifted(run_dir).friction["d_cw"] == (3.95, 0.014)
    (run_dir / "single_axis.json").write_text(json.dumps({**lifted, "vehicle": "heavy_platform"}))
    with pytest.raises(RunDirectoryError, match=r"single_axis.json: measured on the lifted wheels of "
                                                r"'heavy_platform', the run is of 'prototype' \(they differ in "
                                                "vehicle name"):
        read_lifted(run_dir)
    with pytest.raises(RunDirectoryError, match="lifted wheels of 'heavy_platform'"):
        b_w_source(run_dir, DataSheet.load())
    result = _cli("campaign", "--quick", "--no-single-axis", "--force", "--out", run_dir)
    assert result.exit_code == 2 and "lifted wheels" in result.output
    assert (run_dir / "signals.csv").exists()                            # refused before --force removed it
    lifted["datasheet"]["geometry"]["r"] = 0.2
    (run_dir / "single_axis.json").write_text(json.dumps(lifted))
    with pytest.raises(RunDirectoryError, match=r"they differ in geometry.r\)"):
        read_lifted(run_dir)


@pytest.mark.parametrize("key,field,value,message", [
    ("d_cw", "value", -0.1, "pooled.d_cw must be a finite, non-negative value"),
    ("d_vw", "std", 0.0, "pooled.d_vw must be a finite, non-negative value with a positive"),
    ("d_cw", "std", float("nan"), "pooled.d_cw must be"),
    ("d_vw", "value", None, "pooled.d_vw.value/std missing or not a number"),
])
def test_the_lifted_wheels_friction_is_read_only_when_it_is_physical(tmp_path, key, field, value, message):
    assert read_lifted(tmp_path) is None                                 # no single-axis run: no measurement
    pooled = json.loads(json.dumps(_LIFTED))
    (tmp_path / "single_axis.json").write_text(_single_axis(pooled))
    assert read_lifted(tmp_path).friction == {"d_vw": (0.73, 0.002), "d_cw": (3.95, 0.014)}
    if value is None:
        del pooled[key][field]
    else:
        pooled[key][field] = value
    (tmp_path / "single_axis.json").write_text(_single_axis(pooled))
    with pytest.raises(RunDirectoryError, match=f"single_axis.json: {message}"):
        read_lifted(tmp_path)


@pytest.mark.parametrize("damage,message", [
    (lambda w: w.pop("rr"), "wheels.rr.B_w.value/std missing"),
    (lambda w: w["fl"]["B_w"].update(value=0.0), "wheels.fl.B_w must be a finite, positive value"),
    (lambda w: w["rl"]["d_cw"].update(std=-1.0), "wheels.rl.d_cw must be a finite, non-negative value"),
])
def test_each_lifted_wheel_is_read_only_when_it_is_complete_and_physical(tmp_path, damage, message):
    wheels = {w: {"B_w": {"value": 0.12, "std": 0.0008}, **json.loads(json.dumps(_LIFTED))}
              for w in ("fl", "rl", "fr", "rr")}
    (tmp_path / "single_axis.json").write_text(_single_axis(wheels=wheels))
    assert read_lifted(tmp_path).wheels["fr"]["B_w"] == (0.12, 0.0008)
    damage(wheels)
    (tmp_path / "single_axis.json").write_text(_single_axis(wheels=wheels))
    with pytest.raises(RunDirectoryError, match=f"single_axis.json: {message}"):
        read_lifted(tmp_path)


# --- 4. a file cut short, a dead or reversed drive signal ---------------------------------------------------
def _edit_column(run: Path, column: str, change) -> None:
    lines = (run / "signals.csv").read_text().splitlines()
    at = lines[0].split(",").index(column)
    out = [lines[0]]
    for row in lines[1:]:
        f = row.split(",")
        f[at] = repr(float(change(float(f[at]))))
        out.append(",".join(f))
    (run / "signals.csv").write_text("\n".join(out) + "\n")


def test_a_signals_file_cut_short_of_its_metadata_is_refused_naming_the_step(run_dir):
    lines = (run_dir / "signals.csv").read_text().splitlines()
    (run_dir / "signals.csv").write_text("\n".join(lines[:1500]) + "\n")     # in the rotation
    with pytest.raises(RecordingError, match=r"step 'rotation' .* has \d+ of its 1002 rows; the file ends "
                                             r"at .* cut short"):
        load_run(run_dir)
    result = _cli("identify", run_dir)
    assert result.exit_code == 2 and "cut short" in result.output and "Traceback" not in result.output


def _rows_of(run: Path, step: str) -> list[int]:
    """Line indices (0 = header) of ``step``'s rows in the run's signals.csv."""
    lines = (run / "signals.csv").read_text().splitlines()
    return [i for i, line in enumerate(lines) if line.split(",")[1] == step]


def test_rows_missing_inside_a_step_are_refused_naming_the_line(run_dir):
    # 30 rows of a 12 s step are 0.25 %, within the count's tolerance; each shifts every later acceleration
    # of the step by a cycle, and took m_ch 11 % off on a full campaign
    lines = (run_dir / "signals.csv").read_text().splitlines()
    first = _rows_of(run_dir, "rotation")[100]
    (run_dir / "signals.csv").write_text("\n".join(lines[:first] + lines[first + 30:]) + "\n")
    with pytest.raises(RecordingError, match=rf"signals.csv:{first + 1}: time .* follows .*: 30 row\(s\) "
                                             "missing before it"):
        load_run(run_dir)
    result = _cli("identify", run_dir)
    assert result.exit_code == 2 and "missing before it" in result.output and "Traceback" not in result.output


def test_a_row_off_the_sync_grid_is_refused(run_dir):
    lines = (run_dir / "signals.csv").read_text().splitlines()
    at = _rows_of(run_dir, "straight")[50]
    cells = lines[at].split(",")
    cells[0] = repr(float(cells[0]) + 0.0011)
    lines[at] = ",".join(cells)
    (run_dir / "signals.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=rf"signals.csv:{at + 1}: .* its time off the SYNC grid"):
        load_run(run_dir)


def test_a_recording_cut_down_to_some_steps_still_reads(run_dir):
    # the fixture holds the straight and the rotation of a run, the steps between them left out: rows of two
    # steps seconds apart are no missing rows of either
    assert {"straight", "rotation"} <= set(load_run(run_dir)[0].step)


@pytest.mark.parametrize("column, change, message", [
    ("motor_torque_fl [N m motor]", lambda v: 1000 * v, r"column 'motor_torque_fl' is .* beyond the data sheet's "
                                                        r"max_torque 6 N m \(motor side\)"),
    ("alpha_r [rad]", lambda v: 180 / np.pi * v + 100, r"column 'alpha_r' is .* beyond the steering stops"),
])
def test_torques_and_angles_beyond_the_vehicles_limits_are_refused(run_dir, column, change, message):
    # per mille never converted, or degrees: the fit would take them for a vehicle hundreds of times heavier
    _edit_column(run_dir, column, change)
    with pytest.raises(RecordingError, match=message):
        load_run(run_dir)


def test_metadata_without_its_segments_is_refused(run_dir):
    meta = json.loads((run_dir / "metadata.json").read_text())
    meta.pop("segments")
    (run_dir / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(RunDirectoryError, match=r"metadata.json: no 'segments'"):
        load_run(run_dir)
    with pytest.raises(RunDirectoryError, match=r"metadata.json: no 'segments'"):
        identify_run(run_dir)


def test_segments_out_of_time_order_and_a_status_no_campaign_writes_are_refused(run_dir):
    meta = json.loads((run_dir / "metadata.json").read_text())
    _edit_metadata(run_dir, segments=meta["segments"][::-1])
    with pytest.raises(RunDirectoryError, match=r"segments\[1\] .* starts at .* before segments\[0\]"):
        load_run(run_dir)
    _edit_metadata(run_dir, segments=meta["segments"], status="bogus")
    with pytest.raises(RunDirectoryError, match=r"status 'bogus' is not one a campaign writes"):
        load_run(run_dir)


def test_a_key_given_twice_in_a_json_file_is_refused(run_dir):
    text = (run_dir / "metadata.json").read_text()
    (run_dir / "metadata.json").write_text(text.replace('"status"', '"status": "complete", "status"', 1))
    with pytest.raises(RunDirectoryError, match=r"metadata.json: key 'status' appears twice"):
        load_run(run_dir)


@pytest.mark.parametrize("key, setting, value, message", [
    ("settings", "lane_distance", float("nan"), r"settings.lane_distance must be finite"),
    ("settings", "steer_duration", -5.0, r"settings.steer_duration must be > 0"),
    ("settings", "bogus", 1.0, r"'settings' holds a setting no campaign knows"),
    ("controller", "torque_margin", "0.9", r"controller.torque_margin must be a number"),
])
def test_campaign_settings_no_campaign_drives_are_refused(run_dir, key, setting, value, message):
    # the digital twin drives the recorded settings again: a run whose settings no campaign drives did not
    # come from one
    meta = json.loads((run_dir / "metadata.json").read_text())
    _edit_metadata(run_dir, **{key: {**meta.get(key, {}), setting: value}})
    with pytest.raises(RunDirectoryError, match=rf"metadata.json: {message}"):
        load_run(run_dir)
    result = _cli("identify", run_dir)
    assert result.exit_code == 2 and setting in result.output and "Traceback" not in result.output


@pytest.mark.parametrize("value", ["2.5", "7", "-1"])
def test_a_motion_mode_that_is_not_one_is_refused(run_dir, value):
    lines = (run_dir / "signals.csv").read_text().splitlines()
    cells = lines[10].split(",")
    cells[2] = value
    lines[10] = ",".join(cells)
    (run_dir / "signals.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=rf"signals.csv:11: column 'k \[-\]' is {float(value)!r}"):
        read_signals(run_dir / "signals.csv")


def _set_mode(run: Path, step: str, k: int) -> list[int]:
    """The motion mode column of ``step``'s rows in signals.csv set to ``k``; their line indices."""
    lines = (run / "signals.csv").read_text().splitlines()
    rows = _rows_of(run, step)
    for at in rows:
        cells = lines[at].split(",")
        cells[2] = str(k)
        lines[at] = ",".join(cells)
    (run / "signals.csv").write_text("\n".join(lines) + "\n")
    return rows


def test_a_row_in_another_motion_mode_than_its_step_is_refused(run_dir):
    # each step is fitted with its first row's k: the rotation's rows relabelled mode 3 would fit mode 3's
    # regressor to a rotation
    rows = _set_mode(run_dir, "rotation", 3)
    with pytest.raises(RecordingError, match=rf"signals.csv:{rows[0] + 1}: motion mode k = 3 inside step "
                                             r"'rotation', which the metadata records in mode k = 4"):
        load_run(run_dir)


def test_a_step_whose_steering_is_off_its_modes_configuration_is_refused(run_dir):
    # rows and metadata agree on the mode, but the steering says the rows are another step's: a log
    # decoded with another campaign's metadata lays its steps over the wrong rows
    rows = _set_mode(run_dir, "rotation", 3)
    meta = json.loads((run_dir / "metadata.json").read_text())
    for seg in meta["segments"]:
        if seg["name"] == "rotation":
            seg["k"] = 3
    (run_dir / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match=rf"signals.csv:{rows[0] + 1}: the steering angles of step 'rotation' "
                                             r"\(mode 3\) lie 0\.6\d+ rad from the mode's configuration"):
        load_run(run_dir)


def test_a_complete_step_under_a_drifting_jittery_clock_is_complete():
    # a master whose SYNC period is 0.3 % off the nominal 2 ms, time stamps jittering by 50 µs: 30000 rows
    # over the step's 60.2 s are all there; two thirds of them are not
    from types import SimpleNamespace

    from qomni.ident.plausibility import check_coverage

    time = np.cumsum(np.full(30000, 0.002006) + np.random.default_rng(0).normal(0, 5e-5, 30000))
    step = [{"name": "straight", "k": 2, "t_start": 0.0, "t_end": float(time[-1])}]

    def rows(n: int) -> SimpleNamespace:
        return SimpleNamespace(time=time[:n], step=np.array(["straight"] * n), k=np.full(n, 2))

    check_coverage(rows(30000), step, 0.002, "run")
    with pytest.raises(RecordingError, match="has 20000 of its 30000 rows"):
        check_coverage(rows(20000), step, 0.002, "run")


def test_a_data_sheet_whose_cycle_time_is_not_the_recording_s_is_refused(run_dir):
    meta = json.loads((run_dir / "metadata.json").read_text())
    meta["datasheet"]["drive"]["cycle_time"] = 0.004           # the rows are 2 ms apart
    (run_dir / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match=r"rows are 0.002 s apart, the data sheet's cycle time is 0.004 s"):
        load_run(run_dir)


@pytest.mark.parametrize("column, change, message", [
    ("motor_torque_rl [N m motor]", lambda v: 0.0, r"motor_torque_rl is 0.0 N m in every row"),
    ("motor_torque_fr [N m motor]", lambda v: -v, r"motor_torque_fr does not follow the commanded torque "
                                                  r"\(rank correlation -1.00"),
    ("motor_position_fl [rad motor]", lambda v: 3.0, r"motor_position_fl does not move with motor_velocity_fl "
                                                     r"\(R² = 0.00"),
    ("motor_velocity_rr [rad/s motor]", lambda v: -v, r"motor_position_rr does not move with"),
])
def test_a_dead_or_reversed_drive_signal_is_refused(run_dir, column, change, message):
    # each of these still gives parameters, wrong ones (a zeroed torque actual: m_ch -26 %)
    _edit_column(run_dir, column, change)
    with pytest.raises(RecordingError, match=message):
        load_run(run_dir)


def _edit_wheel(run: Path, wheel: str, change) -> None:
    """``change(time, position, velocity)`` of one drive's motor-side position and velocity actual."""
    lines = (run / "signals.csv").read_text().splitlines()
    head = lines[0].split(",")
    at_x = head.index(f"motor_position_{wheel} [rad motor]")
    at_v = head.index(f"motor_velocity_{wheel} [rad/s motor]")
    out = [lines[0]]
    for row in lines[1:]:
        f = row.split(",")
        f[at_x], f[at_v] = (repr(float(v)) for v in change(float(f[0]), float(f[at_x]), float(f[at_v])))
        out.append(",".join(f))
    (run / "signals.csv").write_text("\n".join(out) + "\n")


def _spin(t0: float, duration: float, rate: float):
    """A wheel that spins ``rate`` (motor side, rad/s) faster than it rolls from t0 for ``duration``."""
    def change(t, x, v):
        inside = t0 < t <= t0 + duration
        return x + rate * min(max(t - t0, 0.0), duration), v + (rate if inside else 0.0)
    return change


def test_a_wheel_that_spins_or_lifts_is_refused_naming_it(run_dir):
    # a 2000 kg load 0.7 m off-centre lifted drive rl of the emulated prototype (600 rad/s on the motor
    # side against 38) through a whole campaign; identified as it was, m_ch came out 263 kg
    _edit_wheel(run_dir, "rl", _spin(11.0, 1.5, 600.0))
    with pytest.raises(RecordingError, match=r"signals.csv:\d+: wheel rl rolled \d\.\d+ m beyond the .* its contact "
                                             r"point travelled .* \(step 'straight'\).*spun or lifted"):
        load_run(run_dir)


def _scrub(t0: float, duration: float, factor: float):
    """A wheel that rolls ``factor`` times as fast as it did from t0 for ``duration`` (rows in time order)."""
    held = {}

    def change(t, x, v):
        if t <= t0:
            held["start"] = x
            return x, v
        if t <= t0 + duration:
            held["end"] = x
            return held["start"] + factor * (x - held["start"]), factor * v
        return x + (factor - 1) * (held["end"] - held["start"]), v
    return change


def test_tyres_within_their_tolerances_and_glitches_are_not_slip(run_dir):
    # a tyre 5 % under the data sheet's radius (worn); a wheel rolling 1.6 times its contact point's way
    # for a second, as the wheels scrub where steering friction at its range's end holds the steering
    # off the ICR; one wild position sample: none is a wheel off the ground
    _edit_wheel(run_dir, "fl", lambda t, x, v: (x / 0.95, v / 0.95))
    _edit_wheel(run_dir, "fr", _scrub(19.0, 1.0, 1.6))
    _edit_wheel(run_dir, "rr", lambda t, x, v: (x + (2000.0 if abs(t - 12.0) < 1e-3 else 0.0), v))
    load_run(run_dir)


def test_a_model_that_is_not_physical_is_refused_where_it_would_be_simulated(run_dir, tmp_path):
    data = json.loads((run_dir / "identification.json").read_text())
    data["parameters"]["m_ch"]["value"] = -800.0        # least squares can return it; no vehicle has it
    (run_dir / "identification.json").write_text(json.dumps(data))
    assert load_identification(run_dir).not_physical() == ["m_ch = -800.0"]
    for args in (["export-fmu", run_dir, "--out", tmp_path / "m.fmu"], ["twin", run_dir / "identification.json",
                                                                      "--out", tmp_path / "twin.toml"]):
        result = _cli(*args)
        assert result.exit_code == 2 and "m_ch = -800" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "m.fmu").exists() and not (tmp_path / "twin.toml").exists()


def test_the_remedy_for_a_model_that_is_not_physical_fits_how_far_below_zero_it_lies(run_dir):
    from dataclasses import replace

    result = load_identification(run_dir)
    assert result.not_physical_remedy() == ""
    # noise around a small parameter: a bound mends it
    small = replace(result, values={**result.values, "C_l": -0.5 * result.std["C_l"]})
    assert small.not_physical_remedy() == "identify with --estimator consistent"
    # far below zero: a value taken as known is wrong (a data-sheet B_w 10x the vehicle's: C_l -39 sigma)
    far = replace(result, values={**result.values, "C_l": -39 * result.std["C_l"]})
    assert re.match(r"C_l -39 σ lie far below zero, .*B_w = .*unmodelled effect", far.not_physical_remedy())
    # the consistent estimator's result at its bound is judged by its unbounded first pass, never sent back to it
    held = replace(result, estimator="consistent", values={**result.values, "C_l": 0.0},
                   std={**result.std, "C_l": 0.0},
                   values_ls={**result.values_ls, "C_l": -39 * result.std_ls["C_l"]})
    assert re.match(r"C_l -39 σ unbounded lie far below zero", held.not_physical_remedy())
    at_bound = replace(held, values_ls={**result.values_ls, "C_l": -0.5 * result.std_ls["C_l"]})
    assert "consistent fit holds them at their bound; where no bound" in at_bound.not_physical_remedy()


def test_another_vehicles_model_is_compared_parameter_by_parameter(run_dir, tmp_path):
    from qomni.cli.diagnose import _vehicle_difference

    other = tmp_path / "heavier"
    other.mkdir()
    shutil.copy(run_dir / "metadata.json", other)
    out = tmp_path / "gap"
    out.mkdir()
    _vehicle_difference(run_dir / "identification.json", other, out)       # the data's run not identified
    assert not (out / "vehicle_difference.json").exists()
    data = json.loads((run_dir / "identification.json").read_text())
    data["parameters"]["m_ch"]["value"] += 464.0                           # the heavy platform's difference
    (other / "identification.json").write_text(json.dumps(data))
    _vehicle_difference(run_dir / "identification.json", other, out)
    rows = json.loads((out / "vehicle_difference.json").read_text())["parameters"]
    m_ch = rows["m_ch"]
    assert m_ch["difference"] == pytest.approx(464.0) and m_ch["z"] == pytest.approx(464.0 / m_ch["std"])
    assert m_ch["std"] == pytest.approx(np.sqrt(2) * data["parameters"]["m_ch"]["std"])
    assert all(row["difference"] == 0 for name, row in rows.items() if name != "m_ch")


def test_a_campaign_whose_estimate_is_not_physical_keeps_it_and_skips_the_validation(run_dir, monkeypatch, capsys):
    import qomni.cli.campaign as campaign_cli
    import qomni.ident.identify as identify_module

    data = json.loads((run_dir / "identification.json").read_text())
    data["parameters"]["d_vl"]["value"] = -1.3                  # what WLS gave one blind-suite case
    (run_dir / "identification.json").write_text(json.dumps(data))
    monkeypatch.setattr(identify_module, "identify_run", lambda *a, **k: load_identification(run_dir))
    plotted = []
    monkeypatch.setattr(campaign_cli, "_plots", lambda run, result, validation: plotted.append(validation))
    campaign_cli._identify_and_report(run_dir, "wls", 0.0)       # no SystemExit: the recording stands
    assert plotted == [None]                                     # Fig. 5 only
    out = "".join(capsys.readouterr().out.split())
    assert "validationskipped:themodelisnotphysical(d_vl=-1.3)" in out and "--estimatorconsistent" in out
    assert not (run_dir / "validation.json").exists()


# --- 5. user text is never console markup --------------------------------------------------------------
def _printed(text: str, output: str) -> bool:
    """Whether ``text`` was printed, whatever the console's line wrapping did to its whitespace."""
    return "".join(text.split()) in "".join(output.split())


def test_brackets_in_paths_and_messages_are_printed_as_written(tmp_path):
    weird = tmp_path / "[/x]" / "[bold]run"
    result = _cli("identify", weird)
    assert result.exit_code == 2 and _printed("[/x]/[bold]run", result.output)
    effects = tmp_path / "e.toml"
    effects.write_text("[e]\nx = 1\n")
    result = _cli("campaign", "--out", tmp_path / "out", "--effects", effects)
    assert result.exit_code == 2 and _printed("[e]: unknown effect", result.output)


# --- 6. descriptions and data sheets ---------------------------------------------------------------------
@pytest.mark.parametrize("section, key, value, message", [
    ("truth", "C_ch", "inf", "must be finite"),
    ("truth", "m_ch", "nan", "must be finite"),
    ("body", "steering_unit_mass", "-5.0", "must be >= 0"),
    ("noise", "torque_measurement", "-0.01", "must be >= 0"),
    # wheels whose own inertia about the steering axis (8 kg at a = 0.08 m, and 0.17 kg m²) exceeds a left
    # steering unit's C_l/2 = 0.167 kg m²
    ("body", "wheel_transverse_inertia", "0.17", "steering inertia 0.3342 too small"),
    ("body", "steering_unit_mass", "150.0", "C_ch too small for the body masses"),
])
def test_vehicle_descriptions_refuse_non_finite_and_unphysical_values(tmp_path, section, key, value, message):
    text = PROTOTYPE.read_text()
    lines, inside = [], False
    for line in text.splitlines():
        if line.startswith("["):
            inside = line.strip() == f"[{section}]"
        if inside and line.split("=")[0].strip() == key:
            line = f"{key} = {value}"
        lines.append(line)
    path = tmp_path / "vehicle.toml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DescriptionError, match=message):
        VehicleDescription.load(path)


def test_effect_bodies_the_vehicles_steering_inertia_cannot_hold_are_refused_before_anything_runs(tmp_path):
    """Heavy steering units whose 40 kg wheels alone outweigh a steering unit's inertia about its axis
    (m_w a² beyond C_l/2): the campaign names the inertia, exits 2 without a traceback and writes nothing."""
    effects = tmp_path / "units.toml"
    effects.write_text("[heavy_steering_units]\nsteering_unit_mass = 30.0\nwheel_mass = 40.0\n")
    result = _cli("campaign", "--out", tmp_path / "out", "--quick", "--effects", effects)
    assert result.exit_code == 2 and _printed("too small for wheel_mass", result.output), result.output
    assert not isinstance(result.exception, DescriptionError) and not (tmp_path / "out").exists()


def test_a_vehicle_description_whose_section_is_not_a_table_is_refused_naming_it(tmp_path):
    """``noise = 0.1`` in place of a [noise] table: the description's reader names the section (it is
    the data sheet's table reader, with the description's error type)."""
    text = PROTOTYPE.read_text()
    head, _, tail = text.partition("[noise]")
    body = tail.split("\n[", 1)
    path = tmp_path / "vehicle.toml"
    path.write_text("noise = 0.1\n" + head + ("[" + body[1] if len(body) > 1 else ""))
    with pytest.raises(DescriptionError, match=r"\[noise\] must be a table"):
        VehicleDescription.load(path)


def test_a_data_sheet_refuses_a_cycle_time_no_can_bus_can_serve():
    text = (Path(__file__).resolve().parents[1] / "qomni" / "data" / "prototype_datasheet.toml").read_text()
    with pytest.raises(DataSheetError, match=r"\[drive\] key 'cycle_time' must be within"):
        DataSheet.loads(text.replace("cycle_time = 0.002", "cycle_time = 1e-9"), "sheet.toml")


# --- 7. ordinary mistakes: no traceback -----------------------------------------------------------------
def test_a_truncated_identification_is_a_clear_error(run_dir):
    text = (run_dir / "identification.json").read_text()
    (run_dir / "identification.json").write_text(text[: len(text) // 2])
    with pytest.raises(RunDirectoryError, match="identification.json: not valid JSON"):
        load_identification(run_dir)
    result = _cli("export-fmu", run_dir, "--out", run_dir / "x.fmu")
    assert result.exit_code == 2 and "not valid JSON" in result.output


def test_an_identification_in_another_unit_is_refused(run_dir):
    data = json.loads((run_dir / "identification.json").read_text())
    data["parameters"]["m_ch"]["unit"] = "g"
    (run_dir / "identification.json").write_text(json.dumps(data))
    with pytest.raises(RunDirectoryError, match=r"parameters.m_ch.unit is 'g'; this model's m_ch is in kg"):
        load_identification(run_dir)


def test_an_identification_whose_regressor_was_rank_deficient_is_refused(run_dir, tmp_path):
    # no fit writes a condition number beyond its rank tolerance: parameters so undetermined by the data
    # would be exported as an FMU that simulates nothing the vehicle does
    data = json.loads((run_dir / "identification.json").read_text())
    data["condition_number"] = 1e18
    (run_dir / "identification.json").write_text(json.dumps(data))
    with pytest.raises(RunDirectoryError, match=r"condition_number 1e\+18 is above 1e\+14.* rank-deficient"):
        load_identification(run_dir)
    result = _cli("export-fmu", run_dir / "identification.json", "--out", tmp_path / "m.fmu")
    assert result.exit_code == 2 and "rank-deficient" in result.output and not (tmp_path / "m.fmu").exists()


def test_a_model_of_another_vehicle_is_never_validated_exported_twinned_or_compared(run_dir, tmp_path):
    # its parameters hold for the vehicle they were identified on: on another vehicle's run, or with another
    # wheel radius or gear ratio, each command would give that other vehicle's behaviour without a word
    meta = json.loads((run_dir / "metadata.json").read_text())
    model = json.loads((run_dir / "identification.json").read_text())
    model.setdefault("run", {}).update(vehicle="heavy_platform", datasheet=meta["datasheet"])
    (run_dir / "identification.json").write_text(json.dumps(model))
    for args in (["validate", run_dir], ["export-fmu", run_dir, "--out", tmp_path / "m.fmu"],
                 ["twin", run_dir, "--out", tmp_path / "t.toml"], ["compare", run_dir]):
        result = _cli(*args)
        text = " ".join(result.output.split())
        assert result.exit_code == 2, args
        assert "identified on vehicle 'heavy_platform'" in text and "'prototype'" in text, args
    model["run"]["vehicle"] = meta["vehicle"]
    (run_dir / "identification.json").write_text(json.dumps(model))
    sheet = tmp_path / "other.toml"
    sheet.write_text((Path(__file__).parents[1] / "qomni" / "data" / "prototype_datasheet.toml").read_text()
                     .replace("i_G = 25.0", "i_G = 50.0"))
    for args in (["export-fmu", run_dir, "--out", tmp_path / "m.fmu", "--vehicle", sheet],
                 ["twin", run_dir, "--out", tmp_path / "t.toml", "--datasheet", sheet]):
        result = _cli(*args)
        assert result.exit_code == 2 and "drive.i_G" in result.output, args
    assert not (tmp_path / "m.fmu").exists() and not (tmp_path / "t.toml").exists()


def test_files_of_the_wrong_kind_are_refused_before_anything_runs(run_dir, tmp_path):
    # a twin written over the run's own identification.json, a stats file the histogram would overwrite,
    # a delay off the physics step's grid found only when the campaign starts
    for args, message in ((["twin", run_dir, "--out", run_dir / "identification.json"], "a .toml file"),
                          (["emulate", "--bus", "virtual:unopened", "--stats", tmp_path / "s.png"], "give a .json file"),
                          (["emulate", "--bus", "virtual:unopened", "--stats", tmp_path], "give a .json file")):
        result = _cli(*args)
        assert result.exit_code == 2 and message in " ".join(result.output.split()), args
    assert json.loads((run_dir / "identification.json").read_text())["parameters"]
    effects = tmp_path / "delay.toml"
    effects.write_text("[actuator_delay]\ndelay = 0.0015\n")
    result = _cli("campaign", "--quick", "--effects", effects, "--out", tmp_path / "new")
    assert result.exit_code == 2 and "not a multiple of the physics step" in " ".join(result.output.split())
    assert not (tmp_path / "new").exists()


def test_out_that_is_a_file_and_a_negative_seed_are_refused(tmp_path):
    (tmp_path / "file").write_text("")
    result = _cli("campaign", "--out", tmp_path / "file")
    assert result.exit_code == 2 and "is a file" in " ".join(result.output.split())   # a long path wraps
    result = _cli("campaign", "--out", tmp_path / "run", "--seed", "-1")
    assert result.exit_code == 2 and not (tmp_path / "run").exists()


def test_paths_of_the_wrong_kind_are_refused_without_a_traceback(run_dir, tmp_path):
    (tmp_path / "file").write_text("")
    result = _cli("diagnose", "--model", run_dir, "--data", run_dir, "--out", tmp_path / "file")
    assert result.exit_code == 2 and "is a file" in " ".join(result.output.split())
    result = _cli("twin", run_dir, "--out", tmp_path)
    assert result.exit_code == 2 and "is a directory" in " ".join(result.output.split())
    result = _cli("twin", run_dir, "--out", tmp_path / "nowhere" / "twin.toml")
    assert result.exit_code == 2 and "does not exist" in " ".join(result.output.split())
    assert not list(tmp_path.glob(".*.tmp"))
    (run_dir / "signals.csv").unlink()
    (run_dir / "signals.csv").mkdir()
    result = _cli("identify", run_dir)
    assert result.exit_code == 2 and "Is a directory" in " ".join(result.output.split())


def test_force_keeps_the_old_run_when_the_new_campaigns_inputs_are_refused(run_dir, tmp_path):
    bad = tmp_path / "bad.toml"                    # a valid data sheet, an emulator body that is not physical
    text = PROTOTYPE.read_text()
    assert "contact_stiffness = " in text
    bad.write_text("\n".join("contact_stiffness = -1.0" if line.startswith("contact_stiffness")
                             else line for line in text.splitlines()) + "\n")
    for args in (("--vehicle", bad), ("--excitation", "bogus"), ("--torque-lag", "nan")):
        result = _cli("campaign", "--quick", "--force", "--out", run_dir, *args)
        assert result.exit_code == 2 and "Traceback" not in result.output, args
        assert (run_dir / "signals.csv").exists() and (run_dir / "identification.json").exists(), args


def test_a_bad_bus_is_refused_before_anything_is_created(tmp_path):
    result = _cli("campaign", "--out", tmp_path / "run", "--bus", "nosuchinterface")
    assert result.exit_code == 2 and not (tmp_path / "run").exists()


# --- 7 (hil commands) ----------------------------------------------------------------------------------
@pytest.mark.parametrize("option, value", [("--sync-timeout", "-1"), ("--deadline", "-1"), ("--duration", "nan")])
def test_emulate_refuses_negative_times_before_starting(option, value):
    result = _cli("emulate", "--bus", "virtual:x", option, value)
    assert result.exit_code == 2 and option in result.output


def test_emulate_checks_the_stats_directory_before_running(tmp_path):
    result = _cli("emulate", "--bus", "virtual:x", "--duration", "0.1", "--stats", tmp_path / "no" / "s.json")
    assert result.exit_code == 2 and "does not exist" in " ".join(result.output.split())


def test_a_hub_on_a_port_in_use_is_a_clear_error():
    from qomni.hil.tools.hub import Hub

    with Hub(port=0) as running:
        result = _cli("hub", "--port", running.port)
    assert result.exit_code == 2 and "cannot listen" in result.output


# --- 10. fault plans ---------------------------------------------------------------------------------
@pytest.mark.parametrize("text, message", [
    ("[[bus_off]]\nat = nan\nduration = 0.1\n", "must be finite"),
    ("[[power_cycle]]\nnode = 3\nat = inf\noff = 0.5\n", "must be finite"),
    ("[latency]\nmean = 3600.0\n", "must be ≤ 1.0 s"),
])
def test_fault_plans_refuse_faults_that_never_fire_or_kill_the_sender(tmp_path, text, message):
    from qomni.hil.device.faults import FaultPlan, FaultPlanError

    path = tmp_path / "faults.toml"
    path.write_text(text)
    with pytest.raises(FaultPlanError, match=message):
        FaultPlan.load(path)


def test_pybullet_banners_stay_off_the_console():
    import subprocess
    import sys

    code = ("from qomni.emulator.vehicle import Emulator\n"
            "with Emulator() as emu:\n    emu.step(0.002)\nprint('stepped')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout == "stepped\n" and "pybullet build time" not in out.stderr and "argv[0]" not in out.stderr
