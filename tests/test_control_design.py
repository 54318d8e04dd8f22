"""The campaign controller's robustness to an actuator dead time: the steering design's phase margin
(python-control), the dead-time probe's fit, and a quick campaign at the realistic range's longest
actuator delay completing inside the torque limit."""
import json

import numpy as np
import pytest

from qomni.ident.control_design import delay_robust_bandwidth, design_pid, phase_margin, steering_loop
from qomni.ident.controller import ControllerSettings
from qomni.ident.probe import fit_dead_time

S = ControllerSettings()
TS = 0.002


def _margin(bandwidth, dead_time):
    gains = design_pid(bandwidth, S.damping, TS, S.steering_integral_ratio)
    return phase_margin(steering_loop(gains, TS, S.derivative_cutoff, dead_time), TS)


def test_the_default_steering_loop_keeps_its_bandwidth_without_dead_time_and_loses_its_margin_with_one():
    assert _margin(S.steering_bandwidth, 0.0) >= S.min_phase_margin
    assert _margin(S.steering_bandwidth, 0.02) < 0                      # the limit cycle of a 20 ms delay
    assert delay_robust_bandwidth(S.steering_bandwidth, S.damping, TS, S.steering_integral_ratio,
                                  S.derivative_cutoff, 0.0, S.min_phase_margin) == S.steering_bandwidth


@pytest.mark.parametrize("dead_time", [0.004, 0.01, 0.02, 0.03])
def test_the_redesigned_loop_meets_the_phase_margin_with_the_dead_time(dead_time):
    bw = delay_robust_bandwidth(S.steering_bandwidth, S.damping, TS, S.steering_integral_ratio,
                                S.derivative_cutoff, dead_time, S.min_phase_margin)
    assert bw < S.steering_bandwidth
    assert _margin(bw, dead_time) >= S.min_phase_margin
    assert _margin(bw + 1.0, dead_time) < S.min_phase_margin + 3.0      # the largest such bandwidth


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_phase_margin_agrees_with_python_control():
    import control

    loop = steering_loop(design_pid(30.0, 0.9, TS, 0.25), TS, 150.0, 0.004)
    reference = control.margin(loop)[1]
    assert phase_margin(loop, TS) == pytest.approx(reference, abs=0.5)


def test_a_dead_time_longer_than_a_turn_of_phase_is_counted_in_full():
    """At 45 rad/s a 50 ms dead time lags the crossover by more than 360°: the margin is that negative,
    and the bandwidth the probe's longest readings get keeps falling with them (a wrapped angle read
    42–68 ms as a margin above 30° and gave such readings the undelayed 45 rad/s)."""
    assert _margin(S.steering_bandwidth, 0.05) < -180.0
    bandwidths = [delay_robust_bandwidth(S.steering_bandwidth, S.damping, TS, S.steering_integral_ratio,
                                         S.derivative_cutoff, n * TS, S.min_phase_margin)
                  for n in range(0, 41, 4)]
    assert all(b >= c for b, c in zip(bandwidths, bandwidths[1:]))
    assert bandwidths[-1] < 5.0


@pytest.mark.parametrize("n", [0, 3, 10])
def test_the_probe_fit_recovers_a_dead_time_in_quantized_noisy_samples(n):
    rng = np.random.default_rng(n)
    t = TS * np.arange(1, 26)
    lsb = 2 * np.pi / 2**14
    moved = 30.0 * 0.5 * np.maximum(t - n * TS, 0) ** 2 + rng.normal(0, 0.3 * lsb, t.size)
    moved = np.round(moved / lsb) * lsb
    got, c, _ = fit_dead_time(moved, TS, 15)
    assert got == n and c == pytest.approx(30.0, rel=0.1)


@pytest.mark.slow
def test_a_quick_campaign_at_the_longest_realistic_actuator_delay_completes_inside_the_torque_limit(tmp_path):
    from qomni.suite.range_ends import campaign_margins

    row = campaign_margins({"actuator_delay": {"delay": 0.02}}, tmp_path / "run", seed=3)
    assert row.completed, row.status
    assert row.peak_torque_ratio < 0.9, row
    meta = json.loads((tmp_path / "run" / "metadata.json").read_text())
    assert 0.01 <= meta["probe"]["dead_time"] <= 0.022          # read up to 2 cycles early (docs/effects.md)



