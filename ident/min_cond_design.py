"""Rest-to-rest Fourier excitation that minimises one viscous/Coulomb pair's condition number.

Why this criterion. The smallest singular values of the campaign's column-normalised stack Θ̂₁,w belong to
the three viscous/Coulomb pairs (d_vl, d_cl), (d_vr, d_cr), (d_vw, d_cw) (docs/identification.md,
"Optimised excitation"): over the rows the estimator keeps (|q̇| ≥ the stiction threshold) the two columns
of a pair are q̇ and ≈ sign q̇, whose cosine is ρ = mean|q̇| / rms(q̇), and the pair alone bounds
cond(Θ̂₁ᵀΘ̂₁) ≥ (1 + ρ)/(1 − ρ). A sinusoidal velocity has ρ = 0.90 (≥ 19). ρ is smallest when |q̇| spends
most rows just above the threshold and few at the velocity limit: with two levels q apart,
ρ ≥ 2√q/(1 + q), reached with the slow level held q/(1 + q) of the time — exactly the share that makes the
slow and the fast leg cover the same way, a sawtooth. So the design starts from a two-level "slow out, fast
back" velocity profile and minimises the pair's own criterion from there; a D-optimal criterion
(log det) would reward the velocity limit everywhere, i.e. a high ρ, and was not used.

The design (:func:`design_min_cond_trajectory`):

1. one base period of the step (:func:`base_period`: an integer number of them fill the step) holding a
   pause at rest (the rest conditions), a slow leg at ``slow_factor`` × the threshold, a reversal to the
   velocity limit, the fast leg, a reversal back, the slow leg again (:func:`two_level_velocity`); ramps
   at 80 % of the acceleration limit, but gentle below the threshold, so that |q̇| reaches it no sooner
   than :data:`REVERSAL_REACH`/ω_g after a reversal or a start from rest;
2. its least-squares projection onto the rest-constrained Fourier basis of ``n_harmonics`` harmonics;
3. Powell (scipy.optimize, deterministic) on the coefficients, minimising
   log cond(G) + ``lost_weight`` · (1 − kept) + :data:`REVERSAL_WEIGHT` · near, G the Gram matrix of the
   column-normalised [q̈, q̇, sign q̇] over the samples with |q̇| ≥ :data:`KEEP_FACTOR` · threshold after
   scaling the trajectory to the limits, ``kept`` their share, ``near`` the share of samples above the
   threshold within REVERSAL_REACH/ω_g of a reversal or a rest (:func:`near_reversal`). The Gram matrix
   is summed by ``numpy.einsum`` (no threaded BLAS), so the result does not depend on the number of BLAS
   threads;
4. scaled as far as the position, velocity and acceleration limits allow (× ``margin``).
5. With a cond cap (the chassis steps of a campaign, whose pairs have slack below the steering pairs'
   bound on the stack) the criterion changes: the most RMS acceleration (inertia information, and the
   torque rate the lag estimate needs) whose pair cond stays at or below the cap. Acceleration and a low ρ
   pull against each other: |q̈| comes from changing |q̇|, and every row on the way between the levels
   raises ρ. The profiles that spend it best hold the slow level on most rows and add short bursts to the
   velocity limit and back (:func:`burst_velocity`): few rows of high |q̇|, which is what the pair needs,
   and ramps at the acceleration limit. So the capped design projects a grid of start profiles (the
   two-level one and 1–3 bursts each way, over slow levels, peaks and ramp rates: :data:`START_BURSTS`
   and the three lists beside it) for :func:`base_period`'s number of base periods and up to
   :data:`MAX_EXTRA_PERIODS` more, takes the one of the least capped criterion
   −log(RMS q̈ / q̈_max) + :data:`CAP_WEIGHT` · max(0, log(cond/cap)) + the lost and near terms of step 3,
   and minimises that criterion from there with Powell.

The optimisation takes seconds per step; designs are memoised in-process and those of the full campaign
with the min_cond criterion are shipped in ``data/min_cond_designs.json`` (key: every design input and
:data:`DESIGN_VERSION`), so such a campaign with otherwise default settings never re-runs it.
``python -m qomni.ident.min_cond_design`` rewrites that file. All quantities SI (rad or m).
"""
from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np
from scipy import linalg, optimize

from . import filtering
from .fourier import FourierTrajectory, _basis, _limit_scale

