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
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from qomni.conventions import EPSILON, P1_NAMES, P2_NAMES, PARAMETER_NAMES, PARAMETER_UNITS, WHEELS

__all__ = [
    "PARAMETER_NAMES",
    "P1_NAMES",
    "P2_NAMES",
    "PARAMETER_UNITS",
    "DEFAULT_VELOCITY_THRESHOLD",
    "EPSILON",
    "IdentifiabilityError",
    "RegressorBlock",
    "IdentificationResult",
    "SingleAxisResult",
    "stack_blocks",
    "row_mask",
    "estimate",
    "estimate_single_axis",
]

#: Default stiction threshold on |generalized velocity| (rad/s or m/s).
DEFAULT_VELOCITY_THRESHOLD = 0.05
#: Relative singular-value tolerance of the column-normalised regressor below which it is rank deficient.
RANK_TOL = 1e-7


class IdentifiabilityError(ValueError):
    """Regressor stack is rank deficient; ``parameters`` names the unidentifiable parameters."""

    def __init__(self, message: str, parameters: Sequence[str]):
        super().__init__(message)
        self.parameters = tuple(parameters)


# --------------------------------------------------------------------------------------------
# Input rows
# --------------------------------------------------------------------------------------------


@dataclass
class RegressorBlock:
    """Rows of (22) from one experiment segment.

    Attributes
    ----------
    Theta : ndarray, shape (n_rows, 11)
        Regressor rows Θ̂ in the parameter order (18).
    tau : ndarray, shape (n_rows,)
        Right-hand side τ̂ (generalized torques/forces, N m or N).
    velocity : ndarray, shape (n_rows,)
        Generalized velocity of each row (rad/s or m/s), for the stiction threshold.
    channel : str or sequence of str (n_rows,)
        Channel label per row; a single string applies to all rows.

    Raises
    ------
    ValueError
        On inconsistent shapes or NaN/inf in any array.
    """

    Theta: np.ndarray
    tau: np.ndarray
    velocity: np.ndarray
    channel: str | Sequence[str] | np.ndarray

    def __post_init__(self) -> None:
        theta = np.atleast_2d(np.asarray(self.Theta, dtype=float))
        tau = np.asarray(self.tau, dtype=float).reshape(-1)
        vel = np.asarray(self.velocity, dtype=float).reshape(-1)
        n = theta.shape[0]
        if theta.ndim != 2 or theta.shape[1] != len(PARAMETER_NAMES):
            raise ValueError(f"Theta must have shape (n_rows, {len(PARAMETER_NAMES)}), got {theta.shape}")
        if tau.shape != (n,) or vel.shape != (n,):
            raise ValueError(f"tau and velocity must have shape ({n},), got {tau.shape}, {vel.shape}")
        if isinstance(self.channel, str):
            ch = np.full(n, self.channel, dtype=object)
        else:
            ch = np.asarray(list(self.channel), dtype=object)
            if ch.shape != (n,):
                raise ValueError(f"channel must be a str or have {n} labels, got {ch.shape}")
        for name, arr in (("Theta", theta), ("tau", tau), ("velocity", vel)):
            if not np.all(np.isfinite(arr)):
                bad = sorted(set(ch[~np.isfinite(arr).reshape(n, -1).all(axis=1)]))
                raise ValueError(f"{name} contains NaN or inf (channels {bad})")
        self.Theta, self.tau, self.velocity, self.channel = theta, tau, vel, ch

    @property
    def n_rows(self) -> int:
        return int(self.tau.size)


