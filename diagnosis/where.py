"""Where the model and the data differ: the residual broken down by campaign step / motion mode,
channel, operating regime, frequency band and time window, plus whiteness and input
cross-correlation tests that tell noise from structure.

All numbers are over a channel's moving rows unless stated; residual = measured − model (the given
model, no re-fit). Residuals of ω_g-filtered signals are correlated over ≈ L rows
(``ident.identify.correlation_lag``), so the tests decimate by L first.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import signal, stats

from .channels import ChannelData

#: Frequency bands of the residual spectrum, Hz (ω_g = 40 rad/s ≈ 6.4 Hz is the filter's cut-off).
BANDS = ((0.0, 0.5), (0.5, 2.0), (2.0, 6.4), (6.4, 25.0))
#: Lags of the whiteness test (Ljung–Box), in decimated samples.
LJUNG_BOX_LAGS = 10
WINDOW = 2.0  # s, time-window breakdown
KINEMATIC_STANDSTILL = 0.05  # rad/s of steering below which a kinematic row counts as standstill


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def regimes(ch: ChannelData) -> dict:
    """RMS residual per operating regime: near standstill, slow/fast (split at the moving rows'
    median |ṡ|), low/high |s̈| and small/large |α| (split at 0.2 rad)."""
    r = ch.residual
    v, acc = np.abs(ch.velocity), np.abs(ch.acceleration)
    # Torque channels: the rows above the stiction threshold (ident.identify.VELOCITY_THRESHOLD).
    moving = ch.fitted if ch.kind == "torque" else v > KINEMATIC_STANDSTILL
    out = {"near_standstill": {"rms": _rms(r[~moving]), "rows": int((~moving).sum())}}
    if moving.any():
        v_med = float(np.median(v[moving]))
        a_med = float(np.median(acc[moving]))
        out["slow"] = {"rms": _rms(r[moving & (v <= v_med)]), "rows": int((moving & (v <= v_med)).sum()),
                       "below": v_med}
        out["fast"] = {"rms": _rms(r[moving & (v > v_med)]), "rows": int((moving & (v > v_med)).sum())}
        out["low_acceleration"] = {"rms": _rms(r[moving & (acc <= a_med)]),
                                   "rows": int((moving & (acc <= a_med)).sum()), "below": a_med}
        out["high_acceleration"] = {"rms": _rms(r[moving & (acc > a_med)]),
                                    "rows": int((moving & (acc > a_med)).sum())}
    alpha = np.max(np.abs(ch.rows(ch.context.st.q[:, 3:5])), axis=1)
    small = alpha <= 0.2
    out["small_steering_angle"] = {"rms": _rms(r[small & ch.fitted]), "rows": int((small & ch.fitted).sum())}
    out["large_steering_angle"] = {"rms": _rms(r[~small & ch.fitted]),
                                   "rows": int((~small & ch.fitted).sum())}
    return out


def bands(ch: ChannelData) -> dict:
    """Fraction of the residual's power per frequency band (Welch periodogram)."""
    r = ch.residual - np.mean(ch.residual)
    fs = 1.0 / ch.context.st.cycle_time
    f, pxx = signal.welch(r, fs=fs, nperseg=min(1024, len(r)))
    total = float(np.trapezoid(pxx, f)) if len(f) > 1 else 0.0
    out = {}
    for lo, hi in BANDS:
        m = (f >= lo) & (f < hi)
        out[f"{lo:g}-{hi:g} Hz"] = float(np.trapezoid(pxx[m], f[m]) / total) if total > 0 and m.sum() > 1 else 0.0
    return out


def windows(ch: ChannelData, window: float = WINDOW) -> list[dict]:
    """RMS residual per time window of the step."""
    t, r = ch.time, ch.residual
    out = []
    start = t[0]
    while start < t[-1]:
        m = (t >= start) & (t < start + window) & ch.fitted
        if m.any():
            out.append({"t0": float(start), "t1": float(start + window), "rms": _rms(r[m])})
        start += window
    return out


