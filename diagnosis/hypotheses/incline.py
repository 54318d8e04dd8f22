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


def along_motion(theta: np.ndarray, cov: np.ndarray) -> tuple[float, float, float]:
    """The fitted slope (sin_x, sin_y) along the direction the data determine best: (component, its σ,
    that direction's angle in the world frame [rad]). The direction is the eigenvector of the smallest
    variance of ``cov`` (2×2): the one along which the slope's force does work in the campaign's motion."""
    w, v = np.linalg.eigh(np.asarray(cov, dtype=float)[:2, :2])
    u = v[:, 0]
    return float(u @ np.asarray(theta, dtype=float)[:2]), float(np.sqrt(max(w[0], 0.0))), float(np.arctan2(u[1], u[0]))


def _across_std(c) -> float:
    return float(np.sqrt(max(np.linalg.eigvalsh(np.asarray(c.fit.theta_cov, dtype=float)[-2:, -2:])[1], 0.0)))


def confirm_along_motion(candidates: list, rows: RuleRows) -> None:
    """The incline's rule (``Hypothesis.resolve``): a slope is named only where its component along the
    best-observed direction is there (two-sided z test at the level of the presence test every named
    effect passes, :data:`qomni.diagnosis.fit.ALPHA`) and of relevant size.

    A slope does work only along the motion; the campaign drives mostly along one world direction, so the
    force of a slope across it reaches the data only through the heading's wander (sin γ of a few mrad in
    straight driving). A fitted slope whose evidence lies across the motion is a residual that follows the
    heading (anything that yaws the chassis a little while it drives), not a floor: a real slope at
    least 25° off the lateral has a component along the motion of ≥ 0.42 of its size. A named slope gets
    a note with its component along that direction and the bound across it."""
    from ..fit import ALPHA           # the fitting machinery imports this package: import at use

    for c in candidates:
        if c.hypothesis.name != "incline" or not c.significant:
            continue
        along, std, angle = along_motion(c.fit.theta[-2:], np.asarray(c.fit.theta_cov)[-2:, -2:])
        z = along / std if std > 0 else math.inf
        p = float(2 * stats.norm.sf(abs(z)))
        if p < ALPHA and abs(along) >= RELEVANT:
            c.notes.append(f"slope along the best-observed direction ({math.degrees(angle):.0f}° in the world frame): "
                           f"{along:.2e} ± {std:.1e} (sin of the angle); across it the data bound it only to "
                           f"± {_across_std(c):.1e}")
            continue
        c.significant = False
        c.notes.append(f"the slope along the best-observed direction ({math.degrees(angle):.0f}° in the world "
                       f"frame, where it does work) is {along:.2e} ± {std:.1e} (p = {p:.2g}): the fitted "
                       "slope lies across the motion, seen only through the heading's wander")


INCLINE = Hypothesis("incline", "", ("sin_x", "sin_y"), _incline_columns, magnitude=_incline_magnitude,
                     relevant=RELEVANT, size=lambda t: float(np.hypot(t[0], t[1])), resolve=confirm_along_motion)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (INCLINE,)
