"""Tests for ident.filtering: zero-phase low pass and derivatives."""

import numpy as np
import pytest

from qomni.ident import filtering as flt

T_S = 2e-3


def _sine(omega=5.0, duration=10.0, phase=0.3):
    t = np.arange(0.0, duration, T_S)
    return t, np.sin(omega * t + phase)


def _interior(t, margin=0.5):
    return (t > margin) & (t < t[-1] - margin)


def test_lowpass_preserves_phase_and_amplitude():
    omega = 5.0
    t, x = _sine(omega)
    y = flt.zero_phase_lowpass(x, T_S)
    m = _interior(t)
    # least-squares fit of amplitude and phase over the interior
    basis = np.column_stack([np.sin(omega * t[m]), np.cos(omega * t[m])])
    c, *_ = np.linalg.lstsq(basis, y[m], rcond=None)
    assert abs(np.arctan2(c[1], c[0]) - 0.3) < 1e-4
    assert abs(np.hypot(*c) - 1.0) < 1e-3
    assert np.max(np.abs(y[m] - x[m])) < 1e-3


def test_lowpass_attenuates_above_cutoff():
    t = np.arange(0.0, 10.0, T_S)
    y = flt.zero_phase_lowpass(np.sin(400.0 * t), T_S)
    assert np.max(np.abs(y[_interior(t)])) < 0.02
    # -6 dB (|H|² = 1/2) at omega_g for the forward-backward filter
    y = flt.zero_phase_lowpass(np.sin(flt.OMEGA_G * t), T_S)
    assert abs(np.max(np.abs(y[_interior(t, 1.0)])) - 0.5) < 0.01


def test_derivatives_of_sine():
    omega = 5.0
    t, x = _sine(omega)
    xf, xd, xdd = flt.zero_phase_derivatives(x, T_S)
    m = _interior(t)
    assert np.max(np.abs(xd[m] - omega * np.cos(omega * t[m] + 0.3))) < 2e-3 * omega
    assert np.max(np.abs(xdd[m] + omega**2 * np.sin(omega * t[m] + 0.3))) < 2e-3 * omega**2
    assert np.allclose(flt.derivative(x, T_S, 1)[m], omega * np.cos(omega * t[m] + 0.3), atol=1e-3)


def test_columns_are_independent():
    t, x = _sine(3.0)
    X = np.column_stack([x, 2.0 * x[::-1], np.cos(t)])
    Y = flt.zero_phase_lowpass(X, T_S)
    assert Y.shape == X.shape
    for j in range(3):
        assert np.allclose(Y[:, j], flt.zero_phase_lowpass(X[:, j], T_S))
    _, D1, D2 = flt.zero_phase_derivatives(X, T_S)
    assert D1.shape == D2.shape == X.shape


def test_short_and_bad_signals():
    n = flt.padlen()
    with pytest.raises(ValueError, match="padlen"):
        flt.zero_phase_lowpass(np.zeros(n), T_S)
    flt.zero_phase_lowpass(np.zeros(n + 1), T_S)
    with pytest.raises(ValueError, match="NaN"):
        flt.zero_phase_lowpass(np.array([0.0, np.nan] * 20), T_S)
    with pytest.raises(ValueError, match="Nyquist"):
        flt.design_lowpass(omega_g=2000.0, T_s=T_S)
    with pytest.raises(ValueError):
        flt.zero_phase_lowpass(np.zeros((20, 2, 2)), T_S)