def whiteness(ch: ChannelData, lag: int) -> dict:
    """Ljung–Box test on the residual decimated by the correlation length L: p < 0.001 says the
    residual is structured, not noise."""
    r = ch.residual[ch.fitted][::max(lag, 1)]
    r = r - r.mean() if len(r) else r
    n = len(r)
    h = min(LJUNG_BOX_LAGS, n // 4)
    if n < 8 or h < 1 or not np.any(r):
        return {"q": float("nan"), "p_value": float("nan"), "samples": n}
    acf = np.array([np.sum(r[k:] * r[:-k]) for k in range(1, h + 1)]) / np.sum(r * r)
    q = float(n * (n + 2) * np.sum(acf**2 / (n - np.arange(1, h + 1))))
    return {"q": q, "p_value": float(stats.chi2.sf(q, h)), "samples": n, "lags": h}


def input_correlation(ch: ChannelData, lag: int) -> dict:
    """Largest normalised cross-correlation of the residual with the generalized input torque and with
    the generalized velocity (lags ±0.1 s), against its 99 % band 2.58/√(n/L)."""
    if ch.kind == "kinematic":
        inputs = {"motor_torque": ch.rows(ch.context.st.motor_torque[:, ch.index]),
                  "velocity": ch.velocity}
    elif ch.kind == "rolling":
        inputs = {"motor_torque": ch.rows(ch.context.st.motor_torque.sum(axis=1)), "velocity": ch.velocity}
    else:
        inputs = {"generalized_input": ch.y, "velocity": ch.velocity}
    r = ch.residual[ch.fitted]
    if not len(r):
        return {"band_99": float("nan")}
    r = r - r.mean()
    n_eff = max(len(r) / max(lag, 1), 1.0)
    band = 2.58 / math.sqrt(n_eff)
    max_shift = int(round(0.1 / ch.context.st.cycle_time))
    out = {"band_99": band}
    for name, x in inputs.items():
        x = x[ch.fitted] - np.mean(x[ch.fitted])
        denom = np.linalg.norm(r) * np.linalg.norm(x)
        if denom == 0:
            out[name] = {"max_abs": 0.0, "at_lag_s": 0.0, "significant": False}
            continue
        best, at = 0.0, 0
        for s in range(-max_shift, max_shift + 1, 5):
            c = float(np.sum(r[max(s, 0):len(r) + min(s, 0)] * x[max(-s, 0):len(x) - max(s, 0)]) / denom)
            if abs(c) > abs(best):
                best, at = c, s
        out[name] = {"max_abs": abs(best), "at_lag_s": at * ch.context.st.cycle_time,
                     "significant": abs(best) > band}
    return out


def breakdown(channels: list[ChannelData], lag: int) -> dict:
    """The 'where' section of gap.json: per channel (grouped by step and mode) the residual's size
    relative to the measured signal, regimes, bands, windows and the two tests."""
    out = {}
    for ch in channels:
        fitted = ch.fitted
        rms_y = _rms(ch.y[fitted]) if ch.kind == "torque" else float("nan")
        out[ch.name] = {
            "step": ch.step, "mode": ch.context.k, "kind": ch.kind, "unit": ch.unit,
            "rms_residual": _rms(ch.residual[fitted]),
            "nrmse": _rms(ch.residual[fitted]) / rms_y if ch.kind == "torque" and rms_y > 0 else None,
            "rows": int(fitted.sum()),
            "traction_limited": float(ch.rows(ch.context.traction_limited).mean()),
            "regimes": regimes(ch), "bands": bands(ch), "windows": windows(ch),
            "whiteness": whiteness(ch, lag), "input_correlation": input_correlation(ch, lag),
        }
    return out


def structured(where: dict) -> list[str]:
    """Channels whose residual fails the whiteness test or correlates with an input beyond its band."""
    out = []
    for name, w in where.items():
        p = w["whiteness"]["p_value"]
        corr = [k for k, v in w["input_correlation"].items() if isinstance(v, dict) and v["significant"]]
        if (p == p and p < 1e-3) or corr:
            out.append(name)
    return out
