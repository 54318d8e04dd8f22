"""Per-parameter identifiability report of an estimate: which campaign step determines each parameter,
its relative σ and its correlations with the others (identification.json ``identifiability``).

Which step determines a parameter: each step's rows are left out in turn and the fit's information
matrix recomputed (same row weights). A step is *essential* for a parameter when without it the
parameter is no longer identifiable (:func:`.least_squares.check_rank` names it) or no longer
significant: its σ without the step exceeds |value|/3 (a 3σ test against zero fails, so the data
without the step do not determine it). Otherwise the step's weight is the growth of σ_p without it,
σ_p(without step)/σ_p − 1 (0: the step adds nothing). The determining steps are the essential ones,
else the one with the largest growth. Correlations are
ρ_ij = Cov_ij/(σ_i σ_j) of the reported covariance.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from .least_squares import IdentifiabilityError, check_rank

#: Without an essential step a parameter's |value|/σ falls below this (a two-sided 3σ test against 0).
SIGNIFICANCE = 3.0
#: |ρ| above which two parameters are listed as strongly correlated.
STRONG_CORRELATION = 0.9


def _sigma_shape(x: np.ndarray) -> np.ndarray:
    """sqrt diag (XᵀX)⁻¹ of column-equilibrated X, rescaled (the shape of σ_p, common factor dropped)."""
    norms = np.linalg.norm(x, axis=0)
    return np.sqrt(np.diag(np.linalg.pinv((x / norms).T @ (x / norms)))) / norms


def parameter_report(x: np.ndarray, channel: np.ndarray, values: np.ndarray, cov: np.ndarray,
                     names: Sequence[str], rank_tol: float) -> dict:
    """The report as a JSON-ready dict ``{name: {...}, "correlation": {...}}``.

    Args:
        x: (N, n) weighted rows of the fit; channel: (N,) labels ``"<step>/<coordinate>"``;
        values: (n,) estimate; cov: (n, n) its covariance; names: the n parameter names;
        rank_tol: the fit's rank tolerance.
    """
    sigma = np.sqrt(np.diag(cov))
    steps = list(dict.fromkeys(str(c).partition("/")[0] for c in channel.tolist()))
    step_of = np.array([str(c).partition("/")[0] for c in channel.tolist()])
    full = _sigma_shape(x)
    growth: dict[str, np.ndarray] = {}
    essential: dict[str, set[str]] = {}
    for s in steps:
        rest = x[step_of != s]
        try:
            check_rank(rest, names, rank_tol)
        except IdentifiabilityError as exc:
            essential[s] = set(exc.parameters)
            growth[s] = np.full(len(names), np.inf)
            nz = [i for i, n in enumerate(names) if n not in essential[s]]
            if nz:
                growth[s][nz] = _sigma_shape(rest[:, nz]) / full[nz] - 1.0
            continue
        essential[s] = set()
        growth[s] = _sigma_shape(rest) / full - 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = cov / np.outer(sigma, sigma)
    report: dict = {}
    for i, n in enumerate(names):
        ess = [s for s in steps if n in essential[s]
               or sigma[i] * (1.0 + growth[s][i]) * SIGNIFICANCE > abs(values[i])]
        by = ess or [max(steps, key=lambda s: growth[s][i])]
        others = [(names[j], float(rho[i, j])) for j in range(len(names)) if j != i and np.isfinite(rho[i, j])]
        others.sort(key=lambda t: -abs(t[1]))
        report[n] = {
            "determined_by": by,
            "essential_steps": ess,
            "sigma_growth_without_step": {s: (None if not np.isfinite(growth[s][i]) else float(growth[s][i]))
                                          for s in steps},
            "relative_std": float(sigma[i] / abs(values[i])) if values[i] != 0 else None,
            "strongest_correlation": ({"with": others[0][0], "rho": others[0][1]} if others else None),
            "strongly_correlated_with": [m for m, r in others if abs(r) >= STRONG_CORRELATION],
        }
    report["correlation"] = {"names": list(names),
                             "matrix": np.where(np.isfinite(rho), rho, 0.0).round(6).tolist()}
    report["definition"] = ("determined_by: the step(s) without which the parameter is unidentifiable or "
                            "|value| < 3 sigma, else "
                            "the step whose removal grows its sigma most; sigma_growth_without_step = "
                            "sigma(without step)/sigma - 1 (null: unidentifiable without it); rho from the "
                            "reported covariance")
    return report
