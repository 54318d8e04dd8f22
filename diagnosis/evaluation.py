"""Held-out evaluation of a fit: what it leaves per channel, the shrinkage against the base fit with a
window-bootstrap interval, and when held-out data confirm an effect (``Evaluation.confirms``)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .hypotheses.base import LIFTED_UNMODELLED, Hypothesis
from .problem import Fit, Problem, cached_columns

#: Smallest held-out shrinkage in the affected channel that counts as removing residual.
MIN_SHRINK = 0.10
MIN_SHRINK_MORE = 0.20
BOOTSTRAP = 400
#: Shrinkage below which a channel is untouched: float64 sums of squares over ≤ 10⁵ rows carry a relative
#: rounding error up to ~10⁵·2.2·10⁻¹⁶ ≈ 2·10⁻¹¹, so a fit that changes a channel's residual only by
#: rounding can show a "shrinkage" of 10⁻¹⁵ in every bootstrap replicate. Bounds of the shrinkage's
#: interval smaller than this are 0 (an interval above 0 means above rounding).
SHRINK_RESOLUTION = 1e-9


def predicted_residual(problem: Problem, i: int, fit: Fit, rows: np.ndarray,
                       cache: dict | None = None) -> np.ndarray:
    """What ``fit`` leaves of channel i's residual on ``rows``. Kinematic channels' nuisance terms
    (constant, chassis creep) are re-fitted on those rows."""
    ch = problem.channels[i]
    r = ch.residual[rows].copy()
    if ch.kind == "torque":
        r -= ch.base[rows] @ fit.delta_p
    if fit.hypothesis is not None and len(fit.theta):
        cols = cached_columns(fit.hypothesis, fit.nonlinear, ch, cache)
        if cols is not None:
            r -= cols[rows] @ fit.theta
    if ch.kind != "torque" and len(r):
        # The constant of integration and the chassis' creep are no property of the vehicle's effects:
        # projected out on the evaluated rows.
        N = ch.nuisance[rows]
        coef, *_ = np.linalg.lstsq(N, r, rcond=None)
        r -= N @ coef
    return r


def _describes_lifted(fit: Fit) -> bool:
    """Whether ``fit``'s effects are described on the lifted wheels, or absent there
    (:attr:`.hypotheses.base.Hypothesis.lifted`): else the lifted channel cannot compare it."""
    return fit.hypothesis is None or fit.hypothesis.lifted != LIFTED_UNMODELLED


def _held_out(folds, cache: dict | None) -> dict[str, tuple[float, np.ndarray, list[np.ndarray]]]:
    """Channel → (its weight, the windows of its held-out rows, what each fit leaves there), the folds'
    held-out rows concatenated. ``folds``: (held-out problem, fit, fit, …), every fold with as many fits.
    The lifted channel is left out where a fit holds an effect its columns do not describe there."""
    parts: dict[str, list] = {}
    for fold_problem, *fits in folds:
        for i, ch in enumerate(fold_problem.channels):
            rows = fold_problem.holdout_rows[i]
            if not rows.any() or (ch.context.lifted and not all(_describes_lifted(f) for f in fits)):
                continue
            entry = parts.setdefault(ch.name, [fold_problem.weights[i], [], [[] for _ in fits]])
            entry[1].append(fold_problem.window_id[i][rows])
            for left, fit in zip(entry[2], fits):
                left.append(predicted_residual(fold_problem, i, fit, rows, cache))
    return {name: (w, np.concatenate(wins), [np.concatenate(left) for left in lefts])
            for name, (w, wins, lefts) in parts.items()}


def holdout_rms(problem: Problem, fit: Fit, cache: dict | None = None,
                also: tuple[tuple[Problem, Fit], ...] = ()) -> dict[str, float]:
    """Channel → RMS of what ``fit`` leaves on the held-out rows, in the channel's unit. ``also``: further
    folds (held-out problem, its own fit), their held-out rows joined as in :func:`evaluate`."""
    return {name: float(np.sqrt(np.mean(left ** 2)))
            for name, (_, _, (left,)) in _held_out(((problem, fit), *also), cache).items()}


@dataclass
class ChannelShrink:
    name: str
    rms_before: float
    rms_after: float

    @property
    def shrink(self) -> float:
        return 1.0 - self.rms_after / self.rms_before if self.rms_before > 0 else 0.0

    @property
    def removed_rms(self) -> float:
        """RMS removed, in the channel's unit: √(before² − after²), 0 if nothing."""
        return math.sqrt(max(self.rms_before**2 - self.rms_after**2, 0.0))