__all__ = ["DESIGN_VERSION", "base_period", "burst_velocity", "design_min_cond_trajectory", "near_reversal",
           "pair_condition", "trajectory_pair_condition", "two_level_velocity"]

#: Bumped whenever the design procedure or its constants change, so that shipped designs of an older
#: procedure are not used.
DESIGN_VERSION = 2
SHIPPED_DESIGNS = Path(__file__).with_name("data") / "min_cond_designs.json"
#: Samples per second of the design grid (one base period).
GRID_RATE = 250.0
#: A row within REVERSAL_REACH/ω_g of a velocity reversal or a start from rest carries the stick-slip
#: transition that the zero-phase filter (time scale 1/ω_g) smears into it and tanh(v/ε) does not model; the
#: stiction threshold is meant to drop such rows (docs/identification.md). The design pays
#: REVERSAL_WEIGHT per share of the rows it keeps there, so it leaves reversals slowly.
REVERSAL_REACH = 3.0
#: The criterion counts the rows at |q̇| ≥ KEEP_FACTOR × the threshold as kept: the measured velocity of a
#: row planned just above the threshold may fall below it by the tracking error.
KEEP_FACTOR = 1.1
REVERSAL_WEIGHT = 10.0
#: With a cond cap, how many more base periods than :func:`base_period`'s the design tries.
MAX_EXTRA_PERIODS = 4
#: The capped design's start profiles: bursts per quarter period (0: the two-level profile), slow levels
#: (× ``slow_factor`` × the threshold), peaks (× the velocity limit), ramps (× the acceleration limit).
START_BURSTS = (1, 2, 3)
START_SLOW_SCALES = (1.0, 1.25, 1.6)
START_PEAKS = (0.6, 0.8, 1.0)
START_RAMPS = (0.8, 0.95)
#: The capped criterion's weight on log(cond/cap) above the cap: a 1 % excess costs as much as 20 % less
#: RMS acceleration, so the optimum sits at the cap within :data:`CAP_TOLERANCE`.
CAP_WEIGHT = 20.0
CAP_TOLERANCE = 0.01


def pair_condition(qd: np.ndarray, qdd: np.ndarray, threshold: float) -> tuple[float, float]:
    """cond of the Gram matrix of the column-normalised [q̈, q̇, sign q̇] over |q̇| ≥ ``threshold``.

    Args:
        qd, qdd: (N,) velocity and acceleration samples.
        threshold: the stiction threshold (unit of q per s).
    Returns:
        (condition number, share of the samples kept); ``inf`` where fewer than 3 samples are kept or a
        column vanishes.
    """
    keep = np.abs(qd) >= threshold
    kept = float(keep.mean()) if qd.size else 0.0
    if keep.sum() < 3:
        return math.inf, kept
    r = np.column_stack([qdd[keep], qd[keep], np.sign(qd[keep])])
    gram = np.einsum("ni,nj->ij", r, r)
    d = np.sqrt(np.diag(gram))
    if np.any(d == 0.0):
        return math.inf, kept
    ev = np.linalg.eigvalsh(gram / np.outer(d, d))
    return (float(ev[-1] / ev[0]) if ev[0] > 0 else math.inf), kept


def near_reversal(qd: np.ndarray, slow: float, reach: int) -> np.ndarray:
    """(N,) bool: samples of one period (periodic) within ``reach`` samples of a velocity reversal or a rest
    (|q̇| < 5 % of ``slow``, or a sign change)."""
    still = np.abs(qd) < 0.05 * slow
    flips = np.nonzero(np.sign(qd) != np.sign(np.roll(qd, 1)))[0]
    still[flips] = True
    if not still.any():
        return still
    idx = np.nonzero(still)[0]
    n = qd.size
    pos = np.arange(n)
    # periodic distance to the nearest reversal sample
    j = np.searchsorted(idx, pos) % idx.size
    d = np.minimum(np.abs(pos - idx[j]) % n, np.abs(pos - idx[j - 1]) % n)
    d = np.minimum(d, n - d)
    return d <= reach


