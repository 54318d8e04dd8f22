"""Torque-constant error of one drive: −H_kᵀB e_j u_j.

With the base parameters free (a model identified on the same run) an equal change of all four torque
constants lies in the base span, so the drives differ only through their differences: a weaker drive
fl and a stronger rl load the left side's rows alike. The lifted vehicle tells them apart
(:func:`resolve_drive`): there each wheel is identified through its own drive, and a drive whose torque
is f times what it reports makes its wheel's B_w read 1/f of the others'.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from qomni.conventions import WHEELS

from ..channels import ChannelData
from .base import LIFTED_MODELLED, Hypothesis, RuleRows, _input_torque, _linear_magnitude, _project, _torque_only


def _variant(wheel: str) -> str:
    """The variant label of the hypothesis for ``wheel``'s drive."""
    return f"drive {wheel}"


def _torque_constant(j: int):
    @_torque_only
    def columns(ch: ChannelData, _):
        Bu = _input_torque(ch)
        Q = np.zeros_like(Bu)
        Q[:, 5 + j] = Bu[:, 5 + j]
        return -_project(ch, Q)[:, None]
    return columns


#: |z| of a wheel's lifted B_w against the other three's median beyond which that wheel is off (two-sided
#: 10⁻³). Identical wheels (the data sheet has one B_w) agree within their σ: |z| ≤ 1.29 in the 65 runs of
#: the twin suite's two draws without a torque-constant error; the 5 with one read z = 8.2–16.1 on the
#: faulty wheel (factors 1.08–1.13 and 0.875).
LIFTED_Z = 3.29


