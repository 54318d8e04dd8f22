"""Steering compliance: the front/rear linkage deflects under the tyres' torques and toes the rear wheels,
which drag sideways and roll with the toe (the odometry reads that as chassis motion)."""
from __future__ import annotations

import weakref

import numpy as np

from qomni.conventions import EPSILON as EPS_SIGN, FRONT_SIGN, GRAVITY
from qomni.ident import dynamics, kinematics, odometry
from qomni.ident.regressor_rows import COULOMB_COLUMNS, model_alpha

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


#: Front wheel rows of H_k (the steering angles and the front wheels' rolling): where the linkage
#: deflects, these still obey the rigid model; the rear wheels' rows do not.
_FRONT_ROWS = [3, 4, 5, 7]
_REAR_WHEELS = [i for i in range(4) if FRONT_SIGN[i] < 0]


def _rear_toe_rolling(ctx) -> np.ndarray:
    """(N, 4) rolling of the rear wheels beyond what the steering and the front wheels give them through
    H_k, rad/s wheel side (front entries 0).

    A rear unit toed by the linkage turns about its steering axis, and its wheel, a beside that axis,
    rolls by a·δ̇/r while it does: the encoders see the deflection's rate. Zero in a step whose steering
    moves (:data:`HELD_STEERING_SPEED` exceeded by the median rate): there the 14-bit steering sensor's
    rate error times a/r is of the size of the toe's own rolling (a clean vehicle's lane change shows
    0.03 rad/s of it, its held steps ≤ 0.003)."""
    st, H = ctx.st, ctx.H
    n = len(st.time)
    out = np.zeros((n, 4))
    if np.median(np.abs(st.qd[:, 3:5])) > HELD_STEERING_SPEED:
        return out
    front = H[:, _FRONT_ROWS, :]
    gram = np.einsum("nki,nkj->nij", front, front)
    if np.linalg.matrix_rank(gram).min() < gram.shape[-1]:
        return out
    s_dot = np.linalg.solve(gram, np.einsum("nki,nk->ni", front, st.qd[:, _FRONT_ROWS])[..., None])[..., 0]
    expected = np.einsum("nik,nk->ni", H[:, 5:9, :], s_dot)
    out[:, _REAR_WHEELS] = st.qd[:, [5 + i for i in _REAR_WHEELS]] - expected[:, _REAR_WHEELS]
    return out


def _compliance_odometry(ch: ChannelData) -> np.ndarray:
    """The model's error from the chassis motion its odometry reads off toed rear wheels, N or N m.

    The recording's chassis velocity is the least-squares solution of all four wheels' rolling
    (``ident.odometry.chassis_velocity``): the rear wheels' toe rolling (:func:`_rear_toe_rolling`)
    passes into it as a velocity e (and its rate ė) the chassis does not have, and the model evaluated at
    the measured motion exceeds the one at the true motion by Θ(q, q̇, q̈)p − Θ(q, q̇ − e, q̈ − ė)p (inertia,
    viscous and velocity-product terms; the Coulomb columns, sign functions of rates far above e, are
    left out). Its coefficient is 1 where the toe explains the rolling."""
    ctx = ch.context
    st, g = ctx.st, ctx.sheet.geometry
    n = len(st.time)
    error = np.zeros((n, 9))
    error[:, :3] = odometry.chassis_velocity(st.q[:, 3:5], np.zeros((n, 2)), _rear_toe_rolling(ctx), g)
    if not error.any():
        return ch.rows(np.zeros(n))
    rate = np.gradient(error, st.cycle_time, axis=0, edge_order=2)
    alpha = model_alpha(st, g)
    q = st.q.copy()
    q[:, 3:5] = alpha
    alpha_v = kinematics.alpha_v_from_alpha(alpha, g) if st.k == 2 else None
    p = np.array(ctx.p, dtype=float)
    p[COULOMB_COLUMNS] = 0.0
    measured = dynamics.reduced_regressor(st.k, q, st.qd, st.qdd, g, alpha_v=alpha_v)[:, ch.index, :]
    true = dynamics.reduced_regressor(st.k, q, st.qd - error, st.qdd - rate, g, alpha_v=alpha_v)[:, ch.index, :]
    return ch.rows((true - measured) @ p)


