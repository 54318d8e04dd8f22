"""Validation by comparing generalized torques (paper section 7, Fig. 5 and Fig. 6).

Per row of (24): model torque Θ̂₁ p₁ versus measured torque τ̂ − Θ̂₂ p₂ (p₂ = B_w fixed).

Error measure (used throughout the project)
-------------------------------------------
For each channel c with rows i ∈ c, error e_i = model_i − measured_i:

    rms_error_c = sqrt(mean(e_i²))                          (N m or N, channel unit)
    nrmse_c     = rms_error_c / sqrt(mean(measured_i²))     (dimensionless, relative RMS error)

i.e. NRMSE is normalised by the RMS of the *measured* generalized torque, not by its range.
This is the stricter of the two usual choices (range ≈ 2–3 × RMS for these signals) and does not
depend on a single peak. Acceptance target of the project: chassis channel (``…/x_ch``) ≤ 10 %.

Unlike :func:`qomni.ident.estimation.estimate`, no stiction rows are removed by default (as in the paper's
Fig. 6); pass ``velocity_threshold`` to compare only moving rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from qomni.conventions import P1_NAMES, P2_NAMES, PARAMETER_NAMES
from .result import IdentificationResult
from .regressor import RegressorBlock, row_mask, stack_blocks

__all__ = [
    "NRMSE_DEFINITION",
    "stick_slip_comparison",
    "ChannelComparison",
    "ValidationResult",
    "generalized_torques",
    "compare_generalized_torques",
]

NRMSE_DEFINITION = "rms(model - measured) / rms(measured), per channel"


@dataclass
class ChannelComparison:
    """Model vs. measured generalized torque of one channel.

    ``model``, ``measured``, ``velocity``: shape (n_rows,) over the compared rows, in row order.
    """

    channel: str
    model: np.ndarray
    measured: np.ndarray
    velocity: np.ndarray

    @property
    def n_rows(self) -> int:
        return int(self.measured.size)

    @property
    def error(self) -> np.ndarray:
        return self.model - self.measured

    @property
    def rms_error(self) -> float:
        """RMS of model − measured (N m or N)."""
        return float(np.sqrt(np.mean(self.error**2))) if self.n_rows else math.nan

    @property
    def rms_measured(self) -> float:
        return float(np.sqrt(np.mean(self.measured**2))) if self.n_rows else math.nan

    @property
    def nrmse(self) -> float:
        """rms_error / rms_measured (dimensionless); inf if the measured torque is identically 0."""
        if not self.n_rows:
            return math.nan
        if self.rms_measured == 0.0:
            return 0.0 if self.rms_error == 0.0 else math.inf
        return self.rms_error / self.rms_measured


@dataclass
class ValidationResult:
    """Per-channel comparison; ``channels`` maps label → :class:`ChannelComparison`.

    ``moving`` optionally holds, per channel, the same comparison over moving rows only
    (``{"nrmse": float | None, "n_rows": int}``), which separates stiction from model error;
    ``sticking`` the comparison over the other rows with a model that can stick
    (:func:`stick_slip_comparison`).
    """

    channels: dict[str, ChannelComparison]
    velocity_threshold: float | dict | None = None
    parameters: dict[str, float] = field(default_factory=dict)
    moving: dict[str, dict] = field(default_factory=dict)
    sticking: dict[str, dict] = field(default_factory=dict)

    @property
    def nrmse(self) -> dict[str, float]:
        return {c: v.nrmse for c, v in self.channels.items()}

    @property
    def rms_error(self) -> dict[str, float]:
        return {c: v.rms_error for c, v in self.channels.items()}

    def passes(self, limit: float = 0.10, channels: Sequence[str] | None = None) -> bool:
        """True if NRMSE ≤ ``limit`` for the given channels.

        ``channels`` entries match a full label or its coordinate (after '/'), e.g. ``"x_ch"``;
        default: all channels. Raises KeyError if a requested channel is absent.
        """
        if channels is None:
            sel = list(self.channels)
        else:
            sel = []
            for want in channels:
                hit = [c for c in self.channels if c == want or c.partition("/")[2] == want]
                if not hit:
                    raise KeyError(f"no channel {want!r} in {list(self.channels)}")
                sel += hit
        return all(self.channels[c].nrmse <= limit for c in sel)

    def to_json_dict(self) -> dict:
        return {
            "nrmse_definition": NRMSE_DEFINITION,
            "velocity_threshold": self.velocity_threshold,
            "parameters": dict(self.parameters),
            "channels": {
                c: {
                    "n_rows": v.n_rows,
                    "rms_error": v.rms_error,
                    "rms_measured": v.rms_measured,
                    "nrmse": v.nrmse,
                }
                for c, v in self.channels.items()
            },
        }


def _parameter_vector(parameters, B_w: float | None) -> np.ndarray:
    if isinstance(parameters, IdentificationResult):
        p = parameters.p.copy()
        if B_w is not None:
            p[-1] = B_w
        return p
    if isinstance(parameters, Mapping):
        vals = dict(parameters)
        if B_w is not None:
            vals["B_w"] = B_w
        missing = [n for n in PARAMETER_NAMES if n not in vals]
        if missing:
            raise KeyError(f"parameters missing: {missing}")
        return np.array([float(vals[n]) for n in PARAMETER_NAMES])
    p = np.asarray(parameters, dtype=float).reshape(-1)
    if p.shape == (len(P1_NAMES),):
        if B_w is None:
            raise ValueError("p1 of shape (10,) given: pass B_w")
        p = np.append(p, B_w)
    if p.shape != (len(PARAMETER_NAMES),):
        raise ValueError(f"parameter vector must have shape (11,) or (10,), got {p.shape}")
    if B_w is not None:
        p[-1] = B_w
    return p


def generalized_torques(
    block: RegressorBlock, parameters, *, B_w: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Model Θ̂₁p₁ and measured τ̂ − Θ̂₂p₂ of (24) for one block, each shape (n_rows,).

    ``parameters``: IdentificationResult, mapping name → value, or array (11,) / (10,) with ``B_w``.
    """
    p = _parameter_vector(parameters, B_w)
    i1 = [PARAMETER_NAMES.index(n) for n in P1_NAMES]
    i2 = [PARAMETER_NAMES.index(n) for n in P2_NAMES]
    return block.Theta[:, i1] @ p[i1], block.tau - block.Theta[:, i2] @ p[i2]