def lifted_inertia_ratio(wheels: dict, wheel: str) -> tuple[float, float]:
    """B_w of ``wheel`` over the median of the other wheels' lifted B_w, and its σ (first order, from the
    two wheels' σ).

    ``wheels``: :attr:`qomni.ident.rundir.LiftedMeasurement.wheels`. A torque-constant factor f on the
    wheel's drive makes this 1/f: the lifted run reads that wheel's torques as 1/f of what acts on it. The
    median keeps one faulty wheel out of the others' reference (with their mean, every wheel read off by a
    third of it)."""
    value, std = wheels[wheel]["B_w"]
    others = sorted(wheels[w]["B_w"] for w in wheels if w != wheel)
    median, median_std = others[len(others) // 2]
    ratio = value / median
    return ratio, ratio * math.hypot(std / value, median_std / median)


def lifted_factor(wheels: dict, wheel: str) -> tuple[float, float]:
    """The torque-constant factor − 1 of ``wheel``'s drive as the lifted run measures it, relative to the
    other drives (1/ratio − 1 of :func:`lifted_inertia_ratio`), and its σ (first order)."""
    ratio, std = lifted_inertia_ratio(wheels, wheel)
    return 1.0 / ratio - 1.0, std / ratio**2


def _fitted_factor(c) -> tuple[float, float]:
    """Candidate ``c``'s fitted factor − 1 and its variance from the fit's covariance: the variant's
    coefficient is its fit's last (alone, or after the accepted effects in forward selection)."""
    return float(c.fit.theta[-1]), float(c.fit.theta_cov[-1, -1])


def _lifted_contradicts(c, wheels: dict, wheel: str) -> str | None:
    """Why the lifted run rules out candidate ``c`` (drive ``wheel``'s variant), or None: its fitted
    factor − 1 (:func:`_fitted_factor`) and the lifted run's measure of it differ by |z| ≥ LIFTED_Z (σ of
    the fit from its covariance, of the lifted value from the two wheels' B_w)."""
    theta, variance_fit = _fitted_factor(c)
    sigma_fit = math.sqrt(variance_fit)
    lifted, sigma_lifted = lifted_factor(wheels, wheel)
    z = (theta - lifted) / math.hypot(sigma_fit, sigma_lifted)
    if abs(z) < LIFTED_Z:
        return None
    return (f"the lifted run measures drive {wheel}'s factor − 1 at {lifted:+.3f} ± {sigma_lifted:.3f} (its "
            f"wheel's B_w against the others'); the fitted {theta:+.3f} contradicts it (z = {z:.1f})")


def combined_factor(c, wheels: dict, wheel: str) -> tuple[float, float]:
    """Candidate ``c``'s drive factor − 1 (``wheel``'s variant) estimated from the fit on the ground and
    the lifted run together: the inverse-variance weighted mean of the fitted coefficient (σ from the fit's
    covariance) and :func:`lifted_factor`, and its σ. The two are independent measurements of one
    quantity; the lifted one sees the drive alone, the ground's fit sees it through everything the ground
    does as well. A fit without a variance (a degenerate covariance) is taken alone, σ 0."""
    theta, variance_fit = _fitted_factor(c)
    if not variance_fit > 0:
        return theta, 0.0
    weight_fit = 1.0 / variance_fit
    lifted, sigma_lifted = lifted_factor(wheels, wheel)
    weight_lifted = 1.0 / sigma_lifted**2
    total = weight_fit + weight_lifted
    return (weight_fit * theta + weight_lifted * lifted) / total, 1.0 / math.sqrt(total)


def _combined_not_named(c, wheels: dict, wheel: str, level: float) -> str | None:
    """Why the fit and the lifted run together do not name candidate ``c``, or None: their combined
    factor − 1 (:func:`combined_factor`) is not different from 0 at ``level`` (two-sided, normal), or
    smaller than RELEVANT_FACTOR."""
    value, sigma = combined_factor(c, wheels, wheel)
    p = float(2 * stats.norm.sf(abs(value) / sigma)) if sigma > 0 else float(value == 0.0)
    if p < level and abs(value) >= RELEVANT_FACTOR:
        return None
    return (f"the fit and the lifted run together measure drive {wheel}'s factor − 1 at {value:+.4f} ± "
            f"{sigma:.4f} (p = {p:.2g} against the level {level:.2g}; relevant from {RELEVANT_FACTOR:g}): "
            "not a fault of this drive")


def resolve_drive(candidates: list, rows: RuleRows) -> None:
    """The torque-constant variants' rule (``Hypothesis.resolve``), where the campaign has a lifted run:

    * a variant whose fitted factor the lifted run contradicts (:func:`_lifted_contradicts`) is not
      significant: lifted, each wheel is driven through its own drive alone, and a factor f reads as a
      B_w ratio 1/f there whatever the ground does (a steering compliance's scrub, fitted as drive rl at
      factor 0.19 while the lifted wheel rl read 1.00 of the others);
    * nor is one the two measurements together do not name (:func:`_combined_not_named`, at the round's
      level ``rows.level``): a load the ground puts on one wheel more than the payload hypothesis holds
      fits a drive's column at a factor the lifted run does not contradict for the fit's wide interval
      (drive rr at −0.103 ± 0.033 under a 345 kg payload over wheel rr, the lifted wheel at −0.007 ±
      0.025), while the two together measure −0.043 ± 0.020;
    * where the lifted run singles out one wheel (|z| of its B_w ratio ≥ LIFTED_Z, the other three below)
      and that drive's variant is significant with the sign the ratio implies (ratio < 1: a stronger drive,
      factor − 1 > 0), the other drives' variants are not named: the data on the wheels cannot rank them,
      the lifted run can.

    Without a lifted run nothing changes."""
    if not rows.lifted_wheels:
        return
    variants = {_variant(w): w for w in WHEELS}
    tce = {variants[c.hypothesis.variant]: c for c in candidates
           if c.hypothesis.name == "torque_constant_error" and c.hypothesis.variant in variants}
    if rows.level is None:
        from ..fit import ALPHA as level     # the first round's (fit imports this package)
    else:
        level = rows.level
    for w, c in tce.items():
        if not c.significant or w not in rows.lifted_wheels:
            continue
        why = _lifted_contradicts(c, rows.lifted_wheels, w) \
            or _combined_not_named(c, rows.lifted_wheels, w, level)
        if why is not None:
            c.significant = False
            c.notes.append(why)
    if not any(c.significant for c in tce.values()):
        return
    z = {}
    for w in rows.lifted_wheels:
        ratio, std = lifted_inertia_ratio(rows.lifted_wheels, w)
        z[w] = (ratio, (ratio - 1.0) / std)
    off = [w for w, (_, zw) in z.items() if abs(zw) >= LIFTED_Z]
    if len(off) != 1:
        return
    wheel = off[0]
    ratio, zw = z[wheel]
    chosen = tce.get(wheel)
    if chosen is None or not chosen.significant or (chosen.magnitude.value > 0) != (ratio < 1):
        return
    chosen.notes.append(f"the lifted run singles out wheel {wheel}: its B_w is {ratio:.3f} of the other "
                        f"wheels' (z = {zw:.1f}), as a torque-constant factor {1 / ratio:.3f} gives")
    for w, c in tce.items():
        if c is not chosen and c.significant:
            c.significant = False
            c.notes.append(f"the lifted run places the torque-constant error on drive {wheel} (its wheel's "
                           f"B_w ratio {ratio:.3f}, z = {zw:.1f}); this drive's wheel agrees with the others "
                           f"(z = {z[w][1]:.1f})")


#: 1 % of the torque constant: a permanent-magnet motor's torque constant falls with its magnets'
#: temperature (NdFeB about −0.1 %/K), so 10 K of warming in a campaign moves it by as much, and drive
#: makers specify it to ±5–10 %. A smaller difference between drives is no fault of one drive to report.
RELEVANT_FACTOR = 0.01

TORQUE_CONSTANT = tuple(
    Hypothesis("torque_constant_error", _variant(w), ("factor_minus_one",), _torque_constant(j),
               magnitude=_linear_magnitude(0, "-", f"torque-constant factor − 1 of drive {w}"),
               relevant=RELEVANT_FACTOR, resolve=resolve_drive, lifted=LIFTED_MODELLED)
    for j, w in enumerate(WHEELS))

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (*TORQUE_CONSTANT,)
