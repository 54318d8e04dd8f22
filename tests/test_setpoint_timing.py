"""The torque report lag measured against the bus' set-point (ident/setpoint_lag.py) and the diagnosis'
rule that names or re-sizes a report lag and an actuator delay by it (diagnosis/setpoint_timing.py):
docs/conventions.md, "Torque timing", and docs/diagnosis.md, "Torque timing on the bus"."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from qomni.diagnosis.hypotheses.base import Magnitude
from qomni.diagnosis.setpoint_timing import report_lag_ruled_out, timing_by_setpoint
from qomni.ident.recording import Signals
from qomni.ident.setpoint_lag import SetpointLag, setpoint_lag

T_S, LIMIT = 0.002, 6.0


def _signals(lag_cycles: float, n: int = 6000, noise: float = 0.01, seed: int = 0, scale: float = 1.0) -> Signals:
    """Four drives' smooth random set-points and a torque actual that follows them ``lag_cycles`` late
    (interpolated in time), with white report noise (N m)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * T_S
    cmd = gaussian_filter1d(rng.normal(size=(n, 4)), 15, axis=0)
    cmd *= 4.0 / np.abs(cmd).max()
    reported = np.column_stack([np.interp(t - lag_cycles * T_S, t, c, left=0.0) for c in cmd.T])
    reported = scale * reported + rng.normal(scale=noise, size=reported.shape)
    zeros = np.zeros((n, 4))
    return Signals(t, np.full(n, "straight"), np.ones(n, dtype=int), np.zeros((n, 2)), zeros, zeros, reported,
                   cmd)


@pytest.mark.parametrize("cycles", [0.0, 0.4, 1.0, 2.0, 3.5])
def test_the_lag_of_the_torque_actual_behind_the_set_point_is_measured(cycles):
    m = setpoint_lag(_signals(cycles), T_S, LIMIT)
    assert m.value == pytest.approx(cycles * T_S, abs=2e-5) and m.cycles == pytest.approx(cycles, abs=0.01)
    assert 0 < m.std < 2e-5


def test_a_drive_whose_report_is_scaled_still_reads_its_lag():
    """A torque-constant error scales what a drive applies, not when it reports: the gain is fitted."""
    assert setpoint_lag(_signals(2.0, scale=0.9), T_S, LIMIT).cycles == pytest.approx(2.0, abs=0.01)


def test_clipped_set_points_are_left_out_and_a_recording_too_short_or_without_them_gives_none():
    s = _signals(1.0)
    clipped = replace(s, motor_torque_cmd=np.clip(s.motor_torque_cmd * 3, -LIMIT, LIMIT))
    assert setpoint_lag(clipped, T_S, LIMIT).rows < setpoint_lag(s, T_S, LIMIT).rows
    assert setpoint_lag(_signals(1.0, n=150), T_S, LIMIT) is None
    assert setpoint_lag(replace(s, motor_torque_cmd=np.zeros_like(s.motor_torque_cmd)), T_S, LIMIT) is None


def test_the_lags_sigma_holds_for_coloured_report_noise():
    """A real drive's torque actual carries its current loop's filtered noise, not white noise: over 40
    seeds of noise smoothed over a few cycles the lag's z-scores spread as a standard normal's (the
    Newey–West σ), where a σ for white noise (scaled for the lag-1 autocorrelation alone) would be twice
    too wide."""
    z = []
    for seed in range(40):
        s = _signals(1.5, seed=seed, noise=0.0)
        coloured = gaussian_filter1d(np.random.default_rng(1000 + seed).normal(size=s.motor_torque.shape), 2, axis=0)
        m = setpoint_lag(replace(s, motor_torque=s.motor_torque + 0.01 * coloured / coloured.std()), T_S, LIMIT)
        z.append((m.value - 1.5 * T_S) / m.std)
    assert 0.7 < np.std(z) < 1.5 and abs(np.mean(z)) < 1.0


@dataclass
class _Hyp:
    name: str


