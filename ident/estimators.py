"""The estimators of p₁ behind ``qomni identify --estimator``, all on the same channel-weighted rows of (24).

Each takes the stacked rows Θ̂₁ (N, n), y = τ̂ − Θ̂₂p₂ (N,), the channel label and original row number of
every row, the channel weights 1/σ_c of the first LS pass and the Newey–West lag, and returns a
:class:`Solution` whose covariance is the Newey–West sandwich of its own weighted rows.

- ``wls``: two-step channel-weighted least squares (:func:`.least_squares.channel_weighted_lstsq`).
- ``irls``: M-estimation by iteratively reweighted least squares (Huber 1981, Holland & Welsch 1977).
  Each row's residual r is scaled by its channel's robust σ, s_c = 1.4826·MAD (the channel weights are
  re-estimated robustly: outliers inflate the RMS the WLS weights come from). Huber weights
  (k = 1.345) first, a convex problem with one minimum, to convergence; from there Tukey's bisquare
  ω = (1 − (u/c)²)² for |u| < c, else 0 (c = 4.685), which rejects gross outliers outright where Huber
  only damps them. Both constants give 95 % efficiency under Gaussian noise. Starting the
  redescending (non-convex) bisquare from the Huber solution keeps it off the minima near WLS.
- ``iv``: instrumental variables, p = (ZᵀW²Θ̂₁)⁻¹ ZᵀW²y, with instruments Z the rows of (22) evaluated on a
  trajectory simulated by the model from the measured torque (supplied by the caller, see
  :mod:`.instruments`): noise in the measured positions enters Θ̂₁ but not Z (Janot et al. 2014).
- ``consistent``: physically consistent least squares: minimise the WLS cost subject to every
  inertia, mass, viscous and Coulomb coefficient ≥ 0 (``scipy.optimize.lsq_linear``, a convex bounded
  least-squares problem). When the WLS solution is admissible it is the minimiser, and returned as is.
  Parameters on an active bound are reported with σ = 0 (fixed by the constraint); the others get the
  Newey–West σ of the problem with those fixed.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.optimize import lsq_linear

from .least_squares import RANK_TOL, Fit, check_rank, lstsq, newey_west_cov

ESTIMATORS = ("wls", "irls", "iv", "consistent")

#: Tukey bisquare tuning constant (95 % asymptotic efficiency at the normal distribution).
TUKEY_C = 4.685
#: Huber tuning constant (95 % asymptotic efficiency at the normal distribution).
HUBER_K = 1.345
#: MAD → σ of a normal distribution.
MAD_TO_SIGMA = 1.4826


@dataclass
class Solution:
    """An estimate: p (n,), its covariance (n, n), residuals y − Θ̂₁p (N,), the final row weights (N,)
    (channel weight × robust weight) and estimator details for identification.json."""

    p: np.ndarray
    cov: np.ndarray
    residual: np.ndarray
    weights: np.ndarray
    info: dict = field(default_factory=dict)


def _nw(x, e, w, ch, rows, lag):
    xw, ew = x * w[:, None], e * w
    if lag > 0:
        return newey_west_cov(xw, ew, ch, rows, lag)
    dof = max(len(ew) - x.shape[1], 1)
    return float(ew @ ew) / dof * np.linalg.inv(xw.T @ xw)


def wls(theta, y, ch, rows, w, lag, names, rank_tol=RANK_TOL) -> Solution:
    """Channel-weighted LS with row weights ``w`` (N,)."""
    fit = lstsq(theta * w[:, None], y * w, names, rank_tol)
    r = y - theta @ fit.p
    return Solution(fit.p, _nw(theta, r, w, ch, rows, lag), r, w, {})


def _robust_scales(r: np.ndarray, ch: np.ndarray) -> np.ndarray:
    """Per-row robust σ of its channel, 1.4826·MAD of the channel's residuals (N,)."""
    out = np.empty_like(r)
    for c in dict.fromkeys(ch.tolist()):
        m = ch == c
        mad = MAD_TO_SIGMA * float(np.median(np.abs(r[m] - np.median(r[m]))))
        out[m] = mad if mad > 0 else np.finfo(float).tiny
    return out


def _psi_weights(u: np.ndarray, kind: str) -> np.ndarray:
    if kind == "huber":
        a = np.abs(u)
        return np.where(a <= HUBER_K, 1.0, HUBER_K / np.maximum(a, HUBER_K))
    return np.where(np.abs(u) < TUKEY_C, (1.0 - (u / TUKEY_C) ** 2) ** 2, 0.0)


