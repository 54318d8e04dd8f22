"""The identification result (:class:`IdentificationResult`): identified p₁ with standard deviations, the
fixed p₂, the fit's statistics, and its JSON form (``identification.json``)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from qomni.conventions import P1_NAMES, PARAMETER_NAMES, PARAMETER_UNITS

from .json_values import json_number, json_object, row_counts
from .least_squares import RANK_TOL
from .regressor import DEFAULT_VELOCITY_THRESHOLD
from .torque_timing import TorqueTimingError, check_lag

#: Largest cond(Θ̂₁ᵀΘ̂₁) an identification can have: the fit refuses a regressor whose smallest singular value
#: is under RANK_TOL of its largest (:func:`.least_squares.check_rank`) as rank-deficient.
MAX_CONDITION = RANK_TOL ** -2


#: σ below zero beyond which a parameter no vehicle can have is not a small parameter's noise
#: (:meth:`IdentificationResult.not_physical_remedy`): a one-sided 3 σ bound, 0.13 % of normal draws.
NOT_PHYSICAL_Z = 3.0
#: :meth:`IdentificationResult.not_physical_remedy` where a bound mends the estimate.
BOUND_REMEDY = "identify with --estimator consistent"


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

    def not_physical_remedy(self) -> str:
        """What to do about the parameters :meth:`not_physical` lists, as a sentence ("" where none).

        A value more than :data:`NOT_PHYSICAL_Z` σ below zero is not noise around a small parameter, which a
        bound mends (``--estimator consistent``), but data the model cannot hold: a value the fit takes as
        known that is not the vehicle's, torques in another unit, or an unmodelled effect (a quick blind-suite
        case with Stribeck friction in both joints gave d_vl = −1.33). A parameter the consistent
        estimator holds at its bound (σ = 0) is judged by the unbounded first pass (``values_ls``): on a
        quick prototype campaign with a data-sheet B_w ten times the prototype's that pass put C_l, C_r and
        C_ch at −39, −11 and −116 σ."""
        wrong = self.not_physical()
        if not wrong:
            return ""
        far = {}
        for name in (text.split(" = ")[0] for text in wrong):
            value, sigma, unbounded = self.values[name], self.std.get(name, 0.0), False
            if not sigma > 0 and self.std_ls.get(name, 0.0) > 0:
                value, sigma, unbounded = self.values_ls[name], self.std_ls[name], True
            if sigma > 0 and value < -NOT_PHYSICAL_Z * sigma:
                far[name] = f"{name} {value / sigma:+.0f} σ" + (" unbounded" if unbounded else "")
        cause = (f"the data hold what the model does not: a value the fit takes as known that is not this "
                 f"vehicle's (B_w = {self.B_w:g} kg m², from the data sheet unless a lifted single-axis run "
                 "measured it; the gear ratio i_G; the wheel radius r), torques in another unit, or an "
                 "unmodelled effect ('qomni diagnose' names it)")
        if far:
            return (f"{', '.join(far.values())} lie far below zero, more than noise around a small parameter: "
                    f"{cause}; --estimator consistent bounds them and gives the physical model a twin needs, "
                    "but does not mend the cause")
        if self.estimator == "consistent":
            return f"the physically consistent fit holds them at their bound; where no bound is expected, {cause}"
        return BOUND_REMEDY

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
        """Inverse of :meth:`to_json_dict`, validating what it reads.

        Raises:
            ValueError: naming the key (``parameters.m_ch.value``, ``torque_lag.value`` …): a parameter
                missing or unknown, a value that is not a JSON number (a string, a boolean, null), not
                finite, a unit other than the model's, a standard deviation negative, B_w not positive, a
                torque lag beyond ±MAX_LAG (:mod:`.torque_timing`), a velocity threshold not positive, a
                condition number below 1,
                a covariance not 10 × 10 finite and symmetric, a row count not a non-negative integer.
        """
        params = json_object(d.get("parameters"), "parameters")
        unknown = sorted(set(params) - set(P1_NAMES) - {"B_w"})
        if unknown:
            raise ValueError(f"parameters: unknown {', '.join(unknown)} (this model has {', '.join(PARAMETER_NAMES)})")
        entries = {}
        for name in (*P1_NAMES, "B_w"):
            if name not in params:
                raise ValueError(f"parameters.{name}: missing")
            entry = json_object(params[name], f"parameters.{name}")
            value = json_number(entry.get("value"), f"parameters.{name}.value")
            if "unit" in entry and entry["unit"] != PARAMETER_UNITS[name]:
                raise ValueError(f"parameters.{name}.unit is {entry['unit']!r}; this model's {name} is in "
                                 f"{PARAMETER_UNITS[name]}")
            if name == "B_w":
                std = json_number(entry.get("std") or 0.0, f"parameters.{name}.std")
            else:
                std = json_number(entry.get("std"), f"parameters.{name}.std")
            if std < 0:
                raise ValueError(f"parameters.{name}.std must be >= 0, got {std!r}")
            boot = entry.get("std_bootstrap")
            if boot is not None and json_number(boot, f"parameters.{name}.std_bootstrap") < 0:
                raise ValueError(f"parameters.{name}.std_bootstrap must be >= 0, got {boot!r}")
            entries[name] = (value, std, boot)
        if not entries["B_w"][0] > 0:
            raise ValueError(f"parameters.B_w.value must be > 0 kg m^2, got {entries['B_w'][0]!r}")
        torque_lag = dict(json_object(d.get("torque_lag", {}), "torque_lag"))
        if "value" in torque_lag:
            try:
                check_lag(json_number(torque_lag["value"], "torque_lag.value"))
            except TorqueTimingError as exc:
                raise ValueError(f"torque_lag.value: {exc}") from None
        condition = json_number(d.get("condition_number"), "condition_number")
        if not condition >= 1:
            raise ValueError(f"condition_number must be >= 1, got {condition!r}")
        if condition > MAX_CONDITION:
            raise ValueError(f"condition_number {condition!r} is above {MAX_CONDITION:.0e}, the most an "
                             "identification can have: its regressor is rank-deficient and the parameters are "
                             "not determined by the data")
        weighted = d.get("condition_number_channel_weighted")
        if weighted is not None:
            weighted = json_number(weighted, "condition_number_channel_weighted")
        threshold = d.get("velocity_threshold", DEFAULT_VELOCITY_THRESHOLD)
        for key, v in (threshold.items() if isinstance(threshold, Mapping) else [("", threshold)]):
            where = f"velocity_threshold.{key}" if key else "velocity_threshold"
            if not json_number(v, where) > 0:
                raise ValueError(f"{where} must be > 0 rad/s or m/s, got {v!r}")
        cov = d.get("covariance")
        if cov is not None:
            cov = json_object(cov, "covariance")
            if list(cov.get("names", [])) != list(P1_NAMES):
                raise ValueError(f"covariance.names {cov.get('names')} differ from {list(P1_NAMES)}")
            try:
                cov = np.asarray(cov.get("matrix"), dtype=float)
            except (TypeError, ValueError):
                raise ValueError("covariance.matrix must be a 10 × 10 array of numbers") from None
            n = len(P1_NAMES)
            if cov.shape != (n, n) or not np.isfinite(cov).all() or np.abs(cov - cov.T).max() > 1e-9 * np.abs(cov).max():
                raise ValueError(f"covariance.matrix must be a finite symmetric {n} × {n} array, got shape {cov.shape}")
        first = json_object(d.get("ls_first_pass", {}), "ls_first_pass")
        estimator = json_object(d.get("estimator", {}), "estimator")
        return cls(
            values={n: entries[n][0] for n in P1_NAMES},
            std={n: entries[n][1] for n in P1_NAMES},
            B_w=entries["B_w"][0],
            condition_number=condition,
            rows_used=row_counts(d.get("rows_used", {}), "rows_used"),
            rows_total=row_counts(d.get("rows_total", {}), "rows_total"),
            residual_rms={k: json_number(v, f"residual_rms.{k}")
                          for k, v in json_object(d.get("residual_rms", {}), "residual_rms").items()},
            channel_sigma={k: json_number(v, f"channel_sigma.{k}")
                           for k, v in json_object(d.get("channel_sigma", {}), "channel_sigma").items()},
            method=str(d.get("method", "ls")),
            condition_number_channel_weighted=weighted,
            velocity_threshold=threshold,
            covariance=cov,
            values_ls={k: json_number(json_object(v, f"ls_first_pass.{k}").get("value"), f"ls_first_pass.{k}.value")
                       for k, v in first.items()},
            std_ls={k: json_number(json_object(v, f"ls_first_pass.{k}").get("std"), f"ls_first_pass.{k}.std")
                    for k, v in first.items()},
            estimator=str(estimator.get("name", "wls")),
            estimator_info={k: v for k, v in estimator.items() if k != "name"},
            identifiability=dict(json_object(d.get("identifiability", {}), "identifiability")),
            std_bootstrap={n: float(entries[n][2]) for n in P1_NAMES if entries[n][2] is not None},
            bootstrap=dict(json_object(d.get("bootstrap", {}), "bootstrap")),
            torque_lag=torque_lag,
            spikes=dict(json_object(d.get("spikes", {}), "spikes")),
        )



def parameter_differences(model: IdentificationResult, other: IdentificationResult) -> dict[str, dict]:
    """How another vehicle's identification ``other`` differs from ``model``, parameter by parameter.

    Two vehicles differ in every parameter, which no unmodelled-effect hypothesis describes (a model of a
    vehicle 464 kg heavier named a floor incline on the lighter one's run); their identifications say it
    directly. The two campaigns' estimates are independent, so σ = √(σ_model² + σ_other²). σ counts the
    noise, not the identification's own bias (C_r up to 8 % on the prototype's full campaign,
    docs/identification.md), which two campaigns of one vehicle share only in part.

    Returns:
        {name: {"model", "other", "difference" (other − model), "relative" (to the model's value), "std",
        "z"}} for the ten parameters of p₁ (units: :data:`qomni.conventions.PARAMETER_UNITS`), and
        ``B_w`` with ``std`` and ``z`` null (each fit holds its B_w fixed).
    """
    rows = {}
    for name in P1_NAMES:
        a, b = float(model.values[name]), float(other.values[name])
        std = float(np.hypot(model.std[name], other.std[name]))
        rows[name] = {"model": a, "other": b, "difference": b - a, "relative": (b - a) / a if a else None,
                      "std": std, "z": (b - a) / std if std > 0 else None}
    rows["B_w"] = {"model": model.B_w, "other": other.B_w, "difference": other.B_w - model.B_w,
                   "relative": (other.B_w - model.B_w) / model.B_w if model.B_w else None, "std": None, "z": None}
    return rows
