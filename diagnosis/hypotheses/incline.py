"""Incline: gravity along the floor's slope, m_ch·g along world x and y in the chassis frame."""
from __future__ import annotations

import math

import numpy as np

from scipy import stats

from qomni.conventions import GRAVITY

from ..channels import ChannelData
from .base import Z_95, Hypothesis, Magnitude, RuleRows, _project, _torque_only


@_torque_only
def _incline_columns(ch: ChannelData, _):
    ctx = ch.context
    gamma = ctx.pose[:, 2]
    m_g = ctx.p[6] * GRAVITY
    Qx = np.zeros((len(gamma), 9))
    Qy = np.zeros((len(gamma), 9))
    # World x and y unit vectors in the chassis frame (the downhill force's direction is fitted).
    Qx[:, 0], Qx[:, 1] = np.cos(gamma), -np.sin(gamma)
    Qy[:, 0], Qy[:, 1] = np.sin(gamma), np.cos(gamma)
    return m_g * np.column_stack([_project(ch, Qx), _project(ch, Qy)])


def _incline_magnitude(theta, cov, nonlinear, sheet):
    s = float(np.hypot(theta[0], theta[1]))
    grad = np.array(theta[:2]) / max(s, 1e-12)
    std = float(np.sqrt(max(grad @ cov[:2, :2] @ grad, 0.0)))
    lo, hi = min(max(s - Z_95 * std, 0.0), 1.0), min(s + Z_95 * std, 1.0)
    return Magnitude(math.asin(min(s, 1.0)), (math.asin(lo), math.asin(hi)), "rad", "floor inclination")


#: sin of 1 mrad (0.06°): a slope within an ordinary industrial floor's flatness tolerance (1–3 mm per m)
#: is no incline to report, however well a long campaign determines it.
RELEVANT = math.sin(1e-3)


def _principal(theta: np.ndarray, cov: np.ndarray, k: int) -> tuple[float, float, float]:
    """The slope's component along the eigenvector ``k`` of ``cov`` (2×2, eigenvalues ascending): (component,
    its σ, that direction's angle in the world frame [rad])."""
    w, v = np.linalg.eigh(np.asarray(cov, dtype=float)[:2, :2])
    u = v[:, k]
    component = float(u @ np.asarray(theta, dtype=float)[:2])
    return component, float(np.sqrt(max(w[k], 0.0))), float(np.arctan2(u[1], u[0]))


def along_motion(theta: np.ndarray, cov: np.ndarray) -> tuple[float, float, float]:
    """The fitted slope (sin_x, sin_y) along the direction the data determine best: (component, its σ,
    that direction's angle in the world frame [rad]). The direction is the eigenvector of the smallest
    variance of ``cov`` (2×2): the one along which the slope's force does work in the campaign's motion."""
    return _principal(theta, cov, 0)


def across_motion(theta: np.ndarray, cov: np.ndarray) -> tuple[float, float, float]:
    """The fitted slope (sin_x, sin_y) across the best-observed direction: (component, its σ, that
    direction's angle in the world frame [rad]), the eigenvector of the largest variance of ``cov`` (2×2)."""
    return _principal(theta, cov, 1)


def _z_test(value: float, std: float) -> float:
    """Two-sided p of ``value`` against 0 with standard deviation ``std``."""
    return float(2 * stats.norm.sf(abs(value / std))) if std > 0 else (0.0 if value else 1.0)


def confirm_along_motion(candidates: list, rows: RuleRows) -> None:
    """The incline's rule (``Hypothesis.resolve``): a slope is named by a component the campaign determines,
    of relevant size, each tested two-sided at the level of the presence test every named effect passes
    (:data:`qomni.diagnosis.fit.ALPHA`):

    * along the best-observed direction (the eigenvector of the smallest variance of the slope's 2×2
      covariance: the direction the campaign drives in);
    * or across it, where that component's own σ shows it determined and the incline removes more
      held-out residual than any other named candidate of the round.

    A slope does work only along the motion. The straight step and the lane change drive along one world
    direction, so there the force of a slope across it reaches the data only through the heading's wander
    (sin γ of a few mrad), and anything that yaws the chassis a little while it drives fits that column
    too; its across component's σ is then tens of mrad and its z test fails. The arcs yaw the chassis by
    up to 0.55 rad along their way, so a slope across the straight motion does work there, and the data
    determine it to a few milliradians or better. Within an arc an off-centre payload (its path inertia
    −2κ·s_y against the slope's force, which follows κ·x_ch) fits the same column: a payload reads as a
    slope of a few mrad across the motion and a slope as a payload. The one that removes more held-out residual
    is the one named first. A named slope gets a note with both components."""
    from ..fit import ALPHA           # the fitting machinery imports this package: import at use

    for c in candidates:
        if c.hypothesis.name != "incline" or not c.significant:
            continue
        theta, cov = c.fit.theta[-2:], np.asarray(c.fit.theta_cov)[-2:, -2:]
        along, std, angle = along_motion(theta, cov)
        across, across_std, across_angle = across_motion(theta, cov)
        p = _z_test(along, std)
        if p < ALPHA and abs(along) >= RELEVANT:
            c.notes.append(f"slope along the best-observed direction ({math.degrees(angle):.0f}° in the world "
                           f"frame): {along:.2e} ± {std:.1e} (sin of the angle); across it the data bound it to "
                           f"± {across_std:.1e}")
            continue
        p_across = _z_test(across, across_std)
        c.significant = False
        if p_across >= ALPHA or abs(across) < RELEVANT:
            c.notes.append(f"the slope along the best-observed direction ({math.degrees(angle):.0f}° in the "
                           f"world frame, where it does work) is {along:.2e} ± {std:.1e} (p = {p:.2g}): the "
                           "fitted slope lies across the motion, seen only through the heading's wander")
            continue
        across_note = (f"the slope across the best-observed direction ({math.degrees(across_angle):.0f}° in the "
                       f"world frame) is {across:.2e} ± {across_std:.1e} (p = {p_across:.2g}), along it "
                       f"{along:.2e} ± {std:.1e}")
        if all(c.evaluation.removed >= o.evaluation.removed for o in candidates
               if o is not c and o.significant and o.hypothesis.name != "incline"):
            c.significant = True
            c.notes.append(f"{across_note}: a slope across the straight motion, which the arcs' yaw makes do "
                           "work; it removes more held-out residual than any other candidate")
        else:
            c.notes.append(f"{across_note}, but another candidate removes more held-out residual (in the arcs "
                           "an off-centre payload fits the same column)")


INCLINE = Hypothesis("incline", "", ("sin_x", "sin_y"), _incline_columns, magnitude=_incline_magnitude,
                     relevant=RELEVANT, size=lambda t: float(np.hypot(t[0], t[1])), resolve=confirm_along_motion)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (INCLINE,)