def irls(theta, y, ch, rows, w, lag, names, rank_tol=RANK_TOL, *, max_iter: int = 100,
         tol: float = 1e-8) -> Solution:
    """Huber then Tukey-bisquare IRLS with per-channel robust scales (module docstring).

    Raises IdentifiabilityError when the rows keeping weight no longer determine p."""
    p = wls(theta, y, ch, rows, w, lag, names, rank_tol).p
    iterations, converged = 0, {}
    for kind in ("huber", "tukey"):
        converged[kind] = False
        for _ in range(max_iter):
            iterations += 1
            r = y - theta @ p
            scale = _robust_scales(r, ch)
            wr = np.sqrt(_psi_weights(r / scale, kind)) / scale
            fit = lstsq(theta * wr[:, None], y * wr, names, rank_tol)
            step = np.max(np.abs(fit.p - p) / np.maximum(np.abs(fit.p), 1e-12))
            p = fit.p
            if step < tol:
                converged[kind] = True
                break
    r = y - theta @ p
    cov = _nw(theta, r, wr, ch, rows, lag)
    return Solution(p, cov, r, wr,
                    {"weights": f"Huber (k = {HUBER_K}) to convergence, then Tukey bisquare (c = {TUKEY_C})",
                     "scale": "1.4826 MAD of each channel's residuals", "iterations": iterations,
                     "converged": all(converged.values()), "rows_rejected": int(np.sum(wr == 0.0))})


def iv(theta, y, ch, rows, w, lag, names, instruments: np.ndarray, rank_tol=RANK_TOL) -> Solution:
    """Instrumental-variables estimate with instruments Z (N, n) rows aligned with ``theta``.

    Covariance: the IV sandwich (ZᵀX)⁻¹ S (XᵀZ)⁻¹ with S the Newey–West sum of z_t e_t.
    Raises IdentifiabilityError when Z or ZᵀΘ̂₁ is rank deficient."""
    z = np.asarray(instruments, dtype=float)
    if z.shape != theta.shape:
        raise ValueError(f"instruments must have the shape of the regressor {theta.shape}, got {z.shape}")
    check_rank(z, names, rank_tol)
    zw, xw = z * w[:, None], theta * w[:, None]
    scale = np.linalg.norm(xw, axis=0)
    a = zw.T @ xw / scale
    p = np.linalg.solve(a, zw.T @ (y * w)) / scale
    r = y - theta @ p
    # Sandwich: (ZᵀX)⁻¹ Ŝ (XᵀZ)⁻¹, Ŝ from g_t = z_t e_t; newey_west_cov(z, e) gives (ZᵀZ)⁻¹ Ŝ (ZᵀZ)⁻¹.
    ztz = zw.T @ zw
    inner = ztz @ _nw(z, r, w, ch, rows, lag) @ ztz
    azx_inv = np.linalg.inv(zw.T @ xw)
    cov = azx_inv @ inner @ azx_inv.T
    return Solution(p, cov, r, w, {"instruments": "rows of (22) on the model-simulated trajectory"})


def consistent(theta, y, ch, rows, w, lag, names, lower: Sequence[float], rank_tol=RANK_TOL) -> Solution:
    """Bounded channel-weighted LS, p ≥ ``lower`` (n,) (module docstring)."""
    sol = wls(theta, y, ch, rows, w, lag, names, rank_tol)
    lower = np.asarray(lower, dtype=float)
    if np.all(sol.p >= lower):
        return Solution(sol.p, sol.cov, sol.residual, w, {"active_bounds": [], "equals": "wls"})
    xw = theta * w[:, None]
    scale = np.linalg.norm(xw, axis=0)
    res = lsq_linear(xw / scale, y * w, bounds=(lower * scale, np.inf), method="bvls", tol=1e-12)
    if res.status < 1:
        raise ValueError(f"bounded least squares did not converge: {res.message}")
    p = res.x / scale
    active = np.isclose(p, lower, rtol=0, atol=1e-12 * np.maximum(1.0, np.abs(lower))) | (p <= lower)
    p = np.maximum(p, lower)
    r = y - theta @ p
    cov = np.zeros((len(p), len(p)))
    free = ~active
    if free.any():
        cov[np.ix_(free, free)] = _nw(theta[:, free], r, w, ch, rows, lag)
    return Solution(p, cov, r, w, {"active_bounds": [names[i] for i in np.nonzero(active)[0]],
                                   "solver": "scipy.optimize.lsq_linear (bvls)"})


def solve(estimator: str, theta, y, ch, rows, w, lag, names, *, instruments=None, lower=None,
          rank_tol=RANK_TOL) -> Solution:
    """Dispatch to the estimator named ``estimator`` (one of :data:`ESTIMATORS`).

    Raises: ValueError for an unknown name or a missing ``instruments``/``lower``."""
    if estimator == "wls":
        return wls(theta, y, ch, rows, w, lag, names, rank_tol)
    if estimator == "irls":
        return irls(theta, y, ch, rows, w, lag, names, rank_tol)
    if estimator == "iv":
        if instruments is None:
            raise ValueError("the iv estimator needs instruments (rows on a simulated trajectory)")
        return iv(theta, y, ch, rows, w, lag, names, instruments, rank_tol)
    if estimator == "consistent":
        if lower is None:
            raise ValueError("the consistent estimator needs lower bounds")
        return consistent(theta, y, ch, rows, w, lag, names, lower, rank_tol)
    raise ValueError(f"unknown estimator {estimator!r}; choose one of {', '.join(ESTIMATORS)}")


__all__ = ["ESTIMATORS", "Solution", "solve", "wls", "irls", "iv", "consistent", "Fit"]
