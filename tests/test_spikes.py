"""Isolated glitches in recorded signals (qomni.ident.spikes): found against the neighbours, repaired,
while the signal's own steps, turning points and noise are left as recorded."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from qomni.ident.recording import RecordingError, Signals
from qomni.ident.spikes import H, find_spikes, repair_spikes

TS = 0.002
COUNT = 2 * np.pi / 16384          # an encoder count, rad


def _motion(n: int, seed: int, noise: float, quantum: float = 0.0) -> np.ndarray:
    """A Fourier trajectory with turning points (as the campaign's), noise and quantisation."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * TS
    x = sum(a * np.sin(w * t + phi) for a, w, phi in
            zip(rng.uniform(1, 30, 4), rng.uniform(0.3, 6, 4), rng.uniform(0, 6, 4)))
    x = x + rng.normal(0, noise, n)
    return np.round(x / quantum) * quantum if quantum else x


def _steps(n: int, seed: int, noise: float) -> np.ndarray:
    """A torque-like signal: set-point steps every 0.5 s, each held, plus noise."""
    rng = np.random.default_rng(seed)
    levels = rng.uniform(-3, 3, n // 250 + 1)
    return np.repeat(levels, 250)[:n] + rng.normal(0, noise, n)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), quantised=st.booleans())
def test_a_clean_signal_is_left_as_recorded(seed, quantised):
    # Fourier motion with turning points, noise of 0.1-10 counts, with and without quantisation:
    # nothing stands apart (a flagged turning point would be repaired by less than a count)
    noise = np.random.default_rng(seed).uniform(0.1, 10) * COUNT
    x = _motion(20_000, seed, noise, COUNT if quantised else 0.0)
    corrupt, _ = find_spikes(x)
    repaired = x.copy()
    if corrupt.any():
        idx = np.arange(len(x))
        repaired[corrupt] = np.interp(idx[corrupt], idx[~corrupt], x[~corrupt])
    assert corrupt.sum() <= 3
    assert np.max(np.abs(repaired - x)) <= max(3 * noise, COUNT)


def test_the_steps_of_a_signal_are_kept():
    x = _steps(20_000, 1, 0.01)
    corrupt, steps = find_spikes(x)
    assert corrupt.sum() == 0
    assert steps >= 0.9 * (len(x) // 250)          # a step is seen, and kept


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_glitches_and_short_bursts_are_repaired_to_within_the_noise(seed):
    rng = np.random.default_rng(seed)
    n, noise = 30_000, 2 * COUNT
    clean = _motion(n, seed, noise, COUNT)
    x = clean.copy()
    starts = rng.choice(np.arange(20, n - 20, 40), size=n // 200, replace=False)   # 0.5-2.5 % of samples
    for s in starts:
        length = int(rng.integers(1, H + 1))
        x[s:s + length] = rng.choice([0.0, clean[s] + rng.choice([-1, 1]) * rng.uniform(0.05, 20),
                                      rng.uniform(-100, 100)])
    corrupt, _ = find_spikes(x)
    hit = np.abs(x - clean) > 0
    assert corrupt[hit & (np.abs(x - clean) > 50 * noise)].all()
    idx = np.arange(n)
    repaired = x.copy()
    repaired[corrupt] = np.interp(idx[corrupt], idx[~corrupt], x[~corrupt])
    # what stays is within the noise, or a glitch too small to stand out of it
    assert np.max(np.abs(repaired - clean)) < 50 * noise


def _signals(n: int, seed: int) -> Signals:
    pos = np.column_stack([_motion(n, seed + j, COUNT, COUNT) for j in range(4)])
    torque = np.column_stack([_steps(n, seed + j, 0.01) for j in range(4)])
    return Signals(time=np.arange(1, n + 1) * TS, step=np.array(["straight"] * n), k=np.ones(n, int),
                   alpha=np.column_stack([_motion(n, seed + 9, 1e-4), _motion(n, seed + 10, 1e-4)]) * 0.01,
                   motor_position=pos, motor_velocity=np.gradient(pos, TS, axis=0), motor_torque=torque,
                   motor_torque_cmd=torque.copy())


def test_repair_reports_each_column_and_can_keep_the_samples():
    signals = _signals(10_000, 3)
    glitched = Signals(**{f: getattr(signals, f).copy() for f in signals.__dataclass_fields__})
    glitched.motor_position[[100, 2000, 5000], 2] += 10.0
    glitched.motor_torque[[700, 800], 0] = 6.0
    repaired, report = repair_spikes(glitched)
    assert report.corrupt["motor_position_fr"] == 3 and report.corrupt["motor_torque_fl"] == 2
    assert report.total == 5 and report.repaired
    assert np.max(np.abs(repaired.motor_position - signals.motor_position)) < 2 * COUNT
    assert np.max(np.abs(repaired.motor_torque - signals.motor_torque)) < 0.05
    assert repaired.motor_torque_cmd is glitched.motor_torque_cmd          # the master's own value
    kept, report = repair_spikes(glitched, repair=False)
    assert kept is glitched and report.total == 5 and not report.repaired
    assert report.to_json_dict()["corrupt_samples"]["motor_position_fr"] == 3


def test_a_column_corrupt_beyond_single_glitches_is_refused():
    signals = _signals(10_000, 4)
    signals.motor_torque[::12, 3] = 6.0                                    # 8 % of the samples
    with pytest.raises(RecordingError, match=r"run/signals\.csv: column motor_torque_rr: .* samples"):
        repair_spikes(signals, "run/signals.csv")


def test_a_fast_motion_the_velocity_corroborates_is_kept():
    # a motor crossing a backlash gap and rebounding within 3 cycles: the position leaves its trend and
    # comes back, as a glitch would, but the velocity actual (0x606C, here d/T_s) moves with it
    n = 5_000
    pos = _motion(n, 5, 0.0, COUNT)
    pos[2000:2003] += 0.2
    vel = np.concatenate([[0.0], np.diff(pos) / TS])
    signals = _signals(n, 5)
    signals.motor_position[:, 1], signals.motor_velocity[:, 1] = pos, vel
    _, report = repair_spikes(signals)
    assert report.corrupt["motor_position_rl"] == 0 and report.corrupt["motor_velocity_rl"] == 0
    signals.motor_velocity[:, 1] = np.concatenate([[0.0], np.diff(_motion(n, 5, 0.0, COUNT)) / TS])
    _, report = repair_spikes(signals)                       # the same excursion the velocity did not see
    assert report.corrupt["motor_position_rl"] == 3
