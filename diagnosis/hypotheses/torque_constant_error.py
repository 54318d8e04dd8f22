"""Torque-constant error of one drive: −H_kᵀB e_j u_j."""
from __future__ import annotations

import numpy as np

from qomni.conventions import WHEELS

from ..channels import ChannelData
from .base import Hypothesis, _input_torque, _linear_magnitude, _project, _torque_only


def _torque_constant(j: int):
    @_torque_only
    def columns(ch: ChannelData, _):
        Bu = _input_torque(ch)
        Q = np.zeros_like(Bu)
        Q[:, 5 + j] = Bu[:, 5 + j]
        return -_project(ch, Q)[:, None]
    return columns


TORQUE_CONSTANT = tuple(
    Hypothesis("torque_constant_error", f"drive {w}", ("factor_minus_one",), _torque_constant(j),
               magnitude=_linear_magnitude(0, "-", f"torque-constant factor − 1 of drive {w}"))
    for j, w in enumerate(WHEELS))

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (*TORQUE_CONSTANT,)
