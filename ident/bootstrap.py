"""Moving-block bootstrap of an estimate over campaign windows: a check on the Newey–West σ_p.

Rows of filtered signals are correlated over ≈ 4/(ω_g T_s) rows (``correlation_lag``), so rows cannot be
resampled one by one. Each channel's rows (after the stiction rule) are cut into consecutive windows of
``window`` rows; a replicate draws as many windows of each channel, with replacement, as the channel
has (stratified by channel, so every step keeps its share), and solves the same weighted problem
(Künsch 1989, moving-block bootstrap; Efron & Tibshirani 1993 ch. 8). σ_boot is the standard
deviation of the replicates. Row weights are held at the estimate's final weights.
"""
from __future__ import annotations

import numpy as np

#: Replicates of the bootstrap (the σ of a σ estimate from B replicates is ≈ σ/√(2B): 5 % at B = 200).
N_REPLICATES = 200
#: Windows are this many correlation lengths long, so that windows are nearly independent.
WINDOW_CORRELATION_LENGTHS = 4


def windows(channel: np.ndarray, window: int) -> list[np.ndarray]:
    """Row indices of consecutive windows of ``window`` rows within each channel (the last of a channel
    may be shorter). ``channel`` (N,) labels in row order."""
    out = []
    for c in dict.fromkeys(channel.tolist()):
        idx = np.nonzero(channel == c)[0]
        out += [idx[i:i + window] for i in range(0, len(idx), window)]
    return out


def bootstrap_std(x: np.ndarray, y: np.ndarray, channel: np.ndarray, window: int, *,
                  instruments: np.ndarray | None = None, n_replicates: int = N_REPLICATES,
                  seed: int = 0) -> np.ndarray:
    """σ of the weighted least-squares (or, with ``instruments``, IV) solution over block-bootstrap
    replicates.

    Args:
        x: (N, n) weighted rows; y: (N,) weighted right-hand sides; channel: (N,) labels;
        window: rows per window (≥ 1); instruments: (N, n) weighted instruments for IV;
        n_replicates, seed: the bootstrap's size and its generator's seed (reproducible).
    Returns:
        (n,) standard deviations, in the units of the parameters.
    Raises:
        ValueError: window < 1 or fewer than two windows in every channel.
    """
    if window < 1:
        raise ValueError(f"window must be >= 1 row, got {window}")
    rng = np.random.default_rng(seed)
    by_channel: dict[str, list[np.ndarray]] = {}
    for w in windows(channel, window):
        by_channel.setdefault(channel[w[0]], []).append(w)
    if all(len(ws) < 2 for ws in by_channel.values()):
        raise ValueError("too few rows for a block bootstrap: every channel has fewer than two windows")
    z = x if instruments is None else instruments
    scale = np.linalg.norm(x, axis=0)
    reps = np.empty((n_replicates, x.shape[1]))
    for b in range(n_replicates):
        rows = np.concatenate([ws[j] for ws in by_channel.values()
                               for j in rng.integers(0, len(ws), size=len(ws))])
        xs, zs = x[rows] / scale, z[rows] / scale
        reps[b] = np.linalg.lstsq(zs.T @ xs, zs.T @ y[rows], rcond=None)[0] / scale
    return reps.std(axis=0, ddof=1)
