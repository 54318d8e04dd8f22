"""Zero-phase low-pass filtering and time derivatives of sampled signals (paper section 7).

The paper filters all measured signals, including the first and second time derivatives, zero-phase
with a cut-off frequency ω_g = 40 rad/s at a sample time T_s = 2 ms.

Method used here
----------------
* Low pass: Butterworth filter (``scipy.signal.butter``, second-order sections) applied forwards and
  backwards (``scipy.signal.sosfiltfilt``) → zero phase, squared magnitude. ``omega_g`` is the
  cut-off of the single-pass Butterworth design, so the forward–backward response is
  |H(jω_g)|² = 1/2 (−6 dB) at ω_g and ≈ 1 − (ω/ω_g)^(2·order) well below it.
* Derivatives: *filter first, then differentiate* with second-order central differences
  (``numpy.gradient``, one-sided second-order at the two end samples). The central-difference kernel
  is antisymmetric, hence zero phase; its gain is sin(ωT_s)/(ωT_s), ≥ 0.9989 up to ω_g = 40 rad/s.
  The second derivative is ``numpy.gradient`` applied twice (kernel [1, 0, −2, 0, 1]/(4T_s²), symmetric,
  gain (sin(ωT_s)/(ωT_s))² ≥ 0.998 up to ω_g). Within ~padlen samples of the ends the result is
  affected by the filter's edge padding; discard a short margin at both ends of each experiment.
* Filter the right-hand side (torques) with the same :func:`zero_phase_lowpass` so regressor and
  torques see the same filter.

Arrays are filtered along axis 0 (time): shape (N,) or (N, m) with m independent columns.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy import signal

__all__ = [
    "OMEGA_G",
    "T_S",
    "FILTER_ORDER",
    "design_lowpass",
    "padlen",
    "zero_phase_lowpass",
    "derivative",
    "zero_phase_derivatives",
]

#: Cut-off frequency ω_g of all zero-phase filters (rad/s), paper section 7.
OMEGA_G = 40.0
#: Sample time T_s (s), paper section 7.
T_S = 2e-3
#: Order of the single-pass Butterworth design (the zero-phase filter has twice this order).
FILTER_ORDER = 2


def design_lowpass(omega_g: float = OMEGA_G, T_s: float = T_S, order: int = FILTER_ORDER) -> np.ndarray:
    """Butterworth low pass as second-order sections.

    Parameters
    ----------
    omega_g : float
        Cut-off angular frequency (rad/s), 0 < ω_g < π/T_s.
    T_s : float
        Sample time (s), > 0.
    order : int
        Butterworth order (≥ 1) of one pass.

    Returns
    -------
    sos : ndarray, shape (ceil(order/2), 6)

    Raises
    ------
    ValueError
        If the cut-off is not below the Nyquist frequency or the arguments are non-positive.
    """
    if T_s <= 0 or omega_g <= 0 or order < 1:
        raise ValueError(f"need T_s > 0, omega_g > 0, order >= 1; got {T_s}, {omega_g}, {order}")
    omega_nyq = np.pi / T_s
    if omega_g >= omega_nyq:
        raise ValueError(f"omega_g = {omega_g} rad/s must be below the Nyquist frequency {omega_nyq:.4g} rad/s")
    return signal.butter(order, omega_g / (2.0 * np.pi), btype="low", output="sos", fs=1.0 / T_s)


def padlen(order: int = FILTER_ORDER) -> int:
    """Edge padding (samples) used by :func:`zero_phase_lowpass`; signals must be longer than this.

    Same value as scipy's default for ``sosfiltfilt``: 3·(2·n_sections + 1).
    """
    n_sections = (order + 1) // 2
    return 3 * (2 * n_sections + 1)


def _as_signal(x: ArrayLike, name: str = "x") -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim not in (1, 2):
        raise ValueError(f"{name} must have shape (N,) or (N, m), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} contains NaN or inf")
    return x


def zero_phase_lowpass(
    x: ArrayLike, T_s: float = T_S, omega_g: float = OMEGA_G, order: int = FILTER_ORDER
) -> np.ndarray:
    """Zero-phase Butterworth low pass along axis 0 (forward–backward, ``sosfiltfilt``).

    Parameters
    ----------
    x : array_like, shape (N,) or (N, m)
        Samples at spacing ``T_s``; columns are filtered independently.
    T_s, omega_g, order
        See :func:`design_lowpass` (defaults: 2 ms, 40 rad/s, 2).

    Returns
    -------
    ndarray, shape of ``x``

    Raises
    ------
    ValueError
        If N ≤ :func:`padlen` (signal too short), x contains NaN/inf or has more than 2 dims.
    """
    x = _as_signal(x)
    sos = design_lowpass(omega_g, T_s, order)
    pl = padlen(order)
    if x.shape[0] <= pl:
        raise ValueError(
            f"signal has {x.shape[0]} samples; the zero-phase filter needs more than padlen = {pl}"
        )
    return signal.sosfiltfilt(sos, x, axis=0, padlen=pl)


def derivative(x: ArrayLike, T_s: float = T_S, n: int = 1) -> np.ndarray:
    """n-th time derivative (n = 1 or 2) by repeated second-order central differences (zero phase).

    No filtering is applied; use :func:`zero_phase_derivatives` for measured data.

    Parameters
    ----------
    x : array_like, shape (N,) or (N, m), N ≥ 3
    T_s : float
        Sample time (s).
    n : int
        Derivative order, 1 or 2.

    Returns
    -------
    ndarray, shape of ``x`` (unit of x per sⁿ)
    """
    x = _as_signal(x)
    if n not in (1, 2):
        raise ValueError(f"n must be 1 or 2, got {n}")
    if x.shape[0] < 3:
        raise ValueError(f"need at least 3 samples for a derivative, got {x.shape[0]}")
    d = x
    for _ in range(n):
        d = np.gradient(d, T_s, axis=0, edge_order=2)
    return d


def zero_phase_derivatives(
    x: ArrayLike, T_s: float = T_S, omega_g: float = OMEGA_G, order: int = FILTER_ORDER
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Filtered signal and its first and second time derivatives, all zero phase.

    Filter with :func:`zero_phase_lowpass`, then differentiate with central differences.

    Parameters
    ----------
    x : array_like, shape (N,) or (N, m)
        Samples (e.g. angles in rad) at spacing ``T_s`` (s).
    T_s, omega_g, order
        See :func:`design_lowpass`.

    Returns
    -------
    x_f, x_dot, x_ddot : ndarray, each of the shape of ``x`` (unit, unit/s, unit/s²)

    Raises
    ------
    ValueError
        As :func:`zero_phase_lowpass`.
    """
    x_f = zero_phase_lowpass(x, T_s, omega_g, order)
    x_d = np.gradient(x_f, T_s, axis=0, edge_order=2)
    x_dd = np.gradient(x_d, T_s, axis=0, edge_order=2)
    return x_f, x_d, x_dd