def test_the_probe_takes_the_stronger_pulses_reading_whose_onset_holds_less_friction():
    from qomni.datasheet import DataSheet
    from qomni.ident.probe import DeadTimeProbe

    probe = DeadTimeProbe(DataSheet.load())
    t = TS * np.arange(1, probe.cycles + 1)
    weak = 0.5 * 6.0 * np.maximum(t - 6 * TS, 0) ** 2         # friction: onset 12 ms at 10 rad/s²
    strong = 0.5 * 15.0 * np.maximum(t - 3 * TS, 0) ** 2      # and 6 ms at 20 rad/s²
    result = probe.evaluate([weak, strong])
    assert [p["dead_time"] for p in result.pulses] == pytest.approx([0.012, 0.006])
    assert result.dead_time == pytest.approx(0.006) and result.acceleration == pytest.approx(6.0, rel=0.05)
    delayed = [0.5 * a * np.maximum(t - 5 * TS, 0) ** 2 for a in (9.0, 18.0)]   # 10 ms at both
    assert probe.evaluate(delayed).dead_time == pytest.approx(0.010)
    assert probe.evaluate(delayed).steering_bandwidth < probe.evaluate([weak, strong]).steering_bandwidth < 45.0
    stuck = np.zeros(probe.cycles)                             # friction above the weak pulse's torque
    assert probe.evaluate([stuck, strong]).dead_time == pytest.approx(0.006)
    nothing = probe.evaluate([stuck, stuck])
    assert nothing.dead_time is None and nothing.steering_bandwidth == probe.safe_bandwidth


@pytest.mark.parametrize("effects", [{}, {"actuator_delay": {"delay": 0.012}}])
def test_the_probe_leaves_the_steering_at_rest_where_the_campaign_starts(effects):
    """Its returns at the 30 ms-safe bandwidth stay in the steering's static friction (up to 0.08 rad off);
    the final settle at the chosen bandwidth brings α to 0 before the campaign's first step, recorded as
    probe rows, one per SYNC."""
    from qomni.datasheet import DataSheet
    from qomni.emulator.description import VehicleDescription
    from qomni.emulator.effects import EffectSet
    from qomni.embedded import embedded_vehicle
    from qomni.ident.probe import DeadTimeProbe

    sheet = DataSheet.load()
    probe = DeadTimeProbe(sheet)
    rows = []
    with embedded_vehicle(VehicleDescription.load(), seed=1, effects=EffectSet.from_dict(effects)) as vehicle:
        measurement = vehicle.exchange(np.zeros(4))
        result, measurement = probe.run(vehicle, measurement, lambda m, u: rows.append(np.asarray(m.alpha)))
    lsb = sheet.drive.steering_lsb
    assert len(rows) == probe.total_cycles
    returned = rows[probe.total_cycles - probe._settle_cycles - 1]
    assert np.abs(returned).max() > 40 * lsb                                # where the returns leave it
    # at the start within the proportional loop's deadband against the steering's Coulomb friction at the
    # chosen bandwidth, d_c/(J·k_p) (∝ 1/bandwidth²), plus the sensor's noise
    n, g = sheet.nominal, sheet.geometry
    inertia = np.array([n.C_l, n.C_r]) + 2 * n.B_w * (g.a / g.r) ** 2
    kp = design_pid(result.steering_bandwidth, S.damping, TS, S.steering_integral_ratio).kp
    deadband = np.array([n.d_cl, n.d_cr]) / (inertia * kp)
    assert np.all(np.abs(measurement.alpha) <= deadband + 2 * lsb), (measurement.alpha, deadband)
    assert np.ptp(np.array(rows[-20:]), axis=0).max() <= 3 * lsb             # and at rest (sensor noise)
