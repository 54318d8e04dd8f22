"""Least-squares estimation of the dynamic parameters (paper sections 6.3 and 7).

Input are stacked rows of (22): regressor rows Θ̂ (n_rows, 11) in the parameter order (18)
``p = (C_l, d_vl, d_cl, C_r, d_vr, d_cr, m_ch, C_ch, d_vw, d_cw, B_w)``, right-hand sides τ̂ (n_rows,),
the generalized velocity of each row and a channel label per row (e.g. ``"steer_left/alpha_l"``).
The rows themselves (H_kᵀΘ, H_kᵀBu of (19)) come from elsewhere; this module is generic over them.

Procedure of :func:`estimate`
-----------------------------
1. Stiction (section 7): rows whose |generalized velocity| is below a threshold are removed
   (the paper sets them to zero, which gives the same least-squares solution).
2. Split (23)/(24): p = (p₁, p₂) with p₂ = B_w known (data sheet or :func:`estimate_single_axis`);
   y = τ̂ − Θ̂₂ p₂.
3. Column weighting (25): W = diag(‖θ̂₁,ᵢ‖₂), Θ̂₁,w = Θ̂₁ W⁻¹ (unit-norm columns), p₁,w = W p₁,
   p₁ = W⁻¹ Θ̂₁,w⁺ y. (The paper's typeset (25) writes the weight on the other side; this is the
   scaling that equilibrates the columns, as in Lawson & Hanson.) ``condition_number`` is
   cond(Θ̂₁,wᵀ Θ̂₁,w) as reported in section 7 (11.56 for the prototype).
4. Standard deviations: σ² = ‖r‖²/(N − n), Cov(p₁) = σ² (Θ̂₁ᵀΘ̂₁)⁻¹, σ_p = sqrt(diag Cov).

Departure from the paper: channel weighting
------------------------------------------
The stack mixes channels with different units and noise levels (steering rows in N m, straight rows
in N, rotation rows in N m). Ordinary LS assumes one common noise variance, so its σ_p are wrong and
the large-magnitude channels dominate. With ``channel_weighting=True`` (default) a second pass
weights each row by 1/σ_c, σ_c = RMS of the first-pass residuals of its channel (two-step feasible
generalized LS), and reports values and σ_p from that weighted fit: Cov = s² (Θ̃ᵀΘ̃)⁻¹ with
Θ̃ = diag(1/σ_c) Θ̂₁ and s² the weighted residual variance. The first-pass (paper) values and stds
are kept in ``values_ls``/``std_ls``. For noise-free consistent data both passes give the same p₁.
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

import numpy as np

from qomni.conventions import P1_NAMES, P2_NAMES, PARAMETER_NAMES

from .bootstrap import N_REPLICATES, WINDOW_CORRELATION_LENGTHS, bootstrap_std
from .estimators import solve
from .parameter_report import parameter_report
from .least_squares import RANK_TOL, Fit, IdentifiabilityError, channel_weights, lstsq, per_channel, rms
from .regressor import DEFAULT_VELOCITY_THRESHOLD, RegressorBlock, row_mask, stack_blocks
from .result import IdentificationResult


#: Lower bounds of p₁ for the ``consistent`` estimator: inertias, masses, viscous and Coulomb coefficients
#: are all non-negative (a negative one would make the model's energy or dissipation negative).
PHYSICAL_LOWER_BOUNDS = np.zeros(len(P1_NAMES))


def estimate(
    blocks: Iterable[RegressorBlock],
    B_w: float,
    *,
    velocity_threshold: float | Mapping[str, float] = DEFAULT_VELOCITY_THRESHOLD,
    channel_weighting: bool = True,
    rank_tol: float = RANK_TOL,
    correlation_lag: int = 0,
    estimator: str = "wls",
    instruments: Iterable[RegressorBlock] | None = None,
) -> IdentificationResult:
    """Estimate p₁ from stacked rows of (22) with B_w fixed, (23)–(25).

    Parameters
    ----------
    blocks : iterable of RegressorBlock
        Rows Θ̂ (n_rows, 11), τ̂, generalized velocity and channel labels.
    B_w : float
        Known p₂ = B_w (kg m²), (24).
    velocity_threshold : float or mapping
        Rows with |generalized velocity| below it are removed (section 7). A mapping is looked up by
        channel label, coordinate, step, then ``"*"`` (see :func:`row_mask`). Units rad/s or m/s.
    channel_weighting : bool
        Second pass weighting each channel by 1/σ_c (see module docstring). False = paper's LS.
    rank_tol : float
        Relative singular-value tolerance of the column-normalised Θ̂₁,w for rank deficiency.
    correlation_lag : int
        Rows of low-pass filtered signals are not independent: residuals of samples at T_s filtered at
        ω_g stay correlated for ≈ 4/(ω_g T_s) rows. With a lag L > 0 the reported covariance is the
        Newey–West (Bartlett kernel, lags ≤ L) sandwich estimate over contiguous rows of each channel
        instead of σ²(ΘᵀΘ)⁻¹, which would understate σ_p by about √(correlation length).
    estimator : str
        ``"wls"`` (default), ``"irls"``, ``"iv"`` or ``"consistent"`` (:mod:`.estimators`); the first LS
        pass (``values_ls``) and the channel weights are the same for all.
    instruments : iterable of RegressorBlock, optional
        For ``"iv"``: rows aligned one to one with ``blocks`` (same channels, same lengths), evaluated on
        a model-simulated trajectory (:mod:`.instruments`).

    Returns
    -------
    IdentificationResult

    Raises
    ------
    ValueError
        NaN/inf in the data (from :class:`RegressorBlock`), no blocks, or no rows left after the
        stiction threshold.
    IdentifiabilityError (a ValueError)
        If Θ̂₁ of the kept rows is rank deficient; the message and ``.parameters`` name the
        unidentifiable parameters.
    """
    if not (math.isfinite(B_w)):
        raise ValueError(f"B_w must be finite, got {B_w}")
    theta, tau, vel, ch = stack_blocks(blocks)
    labels = list(dict.fromkeys(ch.tolist()))
    rows_total = {c: int(np.sum(ch == c)) for c in labels}
    keep = row_mask(vel, ch, velocity_threshold)
    if not np.any(keep):
        raise ValueError(
            f"no rows left after the stiction threshold {velocity_threshold!r} "
            f"(max |velocity| = {np.max(np.abs(vel)):.3g})"
        )
    row_index = np.nonzero(keep)[0]
    theta, tau, ch = theta[keep], tau[keep], ch[keep]
    rows_used = {c: int(np.sum(ch == c)) for c in labels}

    i2 = [PARAMETER_NAMES.index(n) for n in P2_NAMES]
    i1 = [PARAMETER_NAMES.index(n) for n in P1_NAMES]
    theta1 = theta[:, i1]
    y = tau - theta[:, i2] @ np.array([B_w])  # (24)

    fit = lstsq(theta1, y, P1_NAMES, rank_tol)
    values_ls = dict(zip(P1_NAMES, fit.p.tolist()))
    std_ls = dict(zip(P1_NAMES, np.sqrt(np.diag(fit.cov)).tolist()))
    used = [c for c in labels if rows_used[c] > 0]
    if channel_weighting:
        wrow, sigma = channel_weights(fit.residual, ch)
        method = "channel_weighted_ls"
    else:
        wrow, sigma = np.ones_like(y), per_channel(fit.residual, ch, used, rms)
        method = "ls"
    z = None
    if instruments is not None:
        z_all = stack_blocks(instruments)[0]
        if z_all.shape[0] != keep.shape[0]:
            raise ValueError(f"instruments have {z_all.shape[0]} rows, the regressor {keep.shape[0]}")
        z = z_all[keep][:, i1]
    sol = solve(estimator, theta1, y, ch, row_index, wrow, correlation_lag, P1_NAMES, instruments=z,
                lower=PHYSICAL_LOWER_BOUNDS, rank_tol=rank_tol)
    cond_w = lstsq(theta1 * wrow[:, None], y * wrow, P1_NAMES, rank_tol).cond if channel_weighting else None
    final = Fit(p=sol.p, cov=sol.cov, cond=fit.cond, residual=sol.residual)
    wf = sol.weights
    report = parameter_report(theta1 * wf[:, None], ch, sol.p, sol.cov, P1_NAMES, rank_tol)
    window = WINDOW_CORRELATION_LENGTHS * max(correlation_lag, 1)
    std_boot = bootstrap_std(theta1 * wf[:, None], y * wf, ch, window,
                             instruments=None if z is None else z * wf[:, None])
    if estimator != "wls":
        method = f"{method}+{estimator}"

    return IdentificationResult(
        values=dict(zip(P1_NAMES, final.p.tolist())),
        std=dict(zip(P1_NAMES, np.sqrt(np.diag(final.cov)).tolist())),
        B_w=float(B_w),
        condition_number=fit.cond,
        condition_number_channel_weighted=cond_w,
        rows_used=rows_used,
        rows_total=rows_total,
        residual_rms={c: (rms(final.residual[ch == c]) if rows_used[c] else float("nan")) for c in labels},
        channel_sigma=sigma,
        method=method,
        velocity_threshold=dict(velocity_threshold) if isinstance(velocity_threshold, Mapping) else float(velocity_threshold),
        covariance=final.cov,
        values_ls=values_ls,
        std_ls=std_ls,
        estimator=estimator,
        estimator_info=sol.info,
        identifiability=report,
        std_bootstrap=dict(zip(P1_NAMES, std_boot.tolist())),
        bootstrap={"method": "moving-block bootstrap over campaign windows, stratified by channel",
                   "window_rows": window, "replicates": N_REPLICATES, "seed": 0},
    )


__all__ = ["IdentifiabilityError", "IdentificationResult", "RegressorBlock", "estimate"]
