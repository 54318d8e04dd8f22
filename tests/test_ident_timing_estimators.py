"""Torque timing from the data and the estimators of ``qomni identify`` on one recorded quick campaign
(the prototype, seed 0, no single-axis run: B_w from the data sheet).

- A report lag is synthesised on the recording (the torque actual column shifted by δ, whole and
  fractional cycles, both signs); the estimate moves by δ within 0.2 ms and the corrected fit gives the
  parameters of the unshifted recording.
- The emulator's drives reporting torque actual sampled at the SYNC (effect ``torque_report_lag``, one
  cycle): the estimate reads 2 ms within 0.2 ms, and the exactly reporting prototype reads 0 within
  0.2 ms (its sensors sample the motion at the SYNC instant, docs/conventions.md).
- One drive's torque actual stuck at the maximum torque (0x6072) for 50 ms at a time, 1 % of the fitted
  rows (longer than the glitch repair's bursts): IRLS brings m_ch, C_ch, d_vw, d_cw back within 3 % of
  the truth where WLS is not.
- 1 % of the rows get glitches of several kinds (a saturated torque, a position off by turns, a zeroed
  row): repaired before filtering (the default), every estimator is within 3 %; fitted as recorded,
  WLS is off by far more.
"""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from qomni.cli import app
from qomni.datasheet import DataSheet
from qomni.embedded import embedded_vehicle
from qomni.emulator.description import VehicleDescription
from qomni.emulator.effects import EffectSet
from qomni.ident.campaign import IDENTIFICATION_STEPS, Campaign, CampaignSettings
from qomni.ident.identify import identify_run
from qomni.ident.regressor_rows import VELOCITY_THRESHOLD, correlation_lag, identification_blocks
from qomni.ident.rundir import load_run
from qomni.ident.torque_timing import estimate_torque_lag, shift_torque

pytestmark = pytest.mark.slow  # every test reads the module's campaign

CHASSIS = ("m_ch", "C_ch", "d_vw", "d_cw")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("timing_run")
    description = VehicleDescription.load()
    with embedded_vehicle(description, seed=0) as client:
        Campaign(DataSheet.load(), run_dir, CampaignSettings.quick(), source="test").run(client)
    return run_dir, description.truth


def _lag(signals, sheet, B_w):
    ts = sheet.drive.cycle_time
    return estimate_torque_lag(signals, lambda s: identification_blocks(s, sheet), B_w, ts,
                               VELOCITY_THRESHOLD, correlation_lag(ts))


@pytest.mark.parametrize("delta", [0.002, -0.0013])
def test_a_report_lag_is_estimated_within_0_2_ms(recorded, delta):
    signals, sheet, _ = load_run(recorded[0])
    base = _lag(signals, sheet, sheet.nominal.B_w)
    late = _lag(shift_torque(signals, -delta), sheet, sheet.nominal.B_w)   # reports δ behind
    assert abs((late.value - base.value) - delta) < 2e-4
    assert 0 < late.std < 2e-4


def test_drives_reporting_one_cycle_late_are_read_from_the_campaign(recorded, tmp_path):
    run_dir, _ = recorded
    description = VehicleDescription.load()
    late = EffectSet.combine(EffectSet.prototype(description),
                             EffectSet.from_dict({"torque_report_lag": {"lag": description.drive.cycle_time}}))
    with embedded_vehicle(description, seed=0, effects=late) as client:
        Campaign(DataSheet.load(), tmp_path / "late", CampaignSettings.quick(), source="test").run(client)
    exact = identify_run(shutil.copytree(run_dir, tmp_path / "exact"), torque_lag="auto")
    lagged = identify_run(tmp_path / "late", torque_lag="auto")
    assert abs(exact.torque_lag["estimate"]) < 2e-4, exact.torque_lag
    assert abs(lagged.torque_lag["estimate"] - description.drive.cycle_time) < 2e-4, lagged.torque_lag
    for name in ("m_ch", "C_ch", "d_vw", "d_cw", "d_cl", "d_cr"):
        assert lagged.values[name] == pytest.approx(exact.values[name], rel=5e-3), name


def test_the_fit_is_corrected_for_the_lag_and_reports_it(recorded, tmp_path):
    run_dir = tmp_path / "run"
    shutil.copytree(recorded[0], run_dir)
    base = identify_run(run_dir, torque_lag="auto")
    base_lag = json.loads((run_dir / "identification.json").read_text())["torque_lag"]["value"]
    signals, _, _ = load_run(run_dir)
    late = shift_torque(signals, -0.002)                       # the drives report one cycle late
    _write_torque(run_dir, late.motor_torque)
    uncorrected = identify_run(run_dir, torque_lag=0.0)
    corrected = identify_run(run_dir, torque_lag="auto")
    data = json.loads((run_dir / "identification.json").read_text())["torque_lag"]
    assert data["source"] == "estimated" and data["unit"] == "s"
    assert abs(data["value"] - base_lag - 0.002) < 2e-4
    rel = lambda r, n: abs(r.values[n] / base.values[n] - 1)  # noqa: E731
    assert max(rel(corrected, n) for n in CHASSIS) < 0.005
    assert max(rel(uncorrected, n) for n in CHASSIS) > 0.01     # the lag matters


