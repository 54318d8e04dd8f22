"""Steering compliance: the front/rear linkage deflects under the tyres' torques and toes the rear wheels."""
from __future__ import annotations

import numpy as np

from qomni.conventions import EPSILON as EPS_SIGN, FRONT_SIGN, GRAVITY, SIDE_INDEX
from qomni.ident import kinematics
from qomni.ident.regressor_rows import model_alpha

from ..channels import ChannelData
from .base import Hypothesis, _linear_magnitude, _project, _tyre_torque


#: low end of 0.8–1.0): the vehicle's data sheet has none.
SCRUB_FRICTION = 0.8


def _linkage_torque(H1: np.ndarray, wheel_torque: np.ndarray) -> np.ndarray:
    """(N, 2) torque each side's front/rear linkage carries, left then right, N m.

    A wheel torque w_i acts on its steering joint as (H₁)_{β_i}·w_i (virtual work, chassis at rest: a
    tyre force F at the offset a gives a·F). The linkage holds the two joints mirrored, so it carries
    half their difference — which makes them turn alike."""
    return np.column_stack([0.5 * (H1[:, 5 + f, s] * wheel_torque[:, f] - H1[:, 5 + r, s] * wheel_torque[:, r])
                            for s, (f, r) in enumerate(((0, 1), (2, 3)))])


def _compliance_kinematic(ch: ChannelData) -> np.ndarray:
    i = ch.index
    if FRONT_SIGN[i] > 0:
        return ch.rows(np.zeros(len(ch.context.st.time)))[:, None]
    ctx, side = ch.context, SIDE_INDEX[ch.index]
    # the rear joint deflects by the linkage torque / stiffness and its wheel rolls with it
    coupling = _linkage_torque(ctx.H, ctx.sheet.drive.i_G * ctx.st.motor_torque)[:, side]
    return ch.rows(ctx.H[:, 5 + i, side] * coupling * FRONT_SIGN[i])[:, None]


#: rad/s: a side's steering joints count as held (static friction engaged) below this filtered speed. A
#: held front unit still wanders with a soft linkage's deflection: up to 0.03 rad/s in straight driving and
#: rotation at 800 N m/rad (0.003 with a rigid one), far below the lane change's steering rates.
HELD_STEERING_SPEED = 0.05

#: Steps whose scrub drag gets a coefficient s_rot/k of its own. In the rotation the chassis turns about
#: its centre and the other wheels take up part of a rear wheel's toe: fitted with the true deflection
#: (an emulator run with the truth recorded, 800 N m/rad), its drag is 0.74 of the μN|δ| straight driving
#: and the lane change show (R² 0.89 against 0.92 and 0.98), where the toed wheel slides fully.
ROTATION_STEPS = ("rotation",)


def play(x: np.ndarray, width: np.ndarray) -> np.ndarray:
    """The play (backlash) operator: y follows x only where |x − y| exceeds ``width``, then at that
    distance; it starts at y = x[0]. (N,), (N,) → (N,), in x's unit; width 0 passes x through."""
    y = np.empty(len(x))
    current = float(x[0])
    for i, (v, w) in enumerate(zip(np.asarray(x, float), np.asarray(width, float))):
        current = min(max(current, v - w), v + w)
        y[i] = current
    return y


def _linkage_deflection(ctx) -> np.ndarray:
    """(N, 2) deflection k·δ of each side's linkage, left then right, N m (δ in rad per unit 1/k).

    Where the steering moves, the two joints' Coulomb friction acts mirrored and cancels in the linkage:
    k·δ = T, the torque :func:`_linkage_torque` of the tyres' longitudinal forces at the mode's angles.
    Where the side's steering is held, each joint's static friction takes up to d_c/2 of the torque
    before the linkage deflects further: k·δ follows T through a play of that width (d_cl, d_cr the
    model's)."""
    st, g, p = ctx.st, ctx.sheet.geometry, ctx.p
    H1 = kinematics.H(1, model_alpha(st, g), g)
    T = _linkage_torque(H1, _tyre_torque(ctx))
    out = np.empty_like(T)
    for side, d_c in ((0, p[2]), (1, p[5])):
        held = np.abs(st.qd[:, 3 + side]) <= HELD_STEERING_SPEED
        out[:, side] = play(T[:, side], np.where(held, abs(d_c) / 2, 0.0))
    return out


def _compliance_scrub(ch: ChannelData) -> np.ndarray:
    """Drag of the rear wheels toed by the linkage's deflection, as generalized force per unit 1/k.

    The linkage deflects by δ (:func:`_linkage_deflection`), which toes the rear wheel by δ away from
    the mirror of the measured front angle. A toed wheel slides sideways at |v|·δ under the lateral
    friction μN, and the component μN|δ| of that force along its travel is a drag."""
    ctx = ch.context
    st, g, p = ctx.st, ctx.sheet.geometry, ctx.p
    deflection = np.abs(_linkage_deflection(ctx))   # × 1/k, rad
    load = SCRUB_FRICTION * p[6] * GRAVITY / 4
    Q = np.zeros((len(st.time), 9))
    Q[:, [6, 8]] = load * g.r * deflection * np.tanh(st.qd_coulomb[:, [6, 8]] / EPS_SIGN)
    return _project(ch, Q, smooth=True)[:, None]


def _compliance_columns(ch: ChannelData, _):
    """Columns (1/k, s_rot/k): the rear wheels' rolling with the deflection (kinematic channels) and the
    scrub drag of driving straight and of the lane change carry 1/k; the rotation's scrub has its own
    coefficient (:data:`STEERING_COMPLIANCE`)."""
    if ch.kind == "kinematic":
        column = _compliance_kinematic(ch)
    elif ch.kind == "torque":
        column = _compliance_scrub(ch)
    else:
        return None
    zero = np.zeros_like(column)
    return np.hstack([zero, column] if ch.context.step in ROTATION_STEPS else [column, zero])


#: 1e-4 rad/(N m) (a linkage of 10 kN m/rad): the campaign's typical tyre forces (≈ 250 N, a·F ≈ 20 N m
#: on the linkage) then toe a rear wheel by < 2 mrad, within an ordinary wheel-alignment tolerance (±0.1°).
#: 1/k: the straight and lane-change drag and the kinematic channels; s_rot/k, 0 ≤ s_rot ≤ S_ROT_MAX:
#: the rotation's share of full sliding. More than full sliding is no scrub of this linkage; the bound
#: leaves room for the two deflection models' errors (fitted s_rot: 0.93–1.01 at 800 N m/rad on full
#: campaigns), not for the 4× 1/k of the drives fighting sticking steering joints.
S_ROT_MAX = 1.5
STEERING_COMPLIANCE = Hypothesis(
    "steering_compliance", "", ("compliance", "compliance_rotation"), _compliance_columns,
    magnitude=_linear_magnitude(0, "rad/(N m)", "front/rear coupling compliance 1/k "
                                f"(scrub taken at μ = {SCRUB_FRICTION})"),
    physical=lambda t: t[0] > 0 and 0 <= t[1] <= S_ROT_MAX * t[0], relevant=1e-4)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (STEERING_COMPLIANCE,)