def stack_blocks(blocks: Iterable[RegressorBlock]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Stack blocks to (Θ̂ (N, 11), τ̂ (N,), velocity (N,), channel (N,) object array).

    Raises
    ------
    ValueError
        If there are no blocks.
    """
    blocks = [b if isinstance(b, RegressorBlock) else RegressorBlock(*b) for b in blocks]
    if not blocks:
        raise ValueError("no regressor blocks given")
    return (
        np.vstack([b.Theta for b in blocks]),
        np.concatenate([b.tau for b in blocks]),
        np.concatenate([b.velocity for b in blocks]),
        np.concatenate([b.channel for b in blocks]),
    )


def _threshold_for(channel: str, threshold: float | Mapping[str, float]) -> float:
    if not isinstance(threshold, Mapping):
        return float(threshold)
    step, _, coord = channel.partition("/")
    for key in (channel, coord, step, "*"):
        if key in threshold:
            return float(threshold[key])
    raise ValueError(
        f"no velocity threshold for channel {channel!r}: give its label, coordinate, step or '*'"
    )


def row_mask(velocity: ArrayLike, channel: ArrayLike, threshold: float | Mapping[str, float]) -> np.ndarray:
    """Rows kept by the stiction rule |velocity| ≥ threshold (section 7), boolean shape (N,).

    ``threshold`` is a float or a mapping looked up by full channel label, then coordinate
    (after '/'), then step (before '/'), then ``"*"``.
    """
    velocity = np.asarray(velocity, dtype=float)
    channel = np.asarray(channel, dtype=object)
    thr = np.empty_like(velocity)
    for ch in np.unique(channel):
        thr[channel == ch] = _threshold_for(str(ch), threshold)
    return np.abs(velocity) >= thr


# --------------------------------------------------------------------------------------------
# Least-squares core
# --------------------------------------------------------------------------------------------


@dataclass
class _Fit:
    p: np.ndarray          # (n,)
    cov: np.ndarray        # (n, n), σ² (ΘᵀΘ)⁻¹
    cond: float            # cond(Θ_wᵀΘ_w) of the column-normalised matrix
    residual: np.ndarray   # (N,) y − Θ p (in the units of the given, possibly row-weighted, y)


def _check_rank(theta: np.ndarray, names: Sequence[str], rank_tol: float) -> None:
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


def _lstsq(theta: np.ndarray, y: np.ndarray, names: Sequence[str], rank_tol: float = RANK_TOL) -> _Fit:
    """Column-norm weighted least squares (25) with covariance; raises on rank deficiency."""
    n_rows, n = theta.shape
    _check_rank(theta, names, rank_tol)
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
    return _Fit(p=p, cov=cov, cond=float((s[0] / s[-1]) ** 2), residual=r)


def _per_channel(values: np.ndarray, channel: np.ndarray, labels: Sequence[str], fn) -> dict[str, float]:
    return {c: float(fn(values[channel == c])) for c in labels}


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2))) if x.size else float("nan")


# --------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------


@dataclass
class IdentificationResult:
    """Result of :func:`estimate`.

    Attributes
    ----------
    values, std : dict[str, float]
        p₁ estimates and standard deviations (SI, see ``PARAMETER_UNITS``) of the reported fit
        (channel-weighted if ``method == "channel_weighted_ls"``).
    B_w : float
        Fixed p₂ (kg m²).
    condition_number : float
        cond(Θ̂₁,wᵀΘ̂₁,w) of the column-weighted stack (25), paper section 7.
    condition_number_channel_weighted : float or None
        Same for the channel-weighted stack (column-renormalised), None if not weighted.
    rows_used, rows_total : dict[str, int]
        Rows per channel after / before the stiction threshold.
    residual_rms : dict[str, float]
        RMS of y − Θ̂₁p₁ per channel over the rows used (channel units, N m or N).
    channel_sigma : dict[str, float]
        σ_c used as channel weights (RMS of first-pass residuals per channel).
    method : str
        ``"ls"`` (paper) or ``"channel_weighted_ls"``.
    velocity_threshold : float or dict
    covariance : ndarray, shape (10, 10)
        Covariance of p₁ (order ``P1_NAMES``) of the reported fit.
    values_ls, std_ls : dict[str, float]
        First-pass (paper's unweighted-row) estimates and stds.
    """

    values: dict[str, float]
    std: dict[str, float]
    B_w: float
    condition_number: float
    rows_used: dict[str, int]
    rows_total: dict[str, int]
    residual_rms: dict[str, float]
    channel_sigma: dict[str, float] = field(default_factory=dict)
    method: str = "channel_weighted_ls"
    condition_number_channel_weighted: float | None = None
    velocity_threshold: float | dict = DEFAULT_VELOCITY_THRESHOLD
    covariance: np.ndarray | None = None
    values_ls: dict[str, float] = field(default_factory=dict)
    std_ls: dict[str, float] = field(default_factory=dict)

    @property
    def p1(self) -> np.ndarray:
        """p₁, shape (10,), order ``P1_NAMES``."""
        return np.array([self.values[n] for n in P1_NAMES])

    @property
    def p(self) -> np.ndarray:
        """Full p of (18), shape (11,), with the fixed B_w last."""
        return np.append(self.p1, self.B_w)

    @property
    def std_vector(self) -> np.ndarray:
        """σ_p₁, shape (10,)."""
        return np.array([self.std[n] for n in P1_NAMES])

    def as_dict(self) -> dict[str, float]:
        """{name: value} for all 11 parameters."""
        return dict(zip(PARAMETER_NAMES, self.p.tolist()))

    def table(self) -> str:
        """Plain-text table like the paper's Table 2."""
        lines = [f"{'Name':<6} {'Value':>12} {'Std':>10}  Unit"]
        for n in P1_NAMES:
            lines.append(f"{n:<6} {self.values[n]:>12.4f} {self.std[n]:>10.4f}  {PARAMETER_UNITS[n]}")
        lines.append(f"{'B_w':<6} {self.B_w:>12.4f} {'(fixed)':>10}  {PARAMETER_UNITS['B_w']}")
        lines.append(f"cond(Theta_1w^T Theta_1w) = {self.condition_number:.2f}")
        return "\n".join(lines)

    def to_json_dict(self) -> dict:
        params: dict = {
            n: {"value": self.values[n], "std": self.std[n], "unit": PARAMETER_UNITS[n]} for n in P1_NAMES
        }
        params["B_w"] = {"value": self.B_w, "unit": PARAMETER_UNITS["B_w"], "fixed": True}
        d = {
            "parameters": params,
            "condition_number": self.condition_number,
            "condition_number_definition": "cond(Theta_1w^T Theta_1w), column-norm weighted (25)",
            "condition_number_channel_weighted": self.condition_number_channel_weighted,
            "method": self.method,
            "velocity_threshold": self.velocity_threshold,
            "rows_used": dict(self.rows_used),
            "rows_total": dict(self.rows_total),
            "residual_rms": dict(self.residual_rms),
            "channel_sigma": dict(self.channel_sigma),
            "ls_first_pass": {
                n: {"value": self.values_ls.get(n), "std": self.std_ls.get(n)} for n in self.values_ls
            },
        }
        if self.covariance is not None:
            d["covariance"] = {"names": list(P1_NAMES), "matrix": np.asarray(self.covariance).tolist()}
        return d

    @classmethod
    def from_json_dict(cls, d: Mapping) -> "IdentificationResult":
        """Inverse of :meth:`to_json_dict`. Raises KeyError if a parameter is missing."""
        params = d["parameters"]
        cov = d.get("covariance")
        if cov is not None:
            if list(cov["names"]) != list(P1_NAMES):
                raise ValueError(f"covariance names {cov['names']} differ from {P1_NAMES}")
            cov = np.asarray(cov["matrix"], dtype=float)
        first = d.get("ls_first_pass", {})
        return cls(
            values={n: float(params[n]["value"]) for n in P1_NAMES},
            std={n: float(params[n]["std"]) for n in P1_NAMES},
            B_w=float(params["B_w"]["value"]),
            condition_number=float(d["condition_number"]),
            rows_used={k: int(v) for k, v in d.get("rows_used", {}).items()},
            rows_total={k: int(v) for k, v in d.get("rows_total", {}).items()},
            residual_rms={k: float(v) for k, v in d.get("residual_rms", {}).items()},
            channel_sigma={k: float(v) for k, v in d.get("channel_sigma", {}).items()},
            method=str(d.get("method", "ls")),
            condition_number_channel_weighted=d.get("condition_number_channel_weighted"),
            velocity_threshold=d.get("velocity_threshold", DEFAULT_VELOCITY_THRESHOLD),
            covariance=cov,
            values_ls={k: float(v["value"]) for k, v in first.items()},
            std_ls={k: float(v["std"]) for k, v in first.items()},
        )


# --------------------------------------------------------------------------------------------
# Estimator
# --------------------------------------------------------------------------------------------


def estimate(
    blocks: Iterable[RegressorBlock],
    B_w: float,
    *,
    velocity_threshold: float | Mapping[str, float] = DEFAULT_VELOCITY_THRESHOLD,
    channel_weighting: bool = True,
    rank_tol: float = RANK_TOL,
    correlation_lag: int = 0,
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

    fit = _lstsq(theta1, y, P1_NAMES, rank_tol)
    values_ls = dict(zip(P1_NAMES, fit.p.tolist()))
    std_ls = dict(zip(P1_NAMES, np.sqrt(np.diag(fit.cov)).tolist()))
    used = [c for c in labels if rows_used[c] > 0]
    sigma = _per_channel(fit.residual, ch, used, _rms)

    final, method, cond_w = fit, "ls", None
    if channel_weighting:
        s_max = max(sigma.values())
        if s_max > 0:
            # Floor tiny σ_c (noise-free channels) so weights stay finite.
            floor = 1e-6 * s_max
            wrow = np.empty_like(y)
            for c in used:
                wrow[ch == c] = 1.0 / max(sigma[c], floor)
            wfit = _lstsq(theta1 * wrow[:, None], y * wrow, P1_NAMES, rank_tol)
            final = _Fit(p=wfit.p, cov=wfit.cov, cond=fit.cond, residual=y - theta1 @ wfit.p)
            cond_w = wfit.cond
            method = "channel_weighted_ls"
        # else: all residuals are zero (noise-free data); weighting cannot change the solution.
    if correlation_lag > 0:
        wrow_final = wrow if method == "channel_weighted_ls" else np.ones_like(y)
        cov = _newey_west_cov(theta1 * wrow_final[:, None], final.residual * wrow_final, ch,
                              row_index, correlation_lag)
        final = _Fit(p=final.p, cov=cov, cond=final.cond, residual=final.residual)

    return IdentificationResult(
        values=dict(zip(P1_NAMES, final.p.tolist())),
        std=dict(zip(P1_NAMES, np.sqrt(np.diag(final.cov)).tolist())),
        B_w=float(B_w),
        condition_number=fit.cond,
        condition_number_channel_weighted=cond_w,
        rows_used=rows_used,
        rows_total=rows_total,
        residual_rms={c: (_rms(final.residual[ch == c]) if rows_used[c] else float("nan")) for c in labels},
        channel_sigma=sigma,
        method=method,
        velocity_threshold=dict(velocity_threshold) if isinstance(velocity_threshold, Mapping) else float(velocity_threshold),
        covariance=final.cov,
        values_ls=values_ls,
        std_ls=std_ls,
    )


def _newey_west_cov(x: np.ndarray, e: np.ndarray, channel: np.ndarray, row_index: np.ndarray,
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


# --------------------------------------------------------------------------------------------
# Single-axis identification (lifted wheels)
# --------------------------------------------------------------------------------------------

SINGLE_AXIS_NAMES: tuple[str, ...] = ("B_w", "d_vw", "d_cw")
WHEEL_NAMES: tuple[str, ...] = WHEELS


@dataclass
class SingleAxisResult:
    """Result of :func:`estimate_single_axis`.

    ``values[wheel][name]``, ``std[wheel][name]`` for name in (B_w, d_vw, d_cw) (kg m², N m s/rad,
    N m, wheel side); ``pooled``/``pooled_std``: one fit over all wheels stacked (the paper assumes
    equal wheels); ``rows_used`` and ``residual_rms`` (N m) per wheel.
    """

    values: dict[str, dict[str, float]]
    std: dict[str, dict[str, float]]
    pooled: dict[str, float]
    pooled_std: dict[str, float]
    rows_used: dict[str, int]
    residual_rms: dict[str, float]
    epsilon: float = EPSILON

    @property
    def B_w(self) -> float:
        """Pooled B_w estimate (kg m²), to use as p₂ in :func:`estimate`."""
        return self.pooled["B_w"]

    def to_json_dict(self) -> dict:
        def block(v, s):
            return {n: {"value": v[n], "std": s[n], "unit": PARAMETER_UNITS[n]} for n in SINGLE_AXIS_NAMES}

        return {
            "wheels": {w: block(self.values[w], self.std[w]) for w in self.values},
            "pooled": block(self.pooled, self.pooled_std),
            "rows_used": dict(self.rows_used),
            "residual_rms": dict(self.residual_rms),
            "epsilon": self.epsilon,
        }

    @classmethod
    def from_json_dict(cls, d: Mapping) -> "SingleAxisResult":
        def split(b):
            return ({n: float(b[n]["value"]) for n in SINGLE_AXIS_NAMES},
                    {n: float(b[n]["std"]) for n in SINGLE_AXIS_NAMES})

        vals, stds = {}, {}
        for w, b in d["wheels"].items():
            vals[w], stds[w] = split(b)
        pv, ps = split(d["pooled"])
        return cls(vals, stds, pv, ps, {k: int(v) for k, v in d["rows_used"].items()},
                   {k: float(v) for k, v in d["residual_rms"].items()}, float(d.get("epsilon", EPSILON)))


def estimate_single_axis(
    beta_dot: ArrayLike,
    beta_ddot: ArrayLike,
    wheel_torque: ArrayLike,
    *,
    epsilon: float = EPSILON,
    velocity_threshold: float = DEFAULT_VELOCITY_THRESHOLD,
    wheels: Sequence[str] | None = None,
    rank_tol: float = RANK_TOL,
    correlation_lag: int = 0,
) -> SingleAxisResult:
    """Single-axis fit without ground contact: B_w β̈ + d_vw β̇ + d_cw tanh(β̇/ε) = i_G M_mot.

    Parameters
    ----------
    beta_dot, beta_ddot : array_like, shape (N,) or (N, n_w)
        Wheel speed (rad/s) and acceleration (rad/s²), one column per wheel.
    wheel_torque : array_like, same shape
        Torque on the wheel side of the gear, i_G · motor_torque (N m).
    epsilon : float
        tanh smoothing ε (rad/s).
    velocity_threshold : float
        Rows with |β̇| below it are removed (rad/s).
    wheels : sequence of str, optional
        Wheel names, default ``fl, rl, fr, rr`` (or ``w0, w1, …`` if n_w ≠ 4).
    correlation_lag : int
        Newey–West lag for the covariance of filtered rows, as in :func:`estimate`.

    Returns
    -------
    SingleAxisResult

    Raises
    ------
    ValueError
        Shape mismatch, NaN/inf, or no rows left after the threshold.
    IdentifiabilityError
        If a wheel's regressor [β̈, β̇, tanh(β̇/ε)] is rank deficient.
    """
    bd = np.asarray(beta_dot, dtype=float)
    bdd = np.asarray(beta_ddot, dtype=float)
    tq = np.asarray(wheel_torque, dtype=float)
    if bd.ndim == 1:
        bd, bdd, tq = bd[:, None], bdd[:, None] if bdd.ndim == 1 else bdd, tq[:, None] if tq.ndim == 1 else tq
    if not (bd.shape == bdd.shape == tq.shape) or bd.ndim != 2:
        raise ValueError(f"shapes differ: beta_dot {bd.shape}, beta_ddot {bdd.shape}, wheel_torque {tq.shape}")
    for name, arr in (("beta_dot", bd), ("beta_ddot", bdd), ("wheel_torque", tq)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} contains NaN or inf")
    n_w = bd.shape[1]
    if wheels is None:
        wheels = WHEEL_NAMES if n_w == 4 else tuple(f"w{i}" for i in range(n_w))
    if len(wheels) != n_w:
        raise ValueError(f"{len(wheels)} wheel names for {n_w} columns")

    vals, stds, rows, res = {}, {}, {}, {}
    all_theta, all_y = [], []
    for j, w in enumerate(wheels):
        keep = np.abs(bd[:, j]) >= velocity_threshold
        rows[w] = int(keep.sum())
        if not keep.any():
            raise ValueError(f"wheel {w}: no rows left after the velocity threshold {velocity_threshold}")
        theta = np.column_stack([bdd[keep, j], bd[keep, j], np.tanh(bd[keep, j] / epsilon)])
        y = tq[keep, j]
        fit = _lstsq(theta, y, SINGLE_AXIS_NAMES, rank_tol)
        if correlation_lag > 0:
            fit.cov = _newey_west_cov(theta, fit.residual, np.zeros(len(y), dtype=object),
                                      np.nonzero(keep)[0], correlation_lag)
        vals[w] = dict(zip(SINGLE_AXIS_NAMES, fit.p.tolist()))
        stds[w] = dict(zip(SINGLE_AXIS_NAMES, np.sqrt(np.diag(fit.cov)).tolist()))
        res[w] = _rms(fit.residual)
        all_theta.append(theta)
        all_y.append(y)
    pooled = _lstsq(np.vstack(all_theta), np.concatenate(all_y), SINGLE_AXIS_NAMES, rank_tol)
    if correlation_lag > 0:
        labels = np.concatenate([np.full(len(y), w, dtype=object) for w, y in zip(wheels, all_y)])
        index = np.concatenate([np.nonzero(np.abs(bd[:, j]) >= velocity_threshold)[0]
                                for j in range(n_w)])
        pooled.cov = _newey_west_cov(np.vstack(all_theta), pooled.residual, labels, index,
                                     correlation_lag)
    return SingleAxisResult(
        values=vals,
        std=stds,
        pooled=dict(zip(SINGLE_AXIS_NAMES, pooled.p.tolist())),
        pooled_std=dict(zip(SINGLE_AXIS_NAMES, np.sqrt(np.diag(pooled.cov)).tolist())),
        rows_used=rows,
        residual_rms=res,
        epsilon=epsilon,
    )