def _raw_columns(ch: ChannelData) -> np.ndarray:
    """(n, 2) scrub drag per unit 1/k and odometry error of a torque channel, computed once per channel
    object (the profile asks for them at every s_rot of :data:`S_ROT_GRID`)."""
    raw = _RAW.get(ch)
    if raw is None:
        raw = _RAW[ch] = np.hstack([_compliance_scrub(ch), _compliance_odometry(ch)[:, None]])
    return raw


_RAW: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _compliance_columns(ch: ChannelData, s_rot):
    """Columns (1/k, c_odo) of the torque channels at the profiled s_rot: the scrub drag of driving
    straight, of the lane change and of the arcs carries 1/k, the rotation's carries s_rot/k; the
    odometry's error from the toe rolling (steps with held steering) carries c_odo, 1 for a toe that
    explains the rolling (:data:`STEERING_COMPLIANCE`).

    The steering steps' kinematic channels get no column: there each unit is driven by its own wheel and
    the linkage deflects by 0.1–0.5 mrad, which the linkage torque T/k does not predict (R² 0.01–0.03
    against the emulator's truth at 400 N m/rad); a column of it worsened their held-out residual (by 28 %
    on the rear right wheel) and pulled 1/k, and the two softest linkages of a full draw named a rolling
    resistance beside the compliance with it and none without."""
    if ch.kind != "torque":
        return None
    raw = _raw_columns(ch)
    share = float(s_rot) if ch.context.step in ROTATION_STEPS else 1.0
    return np.column_stack([share * raw[:, 0], raw[:, 1]])


#: 1e-4 rad/(N m) (a linkage of 10 kN m/rad): the campaign's typical tyre forces (≈ 250 N, a·F ≈ 20 N m
#: on the linkage) then toe a rear wheel by < 2 mrad, within an ordinary wheel-alignment tolerance (±0.1°).
#: s_rot, the rotation's share of full sliding, is profiled over 0 … S_ROT_MAX: one linkage has one
#: stiffness, so the rotation's drag and the other steps' share 1/k, and where they disagree beyond the
#: deflection models' errors the profile's admissible optimum takes the bound (the constrained estimate)
#: instead of discarding the effect. The steps' drags disagree when another effect is collinear with one
#: of them: an incline loads the straight drive's scrub asymmetrically (uphill torque, more toe), and
#: beside a 0.034 rad incline the free fit took the straight steps' 1/k to 0.0014 rad/(N m) where the
#: rotation's stayed at the compliance-only case's 0.0032 (truth 0.0025, 396 N m/rad). Fitted s_rot without
#: another effect: 0.93–1.01 at 800 N m/rad on full campaigns; the bound leaves room for the two deflection
#: models' errors, not for the 4× 1/k of the drives fighting sticking steering joints.
S_ROT_MAX = 1.5
S_ROT_GRID = tuple(float(v) for v in np.linspace(0.0, S_ROT_MAX, 7))
#: c_odo, 0 ≤ c_odo ≤ ODOMETRY_MAX: the odometry error's coefficient, 1 when the measured toe rolling is
#: the deflection's (fitted 0.9–1.2 in straight driving and the arcs at 400 N m/rad, against a truth of
#: 1); the bound leaves the same room for the estimate's error as S_ROT_MAX.
ODOMETRY_MAX = 1.5
STEERING_COMPLIANCE = Hypothesis(
    "steering_compliance", "", ("compliance", "compliance_odometry"), _compliance_columns, S_ROT_GRID,
    magnitude=_linear_magnitude(0, "rad/(N m)", "front/rear coupling compliance 1/k "
                                f"(scrub taken at μ = {SCRUB_FRICTION})"),
    physical=lambda t: t[0] > 0 and 0 <= t[1] <= ODOMETRY_MAX, nonlinear_unit="s_rot (rotation's share of full sliding)",
    relevant=1e-4)

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (STEERING_COMPLIANCE,)