def _write_columns(run_dir, columns: dict):
    """Replace whole columns of signals.csv: {header name: (N,) values}."""
    path = run_dir / "signals.csv"
    lines = path.read_text().splitlines()
    head = lines[0].split(",")
    at = {head.index(name): values for name, values in columns.items()}
    out = [lines[0]]
    for r, row in enumerate(lines[1:]):
        f = row.split(",")
        for c, values in at.items():
            f[c] = repr(float(values[r]))
        out.append(",".join(f))
    path.write_text("\n".join(out) + "\n")


def _write_torque(run_dir, torque):
    _write_columns(run_dir, {f"motor_torque_{w} [N m motor]": torque[:, j] for j, w in enumerate(("fl", "rl", "fr", "rr"))})


def test_irls_rejects_a_stuck_torque_reading_that_biases_wls(recorded, tmp_path):
    run_dir = tmp_path / "run"
    shutil.copytree(recorded[0], run_dir)
    signals, _, _ = load_run(run_dir)
    torque = signals.motor_torque.copy()
    # one drive's torque actual stuck at the maximum torque (0x6072) for 50 ms at a time, 1 % of the rows
    # the fit reads: longer than the bursts the glitch repair takes, so it reaches the estimators
    fitted = np.flatnonzero(np.isin(signals.step, IDENTIFICATION_STEPS))
    rng = np.random.default_rng(1)
    for start in rng.choice(fitted[:-25], size=len(fitted) // 2500, replace=False):
        torque[start:start + 25, rng.integers(4)] = 6.0
    _write_torque(run_dir, torque)
    truth = recorded[1]
    err = lambda r: {n: abs(r.values[n] / getattr(truth, n) - 1) for n in CHASSIS}  # noqa: E731
    wls = err(identify_run(run_dir, torque_lag=0.0, estimator="wls"))
    assert json.loads((run_dir / "identification.json").read_text())["spikes"]["total_corrupt"] == 0
    irls_result = identify_run(run_dir, torque_lag=0.0, estimator="irls")
    irls = err(irls_result)
    # the stuck readings bias WLS (by 10-20 % on a quick campaign); IRLS rejects them
    assert max(irls.values()) < 0.03 and max(wls.values()) > 0.05, (wls, irls)
    info = json.loads((run_dir / "identification.json").read_text())["estimator"]
    assert info["name"] == "irls" and info["rows_rejected"] > 0


def test_glitches_in_signals_are_repaired_before_every_estimator(recorded, tmp_path):
    run_dir = tmp_path / "run"
    shutil.copytree(recorded[0], run_dir)
    signals, _, _ = load_run(run_dir)
    rng = np.random.default_rng(7)
    rows = rng.choice(np.arange(5, len(signals) - 5), size=len(signals) // 100, replace=False)
    kind = rng.integers(0, 3, len(rows))
    position, velocity, torque, alpha = (signals.motor_position.copy(), signals.motor_velocity.copy(),
                                         signals.motor_torque.copy(), signals.alpha.copy())
    for row, k in zip(rows, kind):
        drive = rng.integers(4)
        if k == 0:
            torque[row, drive] = 6.0 * rng.choice([-1, 1])         # saturated reading
        elif k == 1:
            position[row, drive] += rng.choice([-1, 1]) * 2 * np.pi * rng.integers(1, 5)   # turns off
        else:
            position[row], velocity[row], torque[row], alpha[row] = 0.0, 0.0, 0.0, 0.0     # zeroed row
    columns = {}
    for block, name, units in ((position, "motor_position", "rad motor"), (velocity, "motor_velocity", "rad/s motor"),
                               (torque, "motor_torque", "N m motor")):
        for j, wheel in enumerate(("fl", "rl", "fr", "rr")):
            columns[f"{name}_{wheel} [{units}]"] = block[:, j]
    columns["alpha_l [rad]"], columns["alpha_r [rad]"] = alpha[:, 0], alpha[:, 1]
    _write_columns(run_dir, columns)
    truth = recorded[1]
    err = lambda r: max(abs(r.values[n] / getattr(truth, n) - 1) for n in CHASSIS)  # noqa: E731
    for estimator in ("wls", "irls", "consistent"):
        assert err(identify_run(run_dir, torque_lag=0.0, estimator=estimator)) < 0.03, estimator
    spikes = json.loads((run_dir / "identification.json").read_text())["spikes"]
    assert spikes["repaired"] and spikes["total_corrupt"] >= len(rows)
    assert spikes["corrupt_samples"]["motor_position_fl"] > 0
    assert err(identify_run(run_dir, torque_lag=0.0, estimator="wls", repair_spikes=False)) > 0.1
    assert json.loads((run_dir / "identification.json").read_text())["spikes"]["repaired"] is False


def test_cli_identify_takes_estimator_and_torque_lag(recorded, tmp_path):
    run_dir = tmp_path / "run"
    shutil.copytree(recorded[0], run_dir)
    runner = CliRunner()
    ok = runner.invoke(app, ["identify", str(run_dir), "--estimator", "consistent", "--torque-lag", "0.002"])
    assert ok.exit_code == 0, ok.output
    data = json.loads((run_dir / "identification.json").read_text())
    assert data["estimator"]["name"] == "consistent"
    assert data["torque_lag"] == pytest.approx({**data["torque_lag"], "value": 0.002, "cycles": 1.0})
    assert data["torque_lag"]["source"] == "configured" and abs(data["torque_lag"]["estimate"]) < 2e-3
    assert data["identifiability"]["d_vl"]["determined_by"] == ["steer_left"]
    assert data["identifiability"]["m_ch"]["determined_by"] == ["straight"]
    assert all(data["parameters"][n]["std_bootstrap"] > 0 for n in CHASSIS)
    assert "estimator consistent" in ok.output and "torque lag" in ok.output
    # the run's drives report on time: a configured one-cycle lag contradicts the campaign's own estimate
    assert "warning: the configured torque lag is" in " ".join(ok.output.split())
    kept = runner.invoke(app, ["identify", str(run_dir), "--keep-spikes"])
    assert kept.exit_code == 0, kept.output
    assert json.loads((run_dir / "identification.json").read_text())["spikes"]["repaired"] is False
    for args in (["--torque-lag", "soon"], ["--torque-lag", "0.5"], ["--estimator", "ols"]):
        bad = runner.invoke(app, ["identify", str(run_dir), *args])
        assert bad.exit_code == 2 and "error:" in bad.output and "Traceback" not in bad.output
    data["torque_lag"]["value"] = float("nan")                  # an edited identification.json
    (run_dir / "identification.json").write_text(json.dumps(data))
    bad = runner.invoke(app, ["validate", str(run_dir)])
    assert bad.exit_code == 2 and "torque_lag.value" in bad.output


def test_iv_with_instruments_from_the_simulated_model_agrees_with_wls(recorded, tmp_path):
    run_dir = tmp_path / "run"
    shutil.copytree(recorded[0], run_dir)
    wls = identify_run(run_dir, torque_lag=0.0)
    iv = identify_run(run_dir, torque_lag=0.0, estimator="iv")
    for n in CHASSIS:
        assert abs(iv.values[n] / wls.values[n] - 1) < 0.01
        assert 0 < iv.std[n] < 5 * wls.std[n]
    assert json.loads((run_dir / "identification.json").read_text())["estimator"]["name"] == "iv"


STEERING = ("C_l", "d_vl", "d_cl", "C_r", "d_vr", "d_cr")


def test_a_coarse_steering_sensor_is_differentiated_at_a_cutoff_it_resolves(recorded, tmp_path, monkeypatch):
    """The recording's steering angles read again by a 10-bit sensor (steps of 6.1 mrad), the data sheet
    saying so: differentiated at the Coulomb columns' 400 rad/s, the steering rate moves in steps of
    2.5 rad/s, the Coulomb columns' sign flips with each and the steering friction comes out far off; at
    the threshold over the step (33 rad/s, ``coulomb_steering_cutoff``) every steering parameter is within
    5 % of the truth. The 14-bit sensor keeps 400 rad/s."""
    import qomni.ident.regressor_rows as rows
    from qomni.datasheet import DataSheet

    assert rows.coulomb_steering_cutoff(DataSheet.load().drive) == rows.COULOMB_VELOCITY_CUTOFF
    run_dir = tmp_path / "run"
    shutil.copytree(recorded[0], run_dir)
    signals, _, _ = load_run(run_dir)
    step = 2 * np.pi / 2 ** 10
    alpha = np.round(np.asarray(signals.alpha) / step) * step
    _write_columns(run_dir, {"alpha_l [rad]": alpha[:, 0], "alpha_r [rad]": alpha[:, 1]})
    meta = json.loads((run_dir / "metadata.json").read_text())
    meta["datasheet"]["drive"]["steering_sensor_bits"] = 10
    (run_dir / "metadata.json").write_text(json.dumps(meta))
    truth = recorded[1]
    err = lambda r: {n: r.values[n] / getattr(truth, n) - 1 for n in STEERING}  # noqa: E731
    shipped = err(identify_run(run_dir, torque_lag=0.0))
    assert max(map(abs, shipped.values())) < 0.05, shipped
    cutoff = json.loads((run_dir / "identification.json").read_text())["coulomb_velocity_cutoff"]
    assert cutoff["steering"] == pytest.approx(0.2 / step) and cutoff["value"] == rows.COULOMB_VELOCITY_CUTOFF
    monkeypatch.setattr(rows, "coulomb_steering_cutoff", lambda drive: rows.COULOMB_VELOCITY_CUTOFF)
    at_400 = err(identify_run(run_dir, torque_lag=0.0))
    assert max(abs(at_400["d_vl"]), abs(at_400["d_vr"])) > 0.2, at_400