@dataclass
class Evaluation:
    """Held-out comparison of the base fit and an extended fit."""

    channels: list[ChannelShrink]
    weighted_rss_before: float
    weighted_rss_after: float
    affected: str
    shrink_affected: float
    shrink_affected_ci: tuple[float, float]
    #: Σ over the channels of the share of each channel's held-out residual removed,
    #: 1 − RSS_after/RSS_before (a channel whose residual RMS the effect doubles counts −3): every channel
    #: one measurement, whatever its count of rows.
    removed_share: float = 0.0
    #: Window-bootstrap 95 % interval of :attr:`removed_share`: the held-out windows of each step
    #: resampled within that step (every campaign has its steps; all of a step's channels in a window
    #: together), so it asks whether the effect removes residual across the campaign's channels and
    #: windows, not in a few. ``None`` where not computed.
    removed_share_ci: tuple[float, float] | None = None
    #: Step → (its channels' shares removed, summed; the standard deviation of that sum over the window
    #: bootstrap, √n_w · the population standard deviation of its n_w held-out windows' shares): where
    #: :attr:`removed_share` and the width of its interval come from. A step whose sum is near 0 with a
    #: large deviation is one the effect does not act on whose residual the refitted parameters move.
    removed_share_by_step: dict[str, tuple[float, float]] | None = None

    def removed_share_by_step_json(self) -> dict:
        """:attr:`removed_share_by_step` as ``gap.json`` writes it: step → {"share", "sd"}; {} where not
        computed."""
        return {step: {"share": v, "sd": sd} for step, (v, sd) in (self.removed_share_by_step or {}).items()}

    @property
    def removed(self) -> float:
        """Weighted held-out residual removed (RSS units of the noise; the ranking score)."""
        return self.weighted_rss_before - self.weighted_rss_after

    def confirms(self, min_shrink: float) -> bool:
        """Whether the held-out data confirm the effect: it removes at least ``min_shrink`` of its
        affected channel's residual and adds none overall (weighted over every channel). An effect that
        shrinks one channel by making others worse fits the fitted windows' noise, not the vehicle."""
        return self.shrink_affected >= min_shrink and self.removed > 0


#: One fold of a held-out comparison: (held-out problem, fit before, fit after).
Fold = tuple[Problem, Fit, Fit]


