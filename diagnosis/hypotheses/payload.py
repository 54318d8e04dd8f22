"""Payload: an added mass with its centre off the chassis centre (columns Θ̂_{m_ch}, Θ̂_{C_ch}, first moments).

Against a model identified on the same data, m_ch and C_ch already hold the added mass and inertia
(their columns are the hypothesis' first two); what no parameter of (19) can hold is the centre of mass
off the chassis centre, so the hypothesis tested there is the first moments alone (``PAYLOAD_OFFSET``).
"""
from __future__ import annotations

import math

import numpy as np

from ..channels import ChannelData
from .base import Hypothesis, Magnitude, _linear_magnitude, _project, _torque_only, interval_95


@_torque_only
def _payload_columns(ch: ChannelData, _):
    st = ch.context.st
    v, a = st.qd[:, :3], st.qdd[:, :3]
    w, wd = v[:, 2], a[:, 2]
    # Generalized chassis force of a mass with centre (x_c, y_c) in the chassis frame, per unit
    # first moment s = m·(x_c, y_c), beyond the model's diag(m, m, C) (Newton-Euler, body frame).
    Qx = np.zeros((len(w), 9))
    Qx[:, 0], Qx[:, 1], Qx[:, 2] = -w**2, wd, a[:, 1] + w * v[:, 0]
    Qy = np.zeros((len(w), 9))
    Qy[:, 0], Qy[:, 1], Qy[:, 2] = -wd, -w**2, -(a[:, 0] - w * v[:, 1])
    mass, inertia = ch.base[:, 6], ch.base[:, 7]
    return np.column_stack([mass, inertia, _project(ch, Qx), _project(ch, Qy)])


def _offset_columns(ch: ChannelData, nonlinear):
    cols = _payload_columns(ch, nonlinear)
    return None if cols is None else cols[:, 2:]


def _first_moment(theta, cov, nonlinear, sheet) -> Magnitude:
    """|s| = |m·(x_c, y_c)| [kg m] with a delta-method 95 % interval (along the fitted direction; a size
    is not negative, so its lower end is at least 0)."""
    s = np.asarray(theta[:2], dtype=float)
    size = float(np.hypot(*s))
    direction = s / size if size > 0 else np.array([1.0, 0.0])
    sd = math.sqrt(max(float(direction @ np.asarray(cov)[:2, :2] @ direction), 0.0))
    low, high = interval_95(size, sd)
    return Magnitude(size, (max(low, 0.0), high), "kg m", "first moment of the mass off the chassis centre")


#: The payload against a model identified on the same data: the centre-of-mass offset's first moments
#: s = m·(x_c, y_c) [kg m] in the chassis frame; any direction is physical.
PAYLOAD_OFFSET = Hypothesis("payload", "", ("m_x_c", "m_y_c"), _offset_columns, magnitude=_first_moment)

PAYLOAD = Hypothesis(
    "payload", "", ("delta_m", "delta_C", "m_x_c", "m_y_c"), _payload_columns,
    magnitude=_linear_magnitude(0, "kg", "added mass"),
    physical=lambda t: t[0] > 0 and t[1] > -1e-9,
    absorbed_by=("m_ch", "C_ch"), free_base=PAYLOAD_OFFSET,
    folds_into={"m_ch": ("delta_m", lambda p, r: 1.0), "C_ch": ("delta_C", lambda p, r: 1.0)})

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (PAYLOAD,)
