"""Gear backlash: the motor encoder leads the wheel by half the gap in the direction of the torque.

The lead λ_i = ½·gap·tanh(u_i/u_t) of each drive's motor encoder over its wheel breaks the rolling
constraints the kinematic and rolling channels test (the steering steps' kinematic channels take it at
u_t = 0.05 N m without a crossing time; the chassis steps' crossing time is below). In the torque
channels it acts through the model itself: the model's generalized velocities and accelerations are
the encoders' (the chassis twist by odometry (3) from β̇, the wheels' β̇, β̈), so where the gear crosses
its gap the model is evaluated on the lead's motion on top of the wheels' and asks for a torque the
drives did not apply. The column is
−H_kᵀY(q, δq̇, δq̈)p̂ with δβ = λ (per unit gap), the chassis' δq̇ its odometry, and the Coulomb terms
left out (the model's tanh friction is not linear in a velocity step; its viscous and inertial terms
are): the paper's model (19) evaluated on the lead, linear in the gap.

When the torque reverses, the rotor crosses the gap before the teeth meet again: the lead turns over
after the torque's zero crossing, by the crossing time. A rotor of inertia J_r under a torque that grows
from zero at the rate u̇ crosses g in t_c = (6·J_r·g/(i_G·u̇))^(1/3), tens of milliseconds, growing as
g^(1/3); J_r and the rate are the drive's, not the data sheet's, so the torque channels' lead is λ_i(t) =
½·gap·tanh(u_i(t − t_c)/u_t), with t_c and the turn-over's width u_t profiled over :data:`TRANSITION` (2
ms SYNC cycles × N m motor side). On full campaigns with 2.1–18 mrad gaps the profile took 10–20 cycles,
the larger the gap the longer, and the column then removed 49–81 % of the RMS of the gap's torque
residual in the straight run, the rotation and the arcs (17–52 % without the shift).

The rotation's rolling channels see the same lead, so their column takes the torque channels' λ_i(t) at
the same transition: one lead per drive, one profile for the step. Taken memoryless (λ_i = ½·gap·tanh(u_i
/0.05 N m)), it turns over before the motor has crossed the gap and the rolling channels read a 15 mrad
gap 35 % low on a quick campaign (`tests/test_diagnosis_backlash_torque.py`), and the hypothesis' shared
gap read 17 recorded full campaigns' 5.8–18 mrad gaps 25 % low to 6 % high (median 19 % low); with the
torque channels' lead 17 % low to 6 % high (median 4 % low; docs/results.md).

The steering steps (mode 1) get no torque column: there the steered side's drives roll their wheels
against friction at 0.5–0.7 N m (motor side) and keep its sign between the steps' reversals, while the
held side's hold their wheels at 0.01–0.08 N m with the sign changing hundreds of times a second, inside
any transition, where the lead is not a function of the torque's sign (measured on a full campaign with a
3 mrad gap); those steps' kinematic channels see the lead.
"""
from __future__ import annotations

import numpy as np

from qomni.ident import dynamics, filtering, odometry
from qomni.ident.regressor_rows import COULOMB_COLUMNS, model_alpha

from ..channels import ChannelData
from .base import LIFTED_UNMODELLED, Hypothesis, _delayed, _linear_magnitude, _rolling


BACKLASH_TORQUE_SCALE = 0.05  # N m motor side: torque below which the gear floats in its gap
#: The torque channels' profile grid: (crossing time t_c in SYNC cycles, turn-over width u_t in N m motor
#: side). t_c grows as g^(1/3): the 10 cycles (20 ms) measured at 2 mrad make 22 at the realistic range's
#: 20 mrad end and 5 at the smallest relevant gap (0.3 mrad); 0 to 30 cycles spans them with margin.
TRANSITION = tuple((cycles, width) for cycles in (0, 5, 10, 15, 20, 30) for width in (0.05, 0.1))


def _lead(motor_torque: np.ndarray, transition: tuple[int, float]) -> np.ndarray:
    """(N, 4) the encoders' lead per unit gap, ½·tanh(u(t − t_c)/u_t), for a ``transition`` (t_c in SYNC
    cycles, u_t in N m motor side) of :data:`TRANSITION`; ``motor_torque`` (N, 4) N m motor side."""
    cycles, width = transition
    return 0.5 * np.tanh(_delayed(motor_torque, cycles) / width)


def _torque_column(ch: ChannelData, transition: tuple[int, float]) -> np.ndarray | None:
    """(n,) −H_kᵀY(q, δq̇, δq̈)p̂ of a torque channel for a unit gap and a ``transition`` (cycles, N m)
    of :data:`TRANSITION` (see the module); None in mode 1."""
    ctx = ch.context
    st, g = ctx.st, ctx.sheet.geometry
    if ctx.k == 1:
        return None
    lead = filtering.zero_phase_lowpass(_lead(st.motor_torque, transition), st.cycle_time, st.omega_g)
    lead_d = np.gradient(lead, st.cycle_time, axis=0)
    lead_dd = np.gradient(lead_d, st.cycle_time, axis=0)
    alpha = model_alpha(st, g)
    still = np.zeros_like(alpha)
    qd = np.hstack([odometry.chassis_velocity(alpha, still, lead_d, g), still, lead_d])
    qdd = np.hstack([odometry.chassis_velocity(alpha, still, lead_dd, g), still, lead_dd])
    q = st.q.copy()
    q[:, 3:5] = alpha
    p = np.asarray(ctx.p, dtype=float).copy()
    p[COULOMB_COLUMNS] = 0.0
    Y = dynamics.reduced_regressor(ctx.k, q, qd, qdd, g)
    return ch.rows(-(Y[:, ch.index, :] @ p))


def _backlash_columns(ch: ChannelData, transition):
    if ch.kind == "torque":
        column = _torque_column(ch, transition)
        return None if column is None else column[:, None]
    st = ch.context.st
    if ch.kind == "kinematic":
        return ch.rows(0.5 * np.tanh(st.motor_torque[:, ch.index] / BACKLASH_TORQUE_SCALE))[:, None]
    # The encoder reads the motor, half the gap ahead of the wheel in the direction of the torque: the
    # longitudinal rows (−r β̇) see the rate of that lead, the torque channels' lead of the same step.
    lead = _lead(st.motor_torque, transition)
    violation = np.zeros((len(st.time), 8))
    violation[:, 4:] = -ch.context.sheet.geometry.r * np.gradient(lead, st.cycle_time, axis=0)
    return _rolling(ch, violation)[:, None]


#: 0.3 mrad (1 arcmin) at the gear output: what precision gearboxes are specified at; less is no backlash
#: of practical consequence (standard planetary gears have 3–6 mrad).
BACKLASH = Hypothesis("backlash", "", ("gap",), _backlash_columns, TRANSITION,
                      magnitude=_linear_magnitude(0, "rad", "gear backlash (wheel side)"),
                      physical=lambda t: t[0] > 0, relevant=3e-4,
                      nonlinear_unit="(crossing time [SYNC cycles], turn-over width [N m motor side])",
                      lifted=LIFTED_UNMODELLED)


#: Tyre/floor friction coefficient the scrub of a toed wheel is taken at (dry rubber on concrete, the

#: The hypotheses this module adds to the library (:data:`qomni.diagnosis.hypotheses.LIBRARY`).
HYPOTHESES = (BACKLASH,)
