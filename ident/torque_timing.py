"""Torque timing from the data: the lag between the reported torque actual (0x6077) and the torque that
acts on the vehicle, estimated from the campaign itself and corrected before the fit.

Convention (docs/conventions.md, "Torque timing"): the torque actual reported with SYNC j is the torque
applied over [t_j, t_j + T_s]. A drive whose report lags by δ seconds (e.g. δ = T_s when it samples the
torque at the SYNC instant, one cycle behind the set-point it then applies) reports at t the torque
applied at t − δ, so the applied torque is u(t) = r(t + δ). δ < 0 means the torque acts later than
reported (an actuator delay). δ is any real number: a fraction of a cycle or several cycles.

Estimation (Gauss–Newton on the lag, the parameters eliminated by least squares). The rows of (22)
are linear in the torque, so with τ_δ the right-hand sides built from r(t + δ),

    τ_{δ+Δ} ≈ τ_δ + Δ ∂τ/∂δ,    ∂τ/∂δ = the same rows built from ṙ(t + δ),

and the channel-weighted fit of y_δ = τ_δ − Θ̂₂p₂ on [Θ̂₁, −∂τ/∂δ] gives p₁ and the step Δ together;
δ ← δ + Δ until |Δ| < ``tol``. ∂τ/∂δ carries the jerk of the motion, which no column of Θ̂₁ contains, so
δ is identifiable from any exciting campaign. Its σ is the Newey–West σ of the Δ column at convergence.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from qomni.conventions import P1_NAMES, P2_NAMES, PARAMETER_NAMES

from .least_squares import channel_weighted_lstsq, newey_west_cov
from .recording import Signals
from .regressor import RegressorBlock, row_mask, stack_blocks

#: Largest |δ| the estimate may reach (s): beyond it the campaign is not consistent with any lag.
MAX_LAG = 0.05


class TorqueTimingError(ValueError):
    """The torque lag cannot be estimated or applied (no convergence, out of range, bad value)."""


@dataclass(frozen=True)
class TorqueLag:
    """Lag of the reported torque behind the applied one (s) that the fit corrects for; ``source`` is
    ``"estimated"`` or ``"configured"``; ``std`` (s) and ``iterations`` only for an estimate.
    ``estimate``, ``estimate_std`` (s): the campaign's own estimate, also beside a configured lag
    (None where it could not be made)."""

    value: float
    source: str
    cycle_time: float
    std: float | None = None
    iterations: int = 0
    estimate: float | None = None
    estimate_std: float | None = None

    def to_json_dict(self) -> dict:
        return {"value": self.value, "unit": "s", "cycles": self.value / self.cycle_time,
                "std": self.std, "source": self.source, "iterations": self.iterations,
                "estimate": self.estimate, "estimate_std": self.estimate_std,
                "definition": "reported torque actual (0x6077) at t is the torque applied at t - lag; "
                              "applied u(t) = reported r(t + lag) (docs/conventions.md, Torque timing)"}


def shift_torque(signals: Signals, lag: float) -> Signals:
    """The recording with its torque actual replaced by the applied torque u(t) = r(t + lag).

    Linear interpolation in time over the whole recording (steps follow each other without gaps); the
    first/last sample is held beyond the ends. Args: signals (N rows); lag (s, finite).
    Raises: TorqueTimingError for a non-finite lag or |lag| > MAX_LAG.
    """
    check_lag(lag)
    if lag == 0.0:
        return signals
    t = signals.time
    shifted = np.column_stack([np.interp(t + lag, t, col) for col in signals.motor_torque.T])
    return replace(signals, motor_torque=shifted)


def torque_rate(signals: Signals) -> Signals:
    """The recording with its torque actual replaced by its time derivative ṙ (N m/s)."""
    return replace(signals, motor_torque=np.gradient(signals.motor_torque, signals.time, axis=0))


def check_lag(lag: float) -> float:
    """``lag`` as a float. Raises TorqueTimingError if it is not finite or |lag| > MAX_LAG."""
    lag = float(lag)
    if not np.isfinite(lag) or abs(lag) > MAX_LAG:
        raise TorqueTimingError(f"torque lag {lag} s: must be finite and within ±{MAX_LAG} s")
    return lag


def model_lag(result) -> float:
    """The torque lag (s) an :class:`.result.IdentificationResult` was identified with (0 when none):
    data compared with that model must be shifted by it (:func:`shift_torque`) first.

    Raises: TorqueTimingError for an invalid stored lag."""
    return check_lag(result.torque_lag.get("value", 0.0)) if result.torque_lag else 0.0


def estimate_torque_lag(
    signals: Signals,
    blocks_of: Callable[[Signals], list[RegressorBlock]],
    B_w: float,
    cycle_time: float,
    velocity_threshold,
    correlation_lag: int,
    *,
    tol: float = 1e-6,
    max_iter: int = 10,
) -> TorqueLag:
    """Estimate the report lag δ (s) by Gauss–Newton (module docstring).

    Args:
        signals: the recording; blocks_of: builds the identification rows (22) from a recording;
        B_w: fixed p₂ (kg m²); cycle_time: T_s (s); velocity_threshold: stiction rule of the fit;
        correlation_lag: Newey–West lags for σ_δ; tol: step size that ends the iteration (s).
    Raises:
        TorqueTimingError: no convergence within ``max_iter`` or the estimate leaves ±MAX_LAG.
        IdentifiabilityError: the extended regressor is rank deficient.
    """
    i1 = [PARAMETER_NAMES.index(n) for n in P1_NAMES]
    i2 = [PARAMETER_NAMES.index(n) for n in P2_NAMES]
    lag = 0.0
    for it in range(1, max_iter + 1):
        shifted = shift_torque(signals, lag)
        theta, tau, vel, ch = stack_blocks(blocks_of(shifted))
        dtau = stack_blocks(blocks_of(torque_rate(shifted)))[1]
        keep = row_mask(vel, ch, velocity_threshold)
        x = np.column_stack([theta[keep][:, i1], -dtau[keep]])
        y = tau[keep] - theta[keep][:, i2] @ np.array([B_w])
        fit, wrow = channel_weighted_lstsq(x, y, ch[keep], (*P1_NAMES, "lag"))
        step = float(fit.p[-1])
        lag += step
        if abs(lag) > MAX_LAG:
            raise TorqueTimingError(f"torque lag estimate left ±{MAX_LAG} s (reached {lag:.4g} s after "
                                    f"{it} iterations): the torque does not explain the motion at any lag")
        if abs(step) < tol:
            cov = newey_west_cov(x * wrow[:, None], fit.residual * wrow, ch[keep], np.nonzero(keep)[0],
                                 correlation_lag)
            std = float(np.sqrt(cov[-1, -1]))
            return TorqueLag(lag, "estimated", cycle_time, std, it, lag, std)
    raise TorqueTimingError(f"torque lag estimate did not converge in {max_iter} iterations "
                            f"(last step {step:.3g} s)")