@dataclass
class _Cand:
    hypothesis: _Hyp
    magnitude: Magnitude
    significant: bool = False
    measured: str = ""
    notes: list = field(default_factory=list)


def _cand(name: str, ms: float, sd_ms: float, significant: bool = False) -> _Cand:
    v, s = ms * 1e-3, sd_ms * 1e-3
    return _Cand(_Hyp(name), Magnitude(v, (v - 1.96 * s, v + 1.96 * s), "s", name), significant)


def _lag(ms: float, sd_ms: float = 0.001) -> SetpointLag:
    return SetpointLag(ms * 1e-3, sd_ms * 1e-3, ms * 1e-3 / T_S, 40000, 0.01)


def _named(accepted) -> dict:
    return {c.hypothesis.name: (round(c.magnitude.value * 1e3, 2), c.measured) for c in accepted}


def test_a_delay_the_report_lag_hid_is_sized_and_the_lag_named_from_the_set_point():
    """8 ms delay and 4 ms report lag: the ground sees a 3.94 ms delay (their difference)."""
    delay, lag = _cand("actuator_delay", 3.94, 0.11, True), _cand("torque_report_lag", -3.92, 0.11)
    out = timing_by_setpoint([delay, lag], [delay], _lag(4.0), T_S)
    assert _named(out) == {"actuator_delay": (7.94, ""), "torque_report_lag": (4.0, "set-point")}


def test_a_report_lag_the_ground_named_whole_is_confirmed_and_no_delay_added():
    lag = _cand("torque_report_lag", 3.95, 0.1, True)
    out = timing_by_setpoint([lag, _cand("actuator_delay", -3.9, 0.1)], [lag], _lag(4.0), T_S)
    assert _named(out) == {"torque_report_lag": (4.0, "")}


def test_equal_lag_and_delay_that_the_ground_cannot_see_are_both_named_from_the_set_point():
    out = timing_by_setpoint([_cand("torque_report_lag", 0.02, 0.1), _cand("actuator_delay", 0.01, 0.1)], [],
                             _lag(4.0), T_S)
    assert _named(out) == {"torque_report_lag": (4.0, "set-point"), "actuator_delay": (3.98, "set-point")}


def test_a_report_lag_shortened_by_a_delay_names_the_delay():
    lag = _cand("torque_report_lag", 2.0, 0.1, True)
    out = timing_by_setpoint([lag, _cand("actuator_delay", -2.0, 0.1)], [lag], _lag(4.0), T_S)
    assert _named(out) == {"torque_report_lag": (4.0, ""), "actuator_delay": (2.0, "set-point")}


@pytest.mark.parametrize("measured", [None, _lag(0.6), _lag(4.0, 2.0)])
def test_no_lag_on_the_bus_changes_nothing(measured):
    """None (no set-points), under half a cycle, or not there (z < 3.29)."""
    delay = _cand("actuator_delay", 3.94, 0.11, True)
    assert timing_by_setpoint([delay], [delay], measured, T_S) == [delay]


@pytest.mark.parametrize("measured, ruled_out", [(None, False), (_lag(0.0), True), (_lag(0.5), True),
                                                  (_lag(0.6), False), (_lag(0.1, 0.5), False),
                                                  (_lag(4.0, 2.0), False), (_lag(4.0), False)])
def test_where_the_bus_bounds_the_report_lag_below_the_hypothesis_the_ground_is_not_asked_for_one(measured,
                                                                                                ruled_out):
    """With the set-point recorded the report lag is the bus' measurement: where its 95 % upper bound is
    under the shortest lag the hypothesis names (0.3 cycles, 0.6 ms), a report lag fitted to the ground's
    net shift would need a negative actuator delay, so the hypothesis is left out. A measurement that
    cannot bound it (σ 0.5 or 2 ms), or no set-points at all (None), leaves the ground's data to ask."""
    assert report_lag_ruled_out(measured, T_S) is ruled_out