def _ramp(v0: float, v1: float, accel: float, near: float, gentle: float) -> list[tuple[float, float, float]]:
    """(duration, v_start, v_end) segments of a velocity ramp from v0 to v1: at ``gentle`` while
    |q̇| < ``near``, else at ``accel``."""
    points = [v0] + [e for e in (-near, near) if min(v0, v1) < e < max(v0, v1)] + [v1]
    points.sort(reverse=v0 > v1)
    return [(abs(b - a) / (gentle if max(abs(a), abs(b)) <= near * (1 + 1e-12) else accel), a, b)
            for a, b in zip(points[:-1], points[1:])]


def two_level_velocity(t: np.ndarray, period: float, slow: float, fast: float, accel: float, near: float,
                       gentle: float, pause: float = 0.1) -> np.ndarray:
    """Velocity of the two-level start profile at ``t`` (one base period, (N,) → (N,)).

    Pause at rest, ramp to ``slow``, slow leg, reversal to −``fast`` (or the lower level that the slow legs'
    way can balance), fast leg, reversal to ``slow``, slow leg, ramp to rest, pause; the legs' lengths make
    the displacement over the period zero. Ramps run at ``accel``, but at ``gentle`` while |q̇| < ``near``
    (leaving rest or a reversal slowly, :data:`REVERSAL_REACH`).

    Raises: ValueError where the period is too short for the ramps and the slow legs.
    """
    def leave_rest(v: float) -> list[tuple[float, float, float]]:
        return _ramp(0.0, v, accel, near, gentle)

    def come_to_rest(v: float) -> list[tuple[float, float, float]]:
        return _ramp(v, 0.0, accel, near, gentle)

    def legs(f: float) -> tuple[list, float, float]:
        ramps = [leave_rest(slow), come_to_rest(slow), leave_rest(-f), come_to_rest(-f),
                 leave_rest(slow), come_to_rest(slow)]
        time_ = sum(d for r in ramps for d, _, _ in r)
        way = sum(d * (v0 + v1) / 2 for r in ramps for d, v0, v1 in r)
        free = period - 2 * pause - time_
        fast_leg = (slow * free + way) / (slow + f)
        return ramps, fast_leg, free - fast_leg

    lo, hi = near, fast
    if legs(hi)[1] < 0:          # the slow legs' way cannot balance a fast leg at ``fast``: lower it
        for _ in range(60):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if legs(mid)[1] >= 0 else (lo, mid)
        fast = lo
    ramps, fast_leg, slow_leg = legs(fast)
    if fast_leg < 0 or slow_leg <= 0:
        raise ValueError(f"a base period of {period:.3g} s cannot hold the ramps of the two levels")
    knots = ([(pause, 0.0, 0.0)] + ramps[0] + [(slow_leg / 2, slow, slow)] + ramps[1] + ramps[2]
             + [(fast_leg, -fast, -fast)] + ramps[3] + ramps[4] + [(slow_leg / 2, slow, slow)] + ramps[5]
             + [(pause, 0.0, 0.0)])
    edges = np.concatenate([[0.0], np.cumsum([k[0] for k in knots])])
    values = [k[1] for k in knots] + [0.0]
    return np.interp(np.mod(t, period), edges, values)