def compare_generalized_torques(
    blocks: Iterable[RegressorBlock],
    parameters,
    *,
    B_w: float | None = None,
    velocity_threshold: float | Mapping[str, float] | None = None,
) -> ValidationResult:
    """Compare model and measured generalized torques per channel (section 7).

    Parameters
    ----------
    blocks : iterable of RegressorBlock
        Validation rows (e.g. the mode-2 lane change), Θ̂ (n_rows, 11) in the order (18).
    parameters : IdentificationResult, mapping or array (11,)/(10,)
        Parameters to validate; ``B_w`` overrides/provides p₂ (kg m²).
    velocity_threshold : float, mapping or None
        If given, rows below it are left out as in :func:`qomni.ident.regressor.row_mask`.

    Returns
    -------
    ValidationResult
        NRMSE = rms(model − measured)/rms(measured) and RMS error per channel.

    Raises
    ------
    ValueError
        NaN/inf in the data, wrong parameter shapes, or no rows left.
    """
    p = _parameter_vector(parameters, B_w)
    theta, tau, vel, ch = stack_blocks(blocks)
    if velocity_threshold is not None:
        keep = row_mask(vel, ch, velocity_threshold)
        if not keep.any():
            raise ValueError(f"no rows left after the velocity threshold {velocity_threshold!r}")
        theta, tau, vel, ch = theta[keep], tau[keep], vel[keep], ch[keep]
    i1 = [PARAMETER_NAMES.index(n) for n in P1_NAMES]
    i2 = [PARAMETER_NAMES.index(n) for n in P2_NAMES]
    model = theta[:, i1] @ p[i1]
    measured = tau - theta[:, i2] @ p[i2]
    out = {}
    for c in dict.fromkeys(ch.tolist()):
        m = ch == c
        out[c] = ChannelComparison(c, model[m], measured[m], vel[m])
    thr = None
    if velocity_threshold is not None:
        thr = dict(velocity_threshold) if isinstance(velocity_threshold, Mapping) else float(velocity_threshold)
    return ValidationResult(out, thr, dict(zip(PARAMETER_NAMES, p.tolist())))