def evaluate(problem: Problem, base: Fit, ext: Fit, cache: dict | None = None,
             rng: np.random.Generator | None = None, affected: str | None = None,
             also: tuple[Fold, ...] = ()) -> Evaluation:
    """Held-out residual before (``base``) and after (``ext``), per channel, with window-bootstrap 95 %
    intervals for the affected channel's shrinkage and for the shares of residual removed summed over
    every channel (:attr:`Evaluation.removed_share_ci`). ``affected``: that channel, when another
    evaluation of the same effect has chosen it (default: chosen here, see below). ``also``: further
    folds, each held-out problem with its own fits before and after, whose held-out windows are other
    windows of the same channels (cross-fitting, :func:`.problem.swapped`): their rows join the
    comparison as if held out by one fit, each window evaluated by the fits that did not see it."""
    rng = rng or np.random.default_rng(0)
    out = []
    per_window = {}
    gain = {}
    # step → held-out window → the shares of its channels' held-out residual removed there
    share_by_window: dict[str, dict[int, float]] = {}
    rss_b = rss_a = 0.0
    for name, (w, wins, (before, after)) in _held_out(((problem, base, ext), *also), cache).items():
        channel_b, channel_a = float(np.sum((w * before) ** 2)), float(np.sum((w * after) ** 2))
        rss_b += channel_b
        rss_a += channel_a
        out.append(ChannelShrink(name, float(np.sqrt(np.mean(before**2))), float(np.sqrt(np.mean(after**2)))))
        per_window[name] = (wins, before, after)
        gain[name] = w ** 2 * len(before)
        if channel_b <= 0:
            continue
        of_step = share_by_window.setdefault(name.split("/")[0], {})   # channels: "<step>/<quantity>"
        ids, of_row = np.unique(wins, return_inverse=True)
        gained = np.bincount(of_row, weights=((w * before) ** 2 - (w * after) ** 2) / channel_b,
                             minlength=len(ids))
        for k, g in zip(ids, gained):
            of_step[int(k)] = of_step.get(int(k), 0.0) + float(g)
    if not out:
        return Evaluation([], 0.0, 0.0, "", 0.0, (0.0, 0.0))
    # The affected channel: of the channels holding at least a tenth of the removed (weighted) residual,
    # the one where the effect removes the largest fraction.
    removed = {c.name: gain[c.name] * (c.rms_before**2 - c.rms_after**2) for c in out}
    top = max(removed.values())
    # (when the effect removes nothing anywhere, every channel is a candidate)
    pool = [c for c in out if top > 0 and removed[c.name] >= 0.1 * top] or out
    affected = next((c for c in out if c.name == affected), None) or max(pool, key=lambda c: c.shrink)
    wins, before, after = per_window[affected.name]
    ids = np.unique(wins)
    sb = np.array([np.sum(before[wins == k] ** 2) for k in ids])
    sa = np.array([np.sum(after[wins == k] ** 2) for k in ids])
    boot = []
    for _ in range(BOOTSTRAP):
        pick = rng.integers(0, len(ids), len(ids))
        boot.append(1 - math.sqrt(sa[pick].sum() / max(sb[pick].sum(), 1e-300)))
    lo, hi = (np.percentile(boot, [2.5, 97.5]) if len(ids) > 1 else (affected.shrink, affected.shrink))
    lo, hi = (0.0 if abs(bound) < SHRINK_RESOLUTION else bound for bound in (lo, hi))
    # Stratified by step: every campaign has its steps, only their windows vary.
    replicates = np.zeros(BOOTSTRAP)
    for windows in share_by_window.values():
        gained = np.array(list(windows.values()))
        replicates += gained[rng.integers(0, len(gained), (BOOTSTRAP, len(gained)))].sum(axis=1)
    share_lo, share_hi = np.percentile(replicates, [2.5, 97.5])
    share = sum(sum(windows.values()) for windows in share_by_window.values())   # Σ_c 1 − RSS_a/RSS_b
    by_step = {step: (float(sum(windows.values())),
                      float(math.sqrt(len(windows)) * np.std(list(windows.values()))))
               for step, windows in share_by_window.items()}
    return Evaluation(out, rss_b, rss_a, affected.name, affected.shrink, (float(lo), float(hi)),
                      share, (float(share_lo), float(share_hi)), by_step)


def on_model(h: Hypothesis | None, nonlinear, theta: np.ndarray, n_base: int) -> Fit:
    """The model as identified plus effect ``h`` at coefficients ``theta`` (q,), its base parameters
    unchanged (δp = 0, ``n_base`` entries): what adding the effect to the model predicts. Only for
    :func:`evaluate` and :func:`predicted_residual` (no RSS, no covariance)."""
    theta = np.asarray(theta, dtype=float)
    return Fit(h, nonlinear, theta, np.zeros((len(theta), len(theta))), np.zeros(n_base), {}, 0.0, 0.0, 0)


def added_to_identified(problem: Problem, ext: Fit, tail: int, affected: str,
                        cache: dict | None = None, also: tuple[tuple[Problem, Fit], ...] = ()) -> Evaluation:
    """Held-out residual of the model as identified (with the already accepted effects, all but the last
    ``tail`` coefficients of ``ext``) before and after adding the effect at ``ext``'s fitted level, both
    with the base parameters as identified: gap.json's ``holdout_shrink``. Evaluated in the ``affected``
    channel of the comparison from the base fit. ``also``: further folds (held-out problem, that fold's
    ``ext``), as in :func:`evaluate`."""
    n = len(ext.delta_p)

    def before_after(fit: Fit) -> tuple[Fit, Fit]:
        before = fit.theta.copy()
        before[len(before) - tail:] = 0.0
        return (on_model(fit.hypothesis, fit.nonlinear, before, n),
                on_model(fit.hypothesis, fit.nonlinear, fit.theta, n))

    return evaluate(problem, *before_after(ext), cache, affected=affected,
                    also=tuple((p, *before_after(f)) for p, f in also))
