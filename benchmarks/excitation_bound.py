"""How low a steering step's viscous/Coulomb pair can bring cond(Θ̂₁ᵀΘ̂₁) within the campaign's limits.

    python benchmarks/excitation_bound.py [--quick]

The smallest singular values of the campaign's column-normalised stack belong to the viscous/Coulomb
pairs (docs/identification.md, "What bounds cond"). For one steering step the pair's regressor is
[α̈, α̇, sign α̇] over the rows the estimator keeps (|α̇| ≥ 0.2 rad/s). This minimises its condition
number (of the Gram matrix, as cond(Θ̂₁ᵀΘ̂₁)) directly over the coefficients of one rest-to-rest
Fourier period, scaled to the campaign's limits (|α| ≤ alpha_max, |α̇| ≤ alpha_dot_max,
|α̈| ≤ alpha_ddot_max of ``CampaignSettings()``), with a penalty on the rows lost below the threshold,
by Powell from fixed random starts (deterministic). Baseline: the same figure of the default campaign's
``steer_left`` step, planned in the same run. Planned trajectories are the best case: measured
velocities add tracking error and filtering.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy import linalg, optimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))                 # this checkout's qomni, not an installed one

from qomni.datasheet import DataSheet  # noqa: E402
from qomni.ident.campaign import CampaignSettings, plan  # noqa: E402
from qomni.ident.fourier import FourierTrajectory, _basis, _richness_cond  # noqa: E402
from qomni.ident.regressor_rows import VELOCITY_THRESHOLD  # noqa: E402


def pair_condition(qd: np.ndarray, qdd: np.ndarray, threshold: float) -> tuple[float, float]:
    """(cond of the Gram matrix of the column-normalised [q̈, q̇, sign q̇] over |q̇| ≥ threshold, share kept)."""
    keep = np.abs(qd) >= threshold
    if keep.sum() < 3:
        return math.inf, float(keep.mean())
    return _richness_cond(qd[keep], qdd[keep]) ** 2, float(keep.mean())


def best_period(n_h: int, period: float, limits: CampaignSettings, threshold: float, lost_weight: float,
                starts: int, evaluations: int) -> tuple[float, float]:
    """The lowest pair condition (and its share of kept rows) found for one Fourier period."""
    omega = 2 * math.pi / period
    t = np.linspace(0.0, period, 2000, endpoint=False)
    null = linalg.null_space(FourierTrajectory.rest_constraint_matrix(n_h))
    p, v, a = (m @ null for m in _basis(n_h, omega, t))

    def scaled(z):
        q, qd, qdd = p @ z, v @ z, a @ z
        s = min(limits.alpha_dot_max / np.abs(qd).max(), limits.alpha_ddot_max / np.abs(qdd).max(),
                limits.alpha_max / max(np.abs(q).max(), 1e-12))
        return s * qd, s * qdd

    def objective(z):
        cond, kept = pair_condition(*scaled(z), threshold)
        if not math.isfinite(cond) or kept < 0.3:
            return 10.0
        return math.log(cond) + lost_weight * (1.0 - kept)

    rng = np.random.default_rng(0)
    best = None
    for _ in range(starts):
        res = optimize.minimize(objective, null.T @ rng.standard_normal(2 * n_h), method="Powell",
                                options={"maxfev": evaluations, "xtol": 1e-4, "ftol": 1e-6})
        if best is None or res.fun < best.fun:
            best = res
    return pair_condition(*scaled(best.x), threshold)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="one period length, 2 starts")
    args = parser.parse_args(argv)
    settings = CampaignSettings()
    threshold = VELOCITY_THRESHOLD["alpha_l"]
    steer = next(s for s in plan(DataSheet.load(), settings) if s.name == "steer_left")
    t = steer.time()
    _, qd, qdd = steer.evaluate(t)["alpha_l"]
    base, base_kept = pair_condition(qd, qdd, threshold)
    print(f"limits: |alpha| <= {settings.alpha_max} rad, |alpha_dot| <= {settings.alpha_dot_max} rad/s, "
          f"|alpha_ddot| <= {settings.alpha_ddot_max} rad/s^2, rows kept above {threshold} rad/s")
    print(f"{'design':44s} {'pair cond':>9s} {'kept':>5s} {'ratio':>6s}")
    print(f"{'default steer_left (baseline)':44s} {base:9.2f} {base_kept:5.2f} {1.0:6.2f}")
    periods = [settings.steer_period] if args.quick else [settings.steer_period, settings.steer_duration]
    starts, evaluations = (2, 5000) if args.quick else (6, 20000)
    for period in periods:
        for n_h in (6, 8, 10):
            for weight in (1.0, 0.2):
                cond, kept = best_period(n_h, period, settings, threshold, weight, starts, evaluations)
                label = f"optimised, {period:g} s period, {n_h} harmonics, lost rows x{weight:g}"
                print(f"{label:44s} {cond:9.2f} {kept:5.2f} {cond / base:6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
