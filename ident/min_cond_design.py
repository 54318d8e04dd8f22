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

__all__ = ["DESIGN_VERSION", "base_period", "design_min_cond_trajectory", "near_reversal", "pair_condition",
           "trajectory_pair_condition", "two_level_velocity"]

#: Bumped whenever the design procedure or its constants change, so that shipped designs of an older
#: procedure are not used.
DESIGN_VERSION = 1
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
        """(duration, v_start, v_end) segments from rest to ``v``."""
        if abs(v) <= near:
            return [(abs(v) / gentle, 0.0, v)]
        edge = math.copysign(near, v)
        return [(near / gentle, 0.0, edge), ((abs(v) - near) / accel, edge, v)]

    def come_to_rest(v: float) -> list[tuple[float, float, float]]:
        return [(d, v1, v0) for d, v0, v1 in reversed(leave_rest(v))]

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


def _design_periods(periods: int, duration: float, q_min: float, q_max: float, qd_max: float,
                    qdd_max: float, q_start: float, threshold: float, n_harmonics: int, slow_factor: float,
                    lost_weight: float, evaluations: int, margin: float) -> tuple[np.ndarray, float, float]:
    """The design over ``periods`` base periods: (coefficients c = [a; b], its pair cond at the threshold,
    its RMS acceleration). Raises ValueError where a base period cannot hold the two-level profile."""
    slow = slow_factor * threshold
    period = duration / periods
    omega = 2 * math.pi / period
    t = np.arange(int(round(period * GRID_RATE))) / GRID_RATE
    null = linalg.null_space(FourierTrajectory.rest_constraint_matrix(n_harmonics))
    p, v, a = (m @ null for m in _basis(n_harmonics, omega, t))
    reach_time = REVERSAL_REACH / filtering.OMEGA_G
    start = two_level_velocity(t, period, slow, qd_max, 0.8 * qdd_max, near=threshold,
                               gentle=0.9 * threshold / reach_time)
    z0 = np.linalg.lstsq(v, start, rcond=None)[0]
    q_low, q_high = q_start - q_min, q_max - q_start
    reach = int(math.ceil(reach_time * GRID_RATE))

    def scale(z) -> tuple[float, np.ndarray, np.ndarray]:
        """The factor that scales z to the limits, and the unscaled q̇, q̈."""
        qd, qdd = v @ z, a @ z
        return _limit_scale(p @ z, qd, qdd, q_high, q_low, qd_max, qdd_max), qd, qdd

    def objective(z):
        s, qd, qdd = scale(z)
        qd = s * qd
        cond, kept = pair_condition(qd, s * qdd, KEEP_FACTOR * threshold)
        if not math.isfinite(cond):
            return 50.0
        near = near_reversal(qd, slow, reach) & (np.abs(qd) >= threshold)
        return math.log(cond) + lost_weight * (1.0 - kept) + REVERSAL_WEIGHT * float(near.mean())

    res = optimize.minimize(objective, z0, method="Powell",
                            options={"maxfev": evaluations, "xtol": 1e-4, "ftol": 1e-7})
    z = res.x if res.fun <= objective(z0) else z0
    z = z * margin * scale(z)[0]
    cond = pair_condition(v @ z, a @ z, threshold)[0]
    return null @ z, cond, float(np.sqrt(np.mean((a @ z) ** 2)))


@functools.lru_cache(maxsize=64)
def _design(duration: float, q_min: float, q_max: float, qd_max: float, qdd_max: float, q_start: float,
            threshold: float, n_harmonics: int, slow_factor: float, lost_weight: float, evaluations: int,
            margin: float, cond_cap: float = 0.0) -> tuple[tuple[float, ...], tuple[float, ...], int, float]:
    args = (duration, q_min, q_max, qd_max, qdd_max, q_start, threshold, n_harmonics, slow_factor,
            lost_weight, evaluations, margin)
    periods = base_period(duration, q_max - q_min, slow_factor * threshold, qd_max, qdd_max)
    best = (periods, _design_periods(periods, *args))
    if cond_cap > 0:
        # the most acceleration (inertia information, torque rate for the lag) among the period counts
        # whose pair cond stays within the cap
        for more in range(periods + 1, periods + MAX_EXTRA_PERIODS + 1):
            try:
                candidate = _design_periods(more, *args)
            except ValueError:
                break
            if candidate[1] <= cond_cap and candidate[2] > best[1][2]:
                best = (more, candidate)
    periods, (c, _, _) = best
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
        cond_cap: where given, the step may hold more base periods than :func:`base_period`'s (up to
            :data:`MAX_EXTRA_PERIODS` more): the design with the largest RMS acceleration whose pair cond
            stays at or below the cap. A campaign caps the chassis steps at the steering steps' pair cond,
            which bounds the stack's, so the chassis steps spend their slack on inertia information.
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
