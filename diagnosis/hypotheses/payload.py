"""Payload: an added mass with its centre off the chassis centre (columns Θ̂_{m_ch}, Θ̂_{C_ch}, first moments)."""
from __future__ import annotations

import numpy as np

from ..channels import ChannelData
from .base import Hypothesis, _linear_magnitude, _project, _torque_only


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


PAYLOAD = Hypothesis(
    "payload", "", ("delta_m", "delta_C", "m_x_c", "m_y_c"), _payload_columns,
    magnitude=_linear_magnitude(0, "kg", "added mass"),
    physical=lambda t: t[0] > 0 and t[1] > -1e-9,
    absorbed_by=("m_ch", "C_ch"),
    folds_into={"m_ch": ("delta_m", lambda p, r: 1.0), "C_ch": ("delta_C", lambda p, r: 1.0)})

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (PAYLOAD,)
