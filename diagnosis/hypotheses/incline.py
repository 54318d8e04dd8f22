"""Incline: gravity along the floor's slope, m_ch·g along world x and y in the chassis frame."""
from __future__ import annotations

import math

import numpy as np

from qomni.conventions import GRAVITY

from ..channels import ChannelData
from .base import Hypothesis, Magnitude, _project, _torque_only


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
    lo, hi = min(max(s - 1.96 * std, 0.0), 1.0), min(s + 1.96 * std, 1.0)
    return Magnitude(math.asin(min(s, 1.0)), (math.asin(lo), math.asin(hi)), "rad", "floor inclination")


#: sin of 1 mrad (0.06°): a slope within an ordinary industrial floor's flatness tolerance (1–3 mm per m)
#: is no incline to report, however well a long campaign determines it.
INCLINE = Hypothesis("incline", "", ("sin_x", "sin_y"), _incline_columns, magnitude=_incline_magnitude,
                     relevant=math.sin(1e-3), size=lambda t: float(np.hypot(t[0], t[1])))

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (INCLINE,)