def burst_velocity(t: np.ndarray, period: float, slow: float, peak: float, accel: float, near: float,
                   gentle: float, bursts: int, pause: float = 0.1) -> np.ndarray:
    """Velocity of a burst start profile at ``t`` (one base period, (N,) → (N,)).

    Pause at rest, a quarter at −``slow``, a half at +``slow``, a quarter at −``slow``, back to rest, pause;
    the half holds ``bursts`` triangular bursts from the slow level to +``peak`` and back at ``accel``, the
    quarters ⌈bursts/2⌉ and ⌊bursts/2⌋ to −``peak``. The plateaus between them share the remaining time so that the
    period covers no way. Ramps through |q̇| < ``near`` run at ``gentle`` (:func:`two_level_velocity`).
    The slow level holds what the bursts leave of the period, as in the two-level profile, and the bursts
    add acceleration on few rows of high velocity, which is what keeps the pair's ρ = mean|q̇|/rms(q̇) low.

    Raises: ValueError where the period is too short for the ramps and bursts, or ``bursts`` < 1.
    """
    if bursts < 1:
        raise ValueError(f"bursts must be >= 1, got {bursts}")

    def ramp(v0: float, v1: float) -> list[tuple[float, float, float]]:
        return _ramp(v0, v1, accel, near, gentle)

    def burst(sign: float) -> list[tuple[float, float, float]]:
        return ramp(sign * slow, sign * peak) + ramp(sign * peak, sign * slow)

    # segments (duration, v_start, v_end); a slow plateau's duration (None) is set below by its sign
    groups = [(-1.0, (bursts + 1) // 2), (1.0, bursts), (-1.0, bursts // 2)]
    body = ramp(0.0, -slow)
    for i, (sign, n) in enumerate(groups):
        plateau = (None, sign * slow, sign * slow)
        for _ in range(n):
            body += [plateau] + burst(sign)
        body.append(plateau)
        if i + 1 < len(groups):
            body += ramp(sign * slow, -sign * slow)
    body += ramp(-slow, 0.0)
    ramps = [seg for seg in body if seg[0] is not None]
    free = period - 2 * pause - sum(d for d, _, _ in ramps)
    way = sum(d * (v0 + v1) / 2 for d, v0, v1 in ramps)
    n_minus = sum(1 for d, v, _ in body if d is None and v < 0)
    n_plus = sum(1 for d, v, _ in body if d is None and v > 0)
    # n_minus d_minus + n_plus d_plus = free and slow (n_plus d_plus − n_minus d_minus) + way = 0
    d_plus = (free - way / slow) / (2 * n_plus)
    d_minus = (free - n_plus * d_plus) / n_minus
    if free <= 0 or d_plus <= 0 or d_minus <= 0:
        raise ValueError(f"a base period of {period:.3g} s cannot hold {bursts} bursts each way")
    knots = ([(pause, 0.0, 0.0)]
             + [((d_plus if v > 0 else d_minus), v, v1) if d is None else (d, v, v1) for d, v, v1 in body]
             + [(pause, 0.0, 0.0)])
    edges = np.concatenate([[0.0], np.cumsum([k[0] for k in knots])])
    values = [k[1] for k in knots] + [0.0]
    return np.interp(np.mod(t, period), edges, values)


def trajectory_pair_condition(trajectory: FourierTrajectory, threshold: float,
                              cycle_time: float = 2e-3) -> float:
    """The pair cond (:func:`pair_condition`) of a designed trajectory sampled every ``cycle_time`` s."""
    _, qd, qdd = trajectory.evaluate(np.arange(0.0, trajectory.duration, cycle_time))
    return pair_condition(qd, qdd, threshold)[0]


def base_period(duration: float, q_range: float, slow: float, fast: float, accel: float) -> int:
    """Number of base periods in the step: as many as leave each one's slow legs room to sweep 90 % of
    the position range ``q_range`` (at least one)."""
    needed = 0.9 * q_range / slow + 2 * fast / accel + 0.5
    return max(1, int(duration // needed))


class _StepGrid:
    """One base period's design grid: the rest-constrained Fourier basis sampled at :data:`GRID_RATE`, the
    step's limits and the criterion's parts of a coefficient vector z (in the constraints' null space)."""

    def __init__(self, periods: int, duration: float, q_min: float, q_max: float, qd_max: float,
                 qdd_max: float, q_start: float, threshold: float, n_harmonics: int, slow: float):
        self.period = duration / periods
        self.omega = 2 * math.pi / self.period
        self.t = np.arange(int(round(self.period * GRID_RATE))) / GRID_RATE
        self.null = linalg.null_space(FourierTrajectory.rest_constraint_matrix(n_harmonics))
        self.p, self.v, self.a = (m @ self.null for m in _basis(n_harmonics, self.omega, self.t))
        self.limits = (q_max - q_start, q_start - q_min, qd_max, qdd_max)
        self.threshold, self.slow = threshold, slow
        reach_time = REVERSAL_REACH / filtering.OMEGA_G
        self.reach = int(math.ceil(reach_time * GRID_RATE))
        #: ramp rate through |q̇| < threshold: the threshold reached no sooner than reach_time after a
        #: reversal or a start from rest
        self.gentle = 0.9 * threshold / reach_time

    def project(self, velocity: np.ndarray) -> np.ndarray:
        """z whose velocity is the least-squares fit of ``velocity`` (sampled on ``t``)."""
        return np.linalg.lstsq(self.v, velocity, rcond=None)[0]

    def scale(self, z: np.ndarray) -> float:
        """The factor that scales z to the limits."""
        up, down, qd_max, qdd_max = self.limits
        return _limit_scale(self.p @ z, self.v @ z, self.a @ z, up, down, qd_max, qdd_max)

    def measures(self, z: np.ndarray) -> tuple[float, float, float, float]:
        """z scaled to the limits: (pair cond over the rows above KEEP_FACTOR × threshold, their share, the
        share of rows above the threshold near a reversal, RMS acceleration)."""
        s = self.scale(z)
        qd, qdd = s * (self.v @ z), s * (self.a @ z)
        cond, kept = pair_condition(qd, qdd, KEEP_FACTOR * self.threshold)
        near = near_reversal(qd, self.slow, self.reach) & (np.abs(qd) >= self.threshold)
        return cond, kept, float(near.mean()), float(np.sqrt(np.mean(qdd ** 2)))

    def coefficients(self, z: np.ndarray, margin: float) -> np.ndarray:
        """c = [a; b] of z scaled to ``margin`` × the limits."""
        return self.null @ (z * margin * self.scale(z))


def _design_periods(periods: int, duration: float, q_min: float, q_max: float, qd_max: float,
                    qdd_max: float, q_start: float, threshold: float, n_harmonics: int, slow_factor: float,
                    lost_weight: float, evaluations: int, margin: float) -> np.ndarray:
    """The uncapped design over ``periods`` base periods: its coefficients c = [a; b]. Raises ValueError
    where a base period cannot hold the two-level profile."""
    slow = slow_factor * threshold
    grid = _StepGrid(periods, duration, q_min, q_max, qd_max, qdd_max, q_start, threshold, n_harmonics, slow)
    z0 = grid.project(two_level_velocity(grid.t, grid.period, slow, qd_max, 0.8 * qdd_max, near=threshold,
                                         gentle=grid.gentle))

    def objective(z):
        cond, kept, near, _ = grid.measures(z)
        if not math.isfinite(cond):
            return 50.0
        return math.log(cond) + lost_weight * (1.0 - kept) + REVERSAL_WEIGHT * near

    res = optimize.minimize(objective, z0, method="Powell",
                            options={"maxfev": evaluations, "xtol": 1e-4, "ftol": 1e-7})
    return grid.coefficients(res.x if res.fun <= objective(z0) else z0, margin)


def _start_profiles(grid: _StepGrid, slow_factor: float, qd_max: float, qdd_max: float):
    """The capped design's start velocities on ``grid``: the two-level profile and :func:`burst_velocity`
    with 1–3 bursts, over slow levels, peaks and ramp accelerations (:data:`START_SLOW_SCALES`,
    :data:`START_PEAKS`, :data:`START_RAMPS`); those a base period cannot hold are left out."""
    threshold, gentle = grid.threshold, grid.gentle
    for scale in START_SLOW_SCALES:
        slow = scale * slow_factor * threshold
        for peak in START_PEAKS:
            for ramp in START_RAMPS:
                for bursts in (0,) + START_BURSTS:
                    try:
                        if bursts == 0:
                            yield two_level_velocity(grid.t, grid.period, slow, peak * qd_max, ramp * qdd_max,
                                                     near=threshold, gentle=gentle)
                        else:
                            yield burst_velocity(grid.t, grid.period, slow, peak * qd_max, ramp * qdd_max,
                                                 near=threshold, gentle=gentle, bursts=bursts)
                    except ValueError:
                        continue


def _design_capped(first_periods: int, duration: float, q_min: float, q_max: float, qd_max: float,
                   qdd_max: float, q_start: float, threshold: float, n_harmonics: int, slow_factor: float,
                   lost_weight: float, evaluations: int, margin: float, cond_cap: float
                   ) -> tuple[int, np.ndarray] | None:
    """The capped design (module docstring, step 5): (periods, coefficients c = [a; b]) of the most RMS
    acceleration whose pair cond stays within ``cond_cap`` (× 1 + :data:`CAP_TOLERANCE`); None where no
    start profile of any period count stays within it."""
    slow = slow_factor * threshold

    def criterion(cond: float, kept: float, near: float, accel: float) -> float:
        if not math.isfinite(cond) or accel <= 0:
            return 50.0
        return (-math.log(accel / qdd_max) + CAP_WEIGHT * max(0.0, math.log(cond / cond_cap))
                + lost_weight * (1.0 - kept) + REVERSAL_WEIGHT * near)

    def objective(z, grid):
        return criterion(*grid.measures(z))

    best = None                       # (objective, grid, z)
    feasible = None                   # (RMS acceleration, grid, z) of the best start within the cap
    for periods in range(first_periods, first_periods + MAX_EXTRA_PERIODS + 1):
        grid = _StepGrid(periods, duration, q_min, q_max, qd_max, qdd_max, q_start, threshold, n_harmonics,
                         slow)
        for start in _start_profiles(grid, slow_factor, qd_max, qdd_max):
            z = grid.project(start)
            measures = grid.measures(z)
            value = criterion(*measures)
            if best is None or value < best[0]:
                best = (value, grid, z)
            cond, _, _, accel = measures
            if cond <= cond_cap and (feasible is None or accel > feasible[0]):
                feasible = (accel, grid, z)
    if best is None:
        return None
    _, grid, z0 = best
    res = optimize.minimize(objective, z0, args=(grid,), method="Powell",
                            options={"maxfev": evaluations, "xtol": 1e-4, "ftol": 1e-7})
    for z in (res.x, z0):
        if grid.measures(z)[0] <= cond_cap * (1 + CAP_TOLERANCE):
            return int(round(duration / grid.period)), grid.coefficients(z, margin)
    if feasible is None:
        return None
    _, grid, z = feasible
    return int(round(duration / grid.period)), grid.coefficients(z, margin)


@functools.lru_cache(maxsize=64)
def _design(duration: float, q_min: float, q_max: float, qd_max: float, qdd_max: float, q_start: float,
            threshold: float, n_harmonics: int, slow_factor: float, lost_weight: float, evaluations: int,
            margin: float, cond_cap: float = 0.0) -> tuple[tuple[float, ...], tuple[float, ...], int, float]:
    args = (duration, q_min, q_max, qd_max, qdd_max, q_start, threshold, n_harmonics, slow_factor,
            lost_weight, evaluations, margin)
    periods = base_period(duration, q_max - q_min, slow_factor * threshold, qd_max, qdd_max)
    capped = _design_capped(periods, *args, cond_cap) if cond_cap > 0 else None
    if capped is not None:
        periods, c = capped
    else:
        c = _design_periods(periods, *args)
    return (tuple(c[:n_harmonics].tolist()), tuple(c[n_harmonics:].tolist()), periods,
            2 * math.pi * periods / duration)


def _key(**inputs) -> str:
    return json.dumps({"version": DESIGN_VERSION, **{k: float(v) for k, v in sorted(inputs.items())}},
                      sort_keys=True)


@functools.lru_cache(maxsize=1)
def _shipped() -> dict:
    """The shipped designs, checked: each entry's ``a`` and ``b`` equal-length lists of finite numbers,
    ``periods`` an integer ≥ 1, ``omega_f`` finite and > 0.

    Raises: ValueError naming the file and the key of a malformed entry (or the file, for bad JSON)."""
    if not SHIPPED_DESIGNS.exists():
        return {}
    try:
        designs = json.loads(SHIPPED_DESIGNS.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{SHIPPED_DESIGNS}: not readable JSON: {exc}") from exc
    if not isinstance(designs, dict):
        raise ValueError(f"{SHIPPED_DESIGNS}: expected an object of designs")
    for key, d in designs.items():
        try:
            a, b = (np.asarray(d[c], dtype=float) for c in ("a", "b"))
            ok = (a.ndim == 1 and a.shape == b.shape and a.size >= 4 and np.isfinite(a).all()
                  and np.isfinite(b).all() and isinstance(d["periods"], int) and d["periods"] >= 1
                  and math.isfinite(d["omega_f"]) and d["omega_f"] > 0)
        except (KeyError, TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f"{SHIPPED_DESIGNS}: design {key}: needs a, b (equal-length finite numbers), "
                             "an integer periods >= 1 and a finite omega_f > 0")
    return designs


def design_min_cond_trajectory(*, duration: float, q_min: float, q_max: float, qd_max: float,
                               qdd_max: float, threshold: float, q_start: float = 0.0, n_harmonics: int = 16,
                               slow_factor: float = 1.25, lost_weight: float = 1.0, evaluations: int = 6000,
                               margin: float = 0.995, cond_cap: float | None = None,
                               use_shipped: bool = True) -> FourierTrajectory:
    """A rest-to-rest Fourier trajectory minimising the viscous/Coulomb pair's condition number (module
    docstring), within |q − q_start| limits, |q̇| ≤ qd_max, |q̈| ≤ qdd_max, over ``duration``.

    Args:
        duration: step length (s), filled with an integer number of base periods (:func:`base_period`).
        q_min, q_max: position range; ``q_min < q_start < q_max``.
        qd_max, qdd_max: velocity and acceleration limits (> 0).
        threshold: the estimator's stiction threshold on q̇ (docs/identification.md); the design keeps its
            slow level at ``slow_factor`` × it, the margin for tracking error and filtering.
        n_harmonics: harmonics of the base period (≥ 4).
        slow_factor, lost_weight, evaluations, margin: design criterion and budget (module docstring).
        cond_cap: where given, the design with the largest RMS acceleration whose pair cond stays at or
            below the cap (within :data:`CAP_TOLERANCE`; module docstring, step 5), over
            :func:`base_period`'s number of base periods and up to :data:`MAX_EXTRA_PERIODS` more; where
            no start profile stays within it, the uncapped design. A campaign caps its chassis steps so
            that the planned stack stays within its cond target (``CampaignSettings.cond_target``).
        use_shipped: take a shipped design where every input matches.
    Returns:
        FourierTrajectory starting and ending at rest at ``q_start``.
    Raises:
        ValueError: inconsistent limits, or a step too short for the two-level profile.
    """
    if not (duration > 0 and qd_max > 0 and qdd_max > 0 and threshold > 0 and slow_factor >= 1):
        raise ValueError("duration, limits and threshold must be > 0 and slow_factor >= 1, got "
                         f"{duration}, {qd_max}, {qdd_max}, {threshold}, {slow_factor}")
    if not q_min < q_start < q_max:
        raise ValueError(f"need q_min < q_start < q_max, got {q_min}, {q_start}, {q_max}")
    if n_harmonics < 4:
        raise ValueError(f"n_harmonics must be >= 4, got {n_harmonics}")
    if slow_factor * threshold >= qd_max:
        raise ValueError(f"the velocity limit {qd_max} leaves no room above the threshold {threshold}")
    if cond_cap is not None and not (math.isfinite(cond_cap) and cond_cap > 1):
        raise ValueError(f"cond_cap must be a finite number > 1, got {cond_cap}")
    inputs = dict(duration=duration, q_min=q_min, q_max=q_max, qd_max=qd_max, qdd_max=qdd_max,
                  q_start=q_start, threshold=threshold, n_harmonics=n_harmonics, slow_factor=slow_factor,
                  lost_weight=lost_weight, evaluations=evaluations, margin=margin)
    if cond_cap is not None:
        inputs["cond_cap"] = cond_cap
    key = _key(**inputs)
    shipped = _shipped().get(key) if use_shipped and _recording is None else None
    if shipped is not None:
        a, b, periods, omega = shipped["a"], shipped["b"], shipped["periods"], shipped["omega_f"]
    else:
        a, b, periods, omega = _design(**{k: float(v) if k not in ("n_harmonics", "evaluations") else int(v)
                                          for k, v in inputs.items()})
        if _recording is not None:
            _recording[key] = {"a": list(a), "b": list(b), "periods": periods, "omega_f": omega}
    return FourierTrajectory.from_start(omega, np.array(a), np.array(b), q_start=q_start, periods=periods)


_recording: dict | None = None


def default_designs() -> dict:
    """The designs of the full campaign with the min_cond criterion and otherwise default settings,
    computed afresh: {key: entry}."""
    global _recording
    from qomni.datasheet import DataSheet

    from .campaign import CampaignSettings, plan
    _recording = {}
    try:
        plan(DataSheet.load(), CampaignSettings(excitation="min_cond"))
        return dict(sorted(_recording.items()))
    finally:
        _recording = None


def main() -> None:
    """Rewrite :data:`SHIPPED_DESIGNS` with :func:`default_designs` (atomically)."""
    from qomni.ident import min_cond_design   # the module the campaign uses, not this __main__ copy
    from qomni.ident.rundir import write_json

    write_json(SHIPPED_DESIGNS, min_cond_design.default_designs())
    min_cond_design._shipped.cache_clear()
    print(f"wrote {SHIPPED_DESIGNS}")


if __name__ == "__main__":
    main()
