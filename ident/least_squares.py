"""The least-squares core of the estimation: rank check, column-equilibrated solve with its covariance,
Newey–West covariance of correlated rows, per-channel statistics (paper (25); Newey & West 1987)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: Relative singular-value tolerance of the column-normalised regressor below which it is rank deficient.
RANK_TOL = 1e-7



class IdentifiabilityError(ValueError):
    """Regressor stack is rank deficient; ``parameters`` names the unidentifiable parameters."""

    def __init__(self, message: str, parameters: Sequence[str]):
        super().__init__(message)
        self.parameters = tuple(parameters)


@dataclass
class Fit:
    p: np.ndarray          # (n,)
    cov: np.ndarray        # (n, n), σ² (ΘᵀΘ)⁻¹
    cond: float            # cond(Θ_wᵀΘ_w) of the column-normalised matrix
    residual: np.ndarray   # (N,) y − Θ p (in the units of the given, possibly row-weighted, y)


def check_rank(theta: np.ndarray, names: Sequence[str], rank_tol: float) -> None:
    """Raise IdentifiabilityError naming the unidentifiable parameters of ``theta`` (N, n)."""
    n_rows = theta.shape[0]
    norms = np.linalg.norm(theta, axis=0)
    zero = norms <= 1e-12 * max(float(norms.max(initial=0.0)), np.finfo(float).tiny)
    msgs: list[str] = []
    bad: set[str] = set()
    if np.any(zero):
        zs = [names[i] for i in np.nonzero(zero)[0]]
        bad.update(zs)
        msgs.append(f"not excited by any row (zero column): {', '.join(zs)}")
    nz = np.nonzero(~zero)[0]
    if nz.size:
        tw = theta[:, nz] / norms[nz]
        # vt must span all of R^k; full matrices only when there are fewer rows than columns.
        _, s, vt = np.linalg.svd(tw, full_matrices=n_rows < nz.size)
        s_all = np.zeros(nz.size)
        s_all[: s.size] = s
        small = s_all < rank_tol * s_all[0]
        if np.any(small):
            null = vt[small]
            involved = np.nonzero(np.max(np.abs(null), axis=0) > 1e-3)[0]
            dep = [names[nz[i]] for i in involved]
            bad.update(dep)
            combos = [
                " ".join(f"{v[i]:+.3g}*{names[nz[i]]}" for i in np.nonzero(np.abs(v) > 1e-3)[0])
                for v in null[:3]
            ]
            msgs.append(
                f"linearly dependent, only combinations identifiable: {', '.join(dep)} "
                f"(null-space directions of the column-normalised regressor: {'; '.join(combos)})"
            )
    if bad:
        raise IdentifiabilityError(
            f"rank-deficient regressor stack ({n_rows} rows, {len(names)} parameters): " + "; ".join(msgs),
            parameters=[n for n in names if n in bad],
        )


def lstsq(theta: np.ndarray, y: np.ndarray, names: Sequence[str], rank_tol: float = RANK_TOL) -> Fit:
    """Column-norm weighted least squares (25) with covariance; raises on rank deficiency."""
    n_rows, n = theta.shape
    check_rank(theta, names, rank_tol)
    w = np.linalg.norm(theta, axis=0)  # W = diag(‖θ_i‖)
    tw = theta / w
    u, s, vt = np.linalg.svd(tw, full_matrices=False)
    if n_rows <= n:
        raise IdentifiabilityError(
            f"only {n_rows} rows for {n} parameters; need more rows than parameters", names
        )
    p_w = vt.T @ ((u.T @ y) / s)
    p = p_w / w
    r = y - theta @ p
    sigma2 = float(r @ r) / (n_rows - n)
    cov_w = (vt.T / s**2) @ vt
    cov = sigma2 * cov_w / np.outer(w, w)
    return Fit(p=p, cov=cov, cond=float((s[0] / s[-1]) ** 2), residual=r)


def channel_weights(residual: np.ndarray, channel: np.ndarray) -> tuple[np.ndarray, dict[str, float]]:
    """Row weights 1/σ_c, σ_c = RMS of ``residual`` over the rows of channel c (two-step feasible GLS).

    σ_c below 1e-6 of the largest is floored there, so noise-free channels keep finite weights; all
    residuals zero gives unit weights. Returns (weights (N,), {channel: σ_c})."""
    labels = list(dict.fromkeys(channel.tolist()))
    sigma = per_channel(residual, channel, labels, rms)
    s_max = max(sigma.values())
    w = np.ones_like(residual, dtype=float)
    if s_max > 0:
        for c in labels:
            w[channel == c] = 1.0 / max(sigma[c], 1e-6 * s_max)
    return w, sigma


def channel_weighted_lstsq(theta: np.ndarray, y: np.ndarray, channel: np.ndarray, names: Sequence[str],
                           rank_tol: float = RANK_TOL) -> tuple[Fit, np.ndarray]:
    """Two-step channel-weighted least squares: :func:`lstsq`, rows weighted by 1/σ_c of its residuals
    (:func:`channel_weights`), :func:`lstsq` again. Returns the weighted fit (its ``residual`` in the
    units of ``y``, unweighted; ``cov`` from the weighted rows) and the row weights (N,)."""
    first = lstsq(theta, y, names, rank_tol)
    w, _ = channel_weights(first.residual, channel)
    fit = lstsq(theta * w[:, None], y * w, names, rank_tol)
    return Fit(p=fit.p, cov=fit.cov, cond=fit.cond, residual=y - theta @ fit.p), w


def per_channel(values: np.ndarray, channel: np.ndarray, labels: Sequence[str], fn) -> dict[str, float]:
    return {c: float(fn(values[channel == c])) for c in labels}


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


def newey_west_cov(x: np.ndarray, e: np.ndarray, channel: np.ndarray, row_index: np.ndarray,
                    lag: int) -> np.ndarray:
    """Sandwich covariance (XᵀX)⁻¹ S (XᵀX)⁻¹ with S = Σ_{|l|≤L} (1 − |l|/(L+1)) Σ_t g_t g_{t−l}ᵀ,
    g_t = x_t e_t, summed only over pairs of the same channel whose original rows are l apart.

    Args:
        x: (N, n) rows as fitted (weights applied); e: (N,) their residuals; channel: (N,) labels;
        row_index: (N,) original row numbers (rows dropped by the threshold leave gaps); lag: L.
    """
    n = x.shape[1]
    g = x * e[:, None]
    s = g.T @ g
    for c in dict.fromkeys(channel.tolist()):
        sel = channel == c
        idx = row_index[sel]
        full = np.zeros((idx[-1] - idx[0] + 1, n))
        full[idx - idx[0]] = g[sel]
        for l in range(1, min(lag, len(full) - 1) + 1):
            gamma = full[l:].T @ full[:-l]
            s += (1.0 - l / (lag + 1.0)) * (gamma + gamma.T)
    xtx_inv = np.linalg.inv(x.T @ x)
    return xtx_inv @ s @ xtx_inv

