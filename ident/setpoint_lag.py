"""How far the drives' torque actual (0x6077) lags the torque set-point (0x6071) the master sent them.

Convention (docs/conventions.md, "Torque timing"): the torque actual a drive sends with SYNC j is the
set-point latched at SYNC j after its current loop, so by definition it follows the set-point with no
lag. A drive that samples its torque actual at the SYNC instant, before it applies the new set-point,
reports the set-point of the cycle before: its 0x6077 lags 0x6071 by one cycle. The master knows what it
sent, so this lag is measured on the bus directly, without a model: it is the report lag of the torque
actual, and nothing else (an actuator that applies the torque late still reports the set-point at once;
the motion then lags the reported torque, which only the dynamics show).

Estimate. For each drive i and a whole number m of cycles, the least-squares fit of

    r_i(t_j) ≈ g_i · [(1 − a) · c_i(t_{j−m}) + a · c_i(t_{j−m−1})],     0 ≤ a ≤ 1,

over the rows where no set-point is within 1 % of the torque limit (the drive clips what it reports
there); the lag is (m + a)·T_s of the m (0 … :data:`MAX_CYCLES` − 1) with the least residual over the four
drives together, a fitted jointly as g_i·a (linear). Its σ is the delta method's on each drive's
Newey–West covariance of (g_i, g_i·a) (:func:`qomni.ident.least_squares.newey_west_cov`, bandwidth
L = ⌊4 (n/100)^{2/9}⌋ rows, Newey & West 1994), the drives pooled by inverse variance: the report's
noise need not be white. All torques motor side (N m).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .least_squares import newey_west_cov
from .recording import Signals

#: The search covers lags of 0 to MAX_CYCLES cycles.
MAX_CYCLES = 7
#: Rows with a set-point within this share of the torque limit are left out: the report is clipped there.
CLIP_SHARE = 0.99
#: Fewest usable rows per drive for an estimate.
MIN_ROWS = 200


def hac_bandwidth(rows: int) -> int:
    """Newey–West's rule-of-thumb bandwidth ⌊4 (n/100)^{2/9}⌋ for n rows (Newey & West 1994), at least 1."""
    return max(1, int(4.0 * (rows / 100.0) ** (2.0 / 9.0)))


@dataclass(frozen=True)
class SetpointLag:
    """Lag of the torque actual behind the torque set-point: ``value`` and ``std`` (s), ``cycles``
    (value / T_s), ``rows`` used per drive (the fewest), ``rms`` residual (N m, motor side)."""

    value: float
    std: float
    cycles: float
    rows: int
    rms: float

    def z(self) -> float:
        """value / std (inf for a noise-free report)."""
        return self.value / self.std if self.std > 0 else math.inf


def _fit(r: np.ndarray, c: np.ndarray, m: int, keep: np.ndarray):
    """Per drive, the least-squares fit of r(t) ≈ g c(t − m) + h c(t − m − 1) (h = g·a, shifts in rows)
    over the kept rows: (rows, X (n, 2), (g, h), residuals (n,))."""
    n = r.shape[0]
    rows = np.arange(m + 1, n)
    rows = rows[keep[rows] & keep[rows - m] & keep[rows - m - 1]]
    out = []
    for i in range(r.shape[1]):
        X = np.column_stack([c[rows - m, i], c[rows - m - 1, i]])
        y = r[rows, i]
        coef, *_ = np.linalg.lstsq(X, y, rcond=None)
        out.append((rows, X, coef, y - X @ coef))
    return out


def setpoint_lag(signals: Signals, cycle_time: float, max_torque: float) -> SetpointLag | None:
    """The lag of 0x6077 behind 0x6071 (module docstring) over every row of ``signals``.

    Args:
        signals: the run's recording, (N,) rows at the SYNCs; its ``motor_torque`` and
            ``motor_torque_cmd`` (N, 4), motor side.
        cycle_time: T_s (s).
        max_torque: the drives' torque limit (N m, motor side).
    Returns:
        The estimate, or None where fewer than :data:`MIN_ROWS` rows per drive carry an unclipped,
        varying set-point (no campaign, or a recording without set-points).
    """
    r = np.asarray(signals.motor_torque, dtype=float)
    c = np.asarray(signals.motor_torque_cmd, dtype=float)
    if r.ndim != 2 or r.shape != c.shape or r.shape[0] < MIN_ROWS + MAX_CYCLES + 1:
        return None
    keep = np.all(np.isfinite(r) & np.isfinite(c) & (np.abs(c) < CLIP_SHARE * max_torque), axis=1)
    best = None
    for m in range(MAX_CYCLES):
        fits = _fit(r, c, m, keep)
        if min(f[0].size for f in fits) < MIN_ROWS or any(np.ptp(f[1][:, 0]) == 0 for f in fits):
            return None
        sse = sum(float(f[3] @ f[3]) for f in fits)
        if best is None or sse < best[0]:
            best = (sse, m, fits)
    _, m, fits = best
    # a = h / (g + h) per drive, σ by the delta method; the drives pooled by inverse variance
    values, weights = [], []
    for rows, X, (g, h), e in fits:
        cov = newey_west_cov(X, e, np.zeros(rows.size), rows, hac_bandwidth(rows.size))
        total = g + h
        if total == 0:
            continue
        a = h / total
        grad = np.array([-h, g]) / total ** 2
        values.append(a)
        weights.append(1.0 / max(float(grad @ cov @ grad), 1e-300))
    if not values:
        return None
    w = np.array(weights)
    a = float(np.dot(w, values) / w.sum())
    var = 1.0 / float(w.sum())
    e = np.concatenate([f[3] for f in fits])
    cycles = m + min(max(a, 0.0), 1.0)
    return SetpointLag(cycles * cycle_time, math.sqrt(var) * cycle_time, cycles,
                       min(f[0].size for f in fits), float(np.sqrt(np.mean(e ** 2))))


__all__ = ["MAX_CYCLES", "SetpointLag", "setpoint_lag"]
