"""Rolling resistance: (m_ch g r / 4)·tanh(β̇_i/ε) per wheel."""
from __future__ import annotations

import numpy as np

from qomni.conventions import EPSILON as EPS_SIGN, GRAVITY

from ..channels import ChannelData
from .base import Hypothesis, _linear_magnitude, _project, _torque_only


@_torque_only
def _rolling_columns(ch: ChannelData, _):
    st, sheet = ch.context.st, ch.context.sheet
    load = ch.context.p[6] * GRAVITY / 4
    Q = np.zeros((len(st.time), 9))
    Q[:, 5:9] = load * sheet.geometry.r * np.tanh(st.qd_coulomb[:, 5:9] / EPS_SIGN)
    return _project(ch, Q, smooth=True)[:, None]


#: c_rr below 0.003 (a sixth of the wheel's own Coulomb friction as an equivalent c_rr) is within what
#: a small error of another effect (e.g. the wheel radius' lever on d_cw) shifts; tyres on floors have
#: 0.005–0.02.
ROLLING_RESISTANCE = Hypothesis(
    "rolling_resistance", "", ("c_rr",), _rolling_columns,
    magnitude=_linear_magnitude(0, "-", "rolling-resistance coefficient"),
    physical=lambda t: t[0] > 0, absorbed_by=("d_cw",), relevant=0.003,
    folds_into={"d_cw": ("c_rr", lambda p, r: p[6] * GRAVITY * r / 4)})

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (ROLLING_RESISTANCE,)
