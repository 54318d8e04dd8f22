"""The identification result (:class:`IdentificationResult`): identified p₁ with standard deviations, the
fixed p₂, the fit's statistics, and its JSON form (``identification.json``)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from qomni.conventions import P1_NAMES, PARAMETER_NAMES, PARAMETER_UNITS

from .regressor import DEFAULT_VELOCITY_THRESHOLD

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
    estimator : str
        The estimator of ``values`` (:data:`.estimators.ESTIMATORS`); ``estimator_info`` its details
        (robust weights, active bounds, instruments).
    identifiability : dict
        Per-parameter report (:mod:`.parameter_report`): determining step, relative σ, correlations.
    std_bootstrap, bootstrap : dict
        σ_p from a moving-block bootstrap over campaign windows (:mod:`.bootstrap`), and its settings.
    torque_lag : dict
        The lag of the reported torque the rows were corrected for (:mod:`.torque_timing`), if any.
    spikes : dict
        Isolated glitches repaired in the recorded signals before filtering (:mod:`.spikes`), if tested.
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
    estimator: str = "wls"
    estimator_info: dict = field(default_factory=dict)
    identifiability: dict = field(default_factory=dict)
    std_bootstrap: dict[str, float] = field(default_factory=dict)
    bootstrap: dict = field(default_factory=dict)
    torque_lag: dict = field(default_factory=dict)
    spikes: dict = field(default_factory=dict)

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

    def not_physical(self) -> list[str]:
        """The parameters no vehicle can have, as ``"m_ch = -800.0"`` texts: an inertia or mass (C_l,
        C_r, m_ch, C_ch) not positive, a viscous or Coulomb coefficient negative. Least squares returns
        them where the campaign leaves a parameter near zero; ``--estimator consistent`` bounds them.
        Empty for a physical model."""
        inertias = [n for n in ("C_l", "C_r", "m_ch", "C_ch") if not self.values[n] > 0]
        frictions = [n for n in ("d_vl", "d_cl", "d_vr", "d_cr", "d_vw", "d_cw") if self.values[n] < 0]
        return [f"{n} = {float(self.values[n])!r}" for n in inertias + frictions]

    def as_dict(self) -> dict[str, float]:
        """{name: value} for all 11 parameters."""
        return dict(zip(PARAMETER_NAMES, self.p.tolist()))

    def report_row(self, name: str) -> tuple[str, str, str, str]:
        """(relative σ, bootstrap σ, determining steps, strongest correlation) of p₁ entry ``name`` as text
        ("-" where the result has no report)."""
        rep = self.identifiability.get(name, {})
        rel = rep.get("relative_std")
        strongest = rep.get("strongest_correlation")
        boot = self.std_bootstrap.get(name)
        return (f"{100 * rel:.2f} %" if rel is not None else "-",
                f"{boot:.4f}" if boot is not None else "-",
                ", ".join(rep.get("determined_by", [])) or "-",
                f"{strongest['rho']:+.2f} {strongest['with']}" if strongest else "-")

    def table(self) -> str:
        """Plain-text table like the paper's Table 2, with the identifiability report."""
        lines = [f"{'Name':<6} {'Value':>12} {'Std':>10}  {'Unit':<10} {'Rel. std':>9} {'Std boot':>9}  "
                 f"{'Determined by':<32} Strongest corr."]
        for n in P1_NAMES:
            rel, boot, by, rho = self.report_row(n)
            lines.append(f"{n:<6} {self.values[n]:>12.4f} {self.std[n]:>10.4f}  {PARAMETER_UNITS[n]:<10} "
                         f"{rel:>9} {boot:>9}  {by:<32} {rho}")
        lines.append(f"{'B_w':<6} {self.B_w:>12.4f} {'(fixed)':>10}  {PARAMETER_UNITS['B_w']}")
        lines.append(f"cond(Theta_1w^T Theta_1w) = {self.condition_number:.2f}")
        return "\n".join(lines)

    def to_json_dict(self) -> dict:
        params: dict = {
            n: {"value": self.values[n], "std": self.std[n], "unit": PARAMETER_UNITS[n],
                **({"std_bootstrap": self.std_bootstrap[n]} if n in self.std_bootstrap else {})}
            for n in P1_NAMES
        }
        params["B_w"] = {"value": self.B_w, "unit": PARAMETER_UNITS["B_w"], "fixed": True}
        d = {
            "parameters": params,
            "condition_number": self.condition_number,
            "condition_number_definition": "cond(Theta_1w^T Theta_1w), column-norm weighted (25)",
            "condition_number_channel_weighted": self.condition_number_channel_weighted,
            "method": self.method,
            "estimator": {"name": self.estimator, **self.estimator_info},
            "bootstrap": dict(self.bootstrap),
            "identifiability": self.identifiability,
            **({"torque_lag": dict(self.torque_lag)} if self.torque_lag else {}),
            **({"spikes": dict(self.spikes)} if self.spikes else {}),
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
        """Inverse of :meth:`to_json_dict`.

        Raises:
            KeyError: a parameter is missing. ValueError: a value or standard deviation is not finite, a
                standard deviation is negative, B_w is not positive or torque_lag.value is not finite (the key
                named).
        """
        params = d["parameters"]
        for name in (*P1_NAMES, "B_w"):
            value = float(params[name]["value"])
            std = float(params[name].get("std", 0.0) or 0.0) if name == "B_w" else float(params[name]["std"])
            if not (math.isfinite(value) and math.isfinite(std) and std >= 0):
                raise ValueError(f"parameters.{name}: value {value} and std {std} must be finite, std >= 0")
        lag = d.get("torque_lag", {}).get("value", 0.0)
        if not math.isfinite(float(lag)):
            raise ValueError(f"torque_lag.value must be a finite lag in s, got {lag}")
        if not float(params["B_w"]["value"]) > 0:
            raise ValueError(f"parameters.B_w.value must be > 0 kg m^2, got {params['B_w']['value']}")
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
            estimator=str(d.get("estimator", {}).get("name", "wls")),
            estimator_info={k: v for k, v in d.get("estimator", {}).items() if k != "name"},
            identifiability=dict(d.get("identifiability", {})),
            std_bootstrap={n: float(params[n]["std_bootstrap"]) for n in P1_NAMES
                           if "std_bootstrap" in params[n]},
            bootstrap=dict(d.get("bootstrap", {})),
            torque_lag=dict(d.get("torque_lag", {})),
            spikes=dict(d.get("spikes", {})),
        )

