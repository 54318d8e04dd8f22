"""The diagnosis' estimation problem: every channel's rows split into alternating fit and held-out windows,
the fit's result type, and the hypothesis columns cache (see :mod:`.fit`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .channels import ChannelData
from .hypotheses.base import Hypothesis, columns_on

#: Length of the alternating fit / held-out time windows, s (≫ the filter's correlation time).
WINDOW = 1.0
#: Correlation length of kinematic and rolling residuals, s: they are positions (integrated rates), so their noise
#: wanders far longer than the filter's L; they count one independent row per KINEMATIC_CORRELATION.
KINEMATIC_CORRELATION = 0.25


@dataclass(frozen=True)
class MeasuredBase:
    """Base parameters known from a measurement independent of the fitted rows: their shift from the
    model, δp_k ~ N(delta, std²), for the parameters ``index`` of p₁ (e.g. the wheels' friction from the
    lifted vehicle's single-axis run)."""

    index: tuple[int, ...]
    delta: np.ndarray   # (len(index),), units of p₁
    std: np.ndarray     # (len(index),), > 0


@dataclass
class Problem:
    """The stacked channels of one data set, with fit/held-out row selection and weights."""

    channels: list[ChannelData]
    fit_rows: list[np.ndarray]       # per channel, bool (n_c,)
    holdout_rows: list[np.ndarray]   # per channel, bool (n_c,) (may refer to other channels)
    weights: np.ndarray              # per channel, 1/(σ_c √L)
    window_id: list[np.ndarray]      # per channel, int window index of each row
    #: Whether the base parameters are held by their prior (σ = PRIOR_STD_FACTOR·σ_model) or free: free
    #: where the model was identified on these very rows (:func:`.fit.solve`).
    base_prior: bool = True
    #: With free base parameters, those measured independently of these rows are held by that
    #: measurement (:func:`.fit.solve`); None: all free.
    measured: MeasuredBase | None = None
    #: Per channel, rows per independent row where it differs from :func:`channel_lag` (None: that lag);
    #: set by :func:`counted_by_own_correlation`.
    correlation: list[float | None] | None = None
    #: Whether the fit and held-out rows are the even and odd time windows of the same channels
    #: (:func:`make_problem` without a second run): then the two can swap roles (:func:`swapped`).
    alternate: bool = False

    def correlation_rows(self, i: int, lag: int) -> float:
        """Rows of channel ``i`` that count as one independent row (weights and n/L of the F test)."""
        if self.correlation is not None and self.correlation[i] is not None:
            return self.correlation[i]
        return channel_lag(self.channels[i], lag)


def integrated_correlation_rows(residual: np.ndarray, window_factor: float = 5.0) -> float:
    """Integrated autocorrelation time τ = 1 + 2·Σ_{k=1}^{M} ρ_k of a residual series, in rows (≥ 1),
    the window M chosen by Sokal's rule (the smallest M ≥ ``window_factor``·τ(M)): n/τ of its n rows
    are independent for the variance of a mean or a least-squares coefficient (the Bartlett/Newey–West
    long-run variance with a data-chosen bandwidth).

    Args:
        residual: (n,) rows in time order.
    Returns:
        τ in rows; 1.0 for fewer than 10 rows or a constant series.
    """
    x = np.asarray(residual, dtype=float)
    x = x - x.mean()
    n = len(x)
    if n < 10 or not np.any(x):
        return 1.0
    spectrum = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    acf = acf / acf[0]
    tau = 1.0 + 2.0 * np.cumsum(acf[1:])
    enough = np.arange(1, n) >= window_factor * tau
    return float(max(tau[np.argmax(enough)] if enough.any() else tau[-1], 1.0))


def own_correlation_rows(ch: ChannelData, lag: int, explained: np.ndarray | None = None) -> float:
    """Rows over which the channel's own residual (every fitted row, in time order) stays correlated:
    :func:`integrated_correlation_rows`, at least :func:`channel_lag`.

    Args:
        explained: (n, m) columns of the channel whose least-squares fit is taken out of the residual
            first (the extension under test: the correlation of what it leaves, as a heteroscedasticity-
            and-autocorrelation-consistent variance takes it from the extended model's residual). The
            base columns are not: the fit holds them by their prior, and taken out freely they would
            take a wander the fit leaves.
    """
    r = ch.residual[ch.fitted]
    if explained is not None and explained.shape[1]:
        X = explained[ch.fitted]
        coef, *_ = np.linalg.lstsq(X, r, rcond=None)
        r = r - X @ coef
    return max(float(channel_lag(ch, lag)), integrated_correlation_rows(r))


def counted_by_own_correlation(problem: Problem, name: str, rows: float, lag: int) -> Problem:
    """The same problem with channel ``name`` counted by ``rows`` per independent row instead of its
    :func:`channel_lag`: its weight scaled by √(L/rows) and its n/L in the F test by L/rows (a channel
    ``problem`` does not hold is left alone)."""
    weights = problem.weights.copy()
    correlation = list(problem.correlation or [None] * len(problem.channels))
    for i, ch in enumerate(problem.channels):
        if ch.name == name:
            weights[i] *= math.sqrt(problem.correlation_rows(i, lag) / rows)
            correlation[i] = rows
    return replace(problem, weights=weights, correlation=correlation)


def window_index(time: np.ndarray, window: float = WINDOW) -> np.ndarray:
    return np.floor(np.asarray(time) / window).astype(int)


def channel_lag(ch: ChannelData, lag: int) -> int:
    """Rows over which the channel's residual stays correlated."""
    if ch.kind != "torque":
        return max(lag, int(round(KINEMATIC_CORRELATION / ch.context.st.cycle_time)))
    return lag


def make_problem(channels: list[ChannelData], lag: int, holdout: list[ChannelData] | None = None,
                 window: float = WINDOW, base_prior: bool = True,
                 measured: MeasuredBase | None = None,
                 weights_of: dict[str, float] | None = None) -> tuple[Problem, Problem]:
    """The fitting problem and the held-out problem.

    Without ``holdout`` the rows of even time windows are fitted and odd ones held out; with it every
    row of ``channels`` is fitted and ``holdout`` is evaluated. A channel whose rows are only held out
    (:attr:`ChannelData.held_out_only`, the lifted run's) has no fit rows; its odd windows are held out
    (and its even ones in the other fold, :func:`swapped`). ``base_prior``, ``measured``:
    :attr:`Problem.base_prior`, :attr:`Problem.measured`. A channel is weighted by 1/(σ_c √L_c), σ_c the
    RMS of its residual on the fit rows, unless ``weights_of`` (channel name → weight) gives its weight:
    a paired reference run's channels have no residual of their own and take the data's weights.
    """
    weights = []
    fit_rows, hold_rows, wins = [], [], []
    for ch in channels:
        w = window_index(ch.time, window)
        wins.append(w)
        fitted = np.zeros_like(ch.fitted) if ch.held_out_only else ch.fitted
        if holdout is None:
            fit_rows.append(fitted & (w % 2 == 0))
            hold_rows.append(ch.fitted & (w % 2 == 1))
        else:
            fit_rows.append(fitted.copy())
        # a channel never fitted is weighted by the residual of all its rows
        sel = ch.fitted if ch.held_out_only else fit_rows[-1]
        if weights_of is not None and ch.name in weights_of:
            weights.append(weights_of[ch.name])
            continue
        r = ch.residual[sel]
        if ch.nuisance.shape[1] and sel.any():   # the noise scale is what the nuisance terms leave
            coef, *_ = np.linalg.lstsq(ch.nuisance[sel], r, rcond=None)
            r = r - ch.nuisance[sel] @ coef
        sigma = float(np.sqrt(np.mean(r ** 2))) if sel.any() else 1.0
        weights.append(1.0 / (max(sigma, 1e-15) * math.sqrt(channel_lag(ch, lag))))
    weights = np.array(weights)
    fit = Problem(channels, fit_rows, [np.zeros_like(f) for f in fit_rows], weights, wins, base_prior, measured,
                  alternate=holdout is None)
    if holdout is None:
        return fit, Problem(channels, hold_rows, hold_rows, weights, wins, base_prior, measured, alternate=True)
    by_name = {c.name: i for i, c in enumerate(channels)}
    h_weights = np.array([weights[by_name[c.name]] if c.name in by_name else 0.0 for c in holdout])
    h_rows = [c.fitted.copy() for c in holdout]   # (a held-out-only channel of the held-out run: all its rows)
    return fit, Problem(holdout, h_rows, h_rows, h_weights, [window_index(c.time, window) for c in holdout],
                        base_prior, measured)


def restrict(problem: Problem, keep) -> Problem:
    """The same problem on the channels for which ``keep(channel)`` is true."""
    idx = [i for i, ch in enumerate(problem.channels) if keep(ch)]
    return Problem([problem.channels[i] for i in idx], [problem.fit_rows[i] for i in idx],
                   [problem.holdout_rows[i] for i in idx], problem.weights[idx],
                   [problem.window_id[i] for i in idx], problem.base_prior, problem.measured,
                   None if problem.correlation is None else [problem.correlation[i] for i in idx],
                   problem.alternate)


def swapped(fit_problem: Problem, hold_problem: Problem) -> tuple[Problem, Problem] | None:
    """The other fold of an alternate-window split: the held-out windows fitted and the fitted ones held
    out, with the same channels, weights and row counting (cross-fitting: every window is held out
    once). None where the two problems are not such a split (a second run holds the held-out rows). A
    held-out-only channel (:attr:`ChannelData.held_out_only`) stays unfitted: the other fold holds out its
    other windows.

    Raises:
        ValueError: the problems are an alternate split of different channels."""
    if not (fit_problem.alternate and hold_problem.alternate):
        return None
    if [c.name for c in fit_problem.channels] != [c.name for c in hold_problem.channels]:
        raise ValueError("an alternate-window split holds the same channels in its fit and held-out problems")
    channels = fit_problem.channels
    fit_b = replace(fit_problem, fit_rows=[np.zeros_like(r) if c.held_out_only else r
                                           for c, r in zip(channels, hold_problem.holdout_rows)],
                    holdout_rows=[np.zeros_like(r) for r in hold_problem.holdout_rows])
    other = [c.fitted & ~h if c.held_out_only else f
             for c, f, h in zip(channels, fit_problem.fit_rows, hold_problem.holdout_rows)]
    hold_b = replace(hold_problem, fit_rows=other, holdout_rows=other)
    return fit_b, hold_b


@dataclass
class Fit:
    """Solution of one (base or extended) problem."""

    hypothesis: Hypothesis | None
    nonlinear: object
    theta: np.ndarray               # effect coefficients (q,)
    theta_cov: np.ndarray           # (q, q)
    delta_p: np.ndarray             # (10,)
    offsets: dict                   # kinematic channel name → nuisance coefficients
    rss: float                      # weighted, fit rows, including the prior term
    n_eff: float
    n_params: int
    theta0: np.ndarray | None = None  # the reference run's level of the hypothesis, part of the base


def cached_columns(h: Hypothesis, nonlinear, ch: ChannelData, cache: dict | None) -> np.ndarray | None:
    """``h``'s columns on ``ch`` (:func:`.hypotheses.base.columns_on`), computed once per (hypothesis,
    non-linear value, channel) in ``cache``."""
    if cache is None:
        return columns_on(h, ch, nonlinear)
    key = (h.label, nonlinear, id(ch))
    if key not in cache:
        cache[key] = columns_on(h, ch, nonlinear)
    return cache[key]
