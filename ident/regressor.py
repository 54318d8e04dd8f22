"""Regressor rows of (22): one block per channel (:class:`RegressorBlock`), their stacking and the stiction
row mask (paper section 7). Generic over where the rows come from (:mod:`.regressor_rows` builds them)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from qomni.conventions import PARAMETER_NAMES

#: Default stiction threshold on |generalized velocity| (rad/s or m/s).
DEFAULT_VELOCITY_THRESHOLD = 0.05

#: Stiction thresholds on the generalized velocity (paper section 7), by coordinate: rad/s or m/s.
#: The paper gives no value. A row is only usable when the zero-phase filter (time scale 1/ω_g = 25 ms)
#: does not smear a velocity reversal — where the drive really sticks, unlike tanh(v/ε) — into it:
#: |ṡ| ≳ |s̈|_max/ω_g, i.e. 0.2 rad/s for the steering (≈ 6 rad/s² excitation) and 0.05 for the chassis.
VELOCITY_THRESHOLD = {"alpha_l": 0.2, "alpha_r": 0.2, "alpha_v": 0.2, "x_ch": 0.05,
                      "gamma_ch": 0.05, "*": 0.05}



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