#: Parameters whose columns are the Coulomb (tanh) friction of (16).
COULOMB_PARAMETERS = ("d_cl", "d_cr", "d_cw")


def _nrmse(model: np.ndarray, measured: np.ndarray) -> float | None:
    if not measured.size:
        return None
    return ChannelComparison("", model, measured, measured).nrmse


def stick_slip_comparison(blocks: Iterable[RegressorBlock], parameters, velocity_threshold,
                          *, B_w: float | None = None) -> dict[str, dict]:
    """NRMSE per channel on moving and on sticking rows, the sticking rows predicted by a model that
    can stick.

    Rows with |generalized velocity| ≥ the channel's threshold move: the model is Θ̂₁p₁ with its
    tanh(v/ε) Coulomb friction. On the other rows the coordinate sticks: a stick–slip friction switch
    (Karnopp 1985) holds it while the torque it must balance stays within the static friction band, so
    the model's friction is whatever balances the rest of the equation within ±F_s and

        model = clip(measured, rest − F_s, rest + F_s),   rest = Θ̂₁p₁ without its Coulomb columns,

    F_s = Σ_j d_c,j · max_rows |θ_j| over the channel's Coulomb columns (the Coulomb level at
    saturated tanh; the paper's model has no separate static friction).

    Args: blocks: validation rows; parameters: as :func:`compare_generalized_torques`;
        velocity_threshold: float or mapping (:func:`.regressor.row_mask`).
    Returns: ``{channel: {"moving": {"nrmse", "n_rows"}, "sticking": {"nrmse", "n_rows",
        "static_friction"}, "moving_share": float}}`` (nrmse None where a class has no rows).
    Raises: ValueError as :func:`compare_generalized_torques`.
    """
    p = _parameter_vector(parameters, B_w)
    theta, tau, vel, ch = stack_blocks(blocks)
    moving = row_mask(vel, ch, velocity_threshold)
    i1 = [PARAMETER_NAMES.index(n) for n in P1_NAMES]
    i2 = [PARAMETER_NAMES.index(n) for n in P2_NAMES]
    ic = [PARAMETER_NAMES.index(n) for n in COULOMB_PARAMETERS]
    model = theta[:, i1] @ p[i1]
    measured = tau - theta[:, i2] @ p[i2]
    coulomb = theta[:, ic] * p[ic]
    out = {}
    for c in dict.fromkeys(ch.tolist()):
        m = ch == c
        f_s = float(np.sum(np.max(np.abs(theta[m][:, ic]), axis=0) * np.abs(p[ic])))
        rest = model[m] - coulomb[m].sum(axis=1)
        stuck = np.clip(measured[m], rest - f_s, rest + f_s)
        mv = moving[m]
        out[c] = {
            "moving": {"nrmse": _nrmse(model[m][mv], measured[m][mv]), "n_rows": int(mv.sum())},
            "sticking": {"nrmse": _nrmse(stuck[~mv], measured[m][~mv]), "n_rows": int((~mv).sum()),
                         "static_friction": f_s},
            "moving_share": float(mv.mean()),
        }
    return out
