"""Θ̂₁ of a planned campaign, before the vehicle moves: the rows (22) the four identification steps would
give if the vehicle followed its trajectories exactly, and their cond(Θ̂₁ᵀΘ̂₁) (paper section 7).

The measured figure (``condition_number`` in identification.json) adds tracking error, noise and the
zero-phase filter; on the default full campaign the two agree within a few per cent (docs/identification.md,
"Optimised excitation"). No vehicle, no data: the plan, the data sheet's geometry and the stiction thresholds.
"""
from __future__ import annotations

import numpy as np

from qomni.conventions import P1_NAMES, PARAMETER_NAMES
from qomni.datasheet import DataSheet

from . import dynamics
from .campaign import IDENTIFICATION_STEPS, CampaignSettings, plan
from .excitation import ExcitationStep
from .regressor import VELOCITY_THRESHOLD
from .regressor_rows import EXCITED, MODE_COORDINATES

def step_rows(step: ExcitationStep, sheet: DataSheet, cycle_time: float | None = None) -> np.ndarray:
    """Θ̂₁ rows (n_kept, 10) of one planned identification step: its excited coordinate's rows of (19) at the
    step's sampling instants, those with |ṡ| at or above the coordinate's stiction threshold.

    Raises: KeyError for a step that is not an identification step."""
    g = sheet.geometry
    t = step.time(cycle_time or sheet.drive.cycle_time)
    ref = step.evaluate(t)
    n = t.size
    coords = MODE_COORDINATES[step.mode]
    sd = np.column_stack([ref[c][1] if c in ref else np.zeros(n) for c in coords])
    sdd = np.column_stack([ref[c][2] if c in ref else np.zeros(n) for c in coords])
    q = np.zeros((n, 9))
    q[:, 3] = ref["alpha_l"][0] if "alpha_l" in ref else 0.0
    q[:, 4] = ref["alpha_r"][0] if "alpha_r" in ref else 0.0
    alpha_v = ref["alpha_v"][0] if step.mode == 2 else None
    qd, qdd = dynamics.generalized_state(step.mode, q, sd, sdd, g, alpha_v=alpha_v)
    theta = dynamics.reduced_regressor(step.mode, q, qd, qdd, g, alpha_v=alpha_v)
    (excited,) = EXCITED[step.name]
    j = coords.index(excited)
    keep = np.abs(sd[:, j]) >= VELOCITY_THRESHOLD[excited]
    cols = [PARAMETER_NAMES.index(p) for p in P1_NAMES]
    return theta[keep, j][:, cols]


def steps_condition(steps: list[ExcitationStep], sheet: DataSheet) -> float:
    """cond(Θ̂₁,wᵀΘ̂₁,w) of the identification steps among planned ``steps``, Θ̂₁,w column-normalised as in
    (25); ``inf`` where a column has no row."""
    theta = np.vstack([step_rows(s, sheet) for s in steps if s.name in IDENTIFICATION_STEPS])
    norms = np.linalg.norm(theta, axis=0)
    if not np.all(norms > 0):
        return float("inf")
    sv = np.linalg.svd(theta / norms, compute_uv=False)
    return float((sv[0] / sv[-1]) ** 2) if sv[-1] > 0 else float("inf")


def planned_condition(sheet: DataSheet, settings: CampaignSettings | None = None) -> float:
    """cond(Θ̂₁,wᵀΘ̂₁,w) of the campaign planned with ``settings`` (default: the full campaign's).

    Raises: ValueError where the plan cannot be made (:func:`plan`)."""
    return steps_condition(plan(sheet, settings or CampaignSettings()), sheet)


__all__ = ["planned_condition", "step_rows", "steps_condition"]
