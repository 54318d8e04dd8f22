"""The steering-compliance hypothesis in the torque channels: the scrub drag of rear wheels toed by a
compliant front/rear linkage, checked against the hand derivation on steady straight driving; the held
joints' static friction as a play in the deflection; the rotation's share of full sliding, profiled within
its bound."""
from types import SimpleNamespace

import numpy as np
import pytest

from qomni.diagnosis.channels import ChannelData, StepContext
from qomni.conventions import GRAVITY
from qomni.diagnosis.hypotheses import plausible
from qomni.diagnosis.hypotheses.steering_compliance import STEERING_COMPLIANCE
from qomni.diagnosis.hypotheses.steering_compliance import S_ROT_GRID, S_ROT_MAX, SCRUB_FRICTION, play
from qomni.diagnosis import fit as fitting
from qomni.diagnosis.problem import Problem
from qomni.ident import filtering, kinematics
from qomni.datasheet import DataSheet

SHEET = DataSheet.load()
G = SHEET.geometry
I_G = SHEET.drive.i_G
TS = SHEET.drive.cycle_time
#: model parameters, order (18): only m_ch (6), d_vw (8) and d_cw (9) enter the column
P = np.array([0.3, 4.0, 12.0, 0.3, 4.0, 12.0, 840.0, 286.0, 0.74, 3.96, 0.12])
#: the base parameters held by a tight prior
MODEL = SimpleNamespace(std_vector=np.full(10, 1e-6), p1=np.ones(10))


def _straight_channel(v: float, motor_torque: np.ndarray, n: int = 1500, alpha_dot: float = 0.0,
                      step: str = "straight") -> ChannelData:
    """The torque channel of a mode-3 step at constant speed v [m/s] with the given (4,) or (n, 4) motor
    torques; ``alpha_dot`` [rad/s] is what the steering speed signals read (0: the steering is held)."""
    alpha = np.broadcast_to(kinematics.mode_alpha(3, G), (n, 2))
    H = kinematics.H(3, alpha, G)
    qd = H[:, :, 0] * v
    qd[:, 3:5] = alpha_dot
    st = SimpleNamespace(k=3, step=step, time=np.arange(n) * TS, q=np.zeros((n, 9)), qd=qd,
                         qdd=np.zeros((n, 9)), qd_coulomb=qd.copy(),
                         motor_torque=np.broadcast_to(motor_torque, (n, 4)).copy(),
                         cycle_time=TS, omega_g=filtering.OMEGA_G)
    keep = np.ones(n, dtype=bool)
    ctx = StepContext(st, SHEET, P, np.zeros((n, 3)), H, np.zeros((n, 2)), keep,
                      np.zeros(n, dtype=bool))
    zeros = np.zeros(n)
    return ChannelData(f"{step}/x_ch", "torque", "N", 0, zeros, np.zeros((n, 10)), zeros, qd[:, 0], zeros,
                       keep, ctx)


@pytest.mark.parametrize("v, motor_torque", [(0.5, (-0.8, 0.9, 0.7, -0.6)),
                                             (-0.4, (1.2, -1.0, -1.3, 1.1)),
                                             (0.3, (0.6, 0.6, -0.5, -0.5))])
def test_scrub_column_is_the_drag_of_the_rear_wheels_toed_by_the_linkage(v, motor_torque):
    ch = _straight_channel(v, np.array(motor_torque))
    column = STEERING_COMPLIANCE.columns(ch, 1.0)[:, 0]
    beta_d = ch.context.st.qd[0, 5:9]
    # each wheel's longitudinal tyre force along its own rolling direction (the model's wheel friction
    # taken off), N; a tyre force F acts on its steering joint with the lever a
    f_long = (I_G * np.array(motor_torque) - P[9] * np.tanh(beta_d / 0.01) - P[8] * beta_d) / G.r
    linkage = G.a * np.abs([f_long[0] + f_long[1], f_long[2] + f_long[3]]) / 2     # N m, left, right
    # per unit 1/k the rear wheel of each side is toed by linkage/k, slides sideways under μN and drags
    # μN·linkage/k against its travel; in the straight step every wheel rolls at the mode's speed
    expected = SCRUB_FRICTION * P[6] * GRAVITY / 4 * linkage.sum() * np.sign(v)
    middle = slice(300, -300)  # away from the zero-phase filter's edges
    assert np.allclose(column[middle], expected, rtol=1e-6)
    # resisting: the measured input needs more than the model, whichever way the vehicle drives
    assert np.all(np.sign(column[middle]) == np.sign(v))


def test_play_follows_only_beyond_its_width():
    x = np.array([0.0, 1.0, 2.5, 3.0, 2.0, 0.5, -1.0, -0.5])
    assert np.allclose(play(x, np.full(8, 1.0)), [0.0, 0.0, 1.5, 2.0, 2.0, 1.5, 0.0, 0.0])
    assert np.allclose(play(x, np.zeros(8)), x)


def test_held_steering_joints_take_the_torque_within_their_static_friction():
    """A linkage torque T wandering by ±2.5 N m is held by the stuck joints' static friction
    (d_c/2 = 6 N m each side): the deflection, and so the drag, stays at its first value; while the
    steering moves, the joints' friction cancels in the linkage and the drag follows |T|."""
    n, v = 1500, 0.5
    base = np.array([-1.5, 0.9, 0.7, -0.6])   # left linkage torque ≈ −8 N m: |T| does not fold
    torque = np.tile(base, (n, 1))
    # (a/r)·i_G·0.25/2 = ±2.5 N m on the left linkage
    torque[:, 0] += 0.25 * np.sin(2 * np.pi * 1.5 * np.arange(n) * TS)
    middle = slice(300, -300)
    held = STEERING_COMPLIANCE.columns(_straight_channel(v, torque), 1.0)[:, 0]
    steady = STEERING_COMPLIANCE.columns(_straight_channel(v, base), 1.0)[:, 0]
    assert np.allclose(held[middle], steady[middle], rtol=1e-3)
    moving = STEERING_COMPLIANCE.columns(_straight_channel(v, torque, alpha_dot=0.5), 1.0)[:, 0]
    swing = G.a / G.r * I_G * 0.25                                      # peak to peak of |T|, N m
    assert np.ptp(moving[middle]) == pytest.approx(SCRUB_FRICTION * P[6] * GRAVITY / 4 * swing, rel=0.05)


def test_the_rotation_drag_is_the_profiled_share_of_full_sliding():
    base = np.array([-0.8, 0.9, 0.7, -0.6])
    straight = STEERING_COMPLIANCE.columns(_straight_channel(0.5, base), 0.5)
    rotation = STEERING_COMPLIANCE.columns(_straight_channel(0.5, base, step="rotation"), 0.5)
    assert np.any(straight[:, 0] != 0)
    assert np.allclose(rotation[:, 0], 0.5 * straight[:, 0])
    assert np.allclose(STEERING_COMPLIANCE.columns(_straight_channel(0.5, base), 1.5), straight)
    assert min(S_ROT_GRID) == 0.0 and max(S_ROT_GRID) == S_ROT_MAX == 1.5
    assert STEERING_COMPLIANCE.physical(np.array([5e-4, 1.0]))
    assert not STEERING_COMPLIANCE.physical(np.array([5e-4, -0.5]))  # the odometry error's opposite
    assert not STEERING_COMPLIANCE.physical(np.array([5e-4, 3.0]))
    assert not STEERING_COMPLIANCE.physical(np.array([-5e-4, 1.0]))


def _scrub_problem(rotation_share: float, inverse_stiffness: float = 2e-3, seed: int = 3):
    """A straight step and a rotation whose residuals are the scrub drag at 1/k and at
    rotation_share·(1/k), with noise of 2 % of the drag's RMS."""
    rng = np.random.default_rng(seed)
    n = 1500
    t = np.arange(n) * TS
    torque = np.array([-0.8, 0.9, 0.7, -0.6]) * (1 + 0.5 * np.sin(2 * np.pi * 0.3 * t))[:, None]
    speed = 0.5 * np.sign(np.sin(2 * np.pi * 0.1 * t) + 1e-9)
    channels = []
    for step, share in (("straight", 1.0), ("rotation", rotation_share)):
        ch = _straight_channel(0.5, torque, n=n, step=step)
        ch.context.st.qd[:, 6:9] *= speed[:, None] / 0.5
        ch.context.st.qd_coulomb[:] = ch.context.st.qd
        drag = STEERING_COMPLIANCE.columns(ch, 1.0)[:, 0] * inverse_stiffness * share
        ch.y = drag + 0.02 * np.std(drag) * rng.normal(size=n)
        channels.append(ch)
    rows = [np.ones(n, bool) for _ in channels]
    return Problem(channels, rows, [np.zeros(n, bool) for _ in channels], np.ones(2), [np.zeros(n, int)] * 2)


@pytest.mark.parametrize("share", [0.5, 1.0])
def test_the_profile_finds_the_rotations_share_within_the_bound(share):
    problem = _scrub_problem(share)
    best, _ = fitting._profile(problem, MODEL, STEERING_COMPLIANCE, fitting.solve(problem, MODEL, None, None, 1),
                               1, {}, None, 2)
    assert best.nonlinear == pytest.approx(share)
    assert best.theta[0] == pytest.approx(2e-3, rel=0.02)


def test_a_rotation_drag_beyond_full_sliding_is_fitted_at_the_bound_not_discarded():
    # The straight step's scrub is partly taken by a collinear effect (an incline, in a campaign): the
    # rotation's drag then reads 2.3× the straight step's per 1/k. The free fit's share would be
    # impossible; the profile's admissible optimum is the bound, with one 1/k between the two steps' own.
    problem = _scrub_problem(2.3, inverse_stiffness=1e-3)
    best, _ = fitting._profile(problem, MODEL, STEERING_COMPLIANCE, fitting.solve(problem, MODEL, None, None, 1),
                               1, {}, None, 2)
    assert best.nonlinear == S_ROT_MAX
    assert STEERING_COMPLIANCE.physical(best.theta)
    assert 1e-3 < best.theta[0] < 2.3e-3


def test_a_stiffer_linkage_than_alignment_tolerance_is_not_relevant():
    assert not STEERING_COMPLIANCE.physical(np.array([-1e-4, 1.0]))
    assert not plausible(STEERING_COMPLIANCE, np.array([5e-5, 1.0]))   # 20 kN m/rad
    assert plausible(STEERING_COMPLIANCE, np.array([5e-4, 1.0]))       # 2 kN m/rad


def _toed_straight_step(toe_rolling: bool, alpha_dot: float = 0.0, n: int = 1500):
    """A straight (mode 2) step at a varying speed whose rear units turn by δ(t) about their steering
    axes, as a soft linkage toes them: the rear wheels roll by a·δ̇/r more than the rigid kinematics,
    and the chassis velocity is the recording pipeline's least-squares odometry of all four wheels. Returns
    the channel of x_ch (``y`` the true generalized force of the model, ``model`` the model at the
    measured motion) and the (n, 4) extra rolling, rad/s."""
    from qomni.ident import dynamics, odometry
    from qomni.ident.regressor_rows import COULOMB_COLUMNS

    t = np.arange(n) * TS
    alpha = np.zeros((n, 2))
    H = kinematics.H(2, alpha, G, alpha_v=np.zeros(n))
    x_dot = 0.4 + 0.2 * np.sin(2 * np.pi * 0.7 * t)
    toe_rate = np.column_stack([0.15 * np.cos(2 * np.pi * 1.3 * t), -0.1 * np.cos(2 * np.pi * 0.9 * t + 0.4)])  # δ ≈ 0.02 rad
    extra = np.zeros((n, 4))
    if toe_rolling:
        extra[:, 1], extra[:, 3] = G.a / G.r * toe_rate[:, 0], G.a / G.r * toe_rate[:, 1]
    qd_true = H[:, :, 1] * x_dot[:, None]
    qd_true[:, 3:5] = alpha_dot
    qd_true[:, 5:9] += extra
    qd = qd_true.copy()
    qd[:, :3] = odometry.chassis_velocity(alpha, qd[:, 3:5], qd[:, 5:9], G)
    qdd_true, qdd = (np.gradient(x, TS, axis=0, edge_order=2) for x in (qd_true, qd))
    p = P.copy()
    p[COULOMB_COLUMNS] = 0.0            # sign functions of rates far above the error: left out
    q = np.zeros((n, 9))
    y = dynamics.reduced_regressor(2, q, qd_true, qdd_true, G)[:, 1, :] @ p
    model = dynamics.reduced_regressor(2, q, qd, qdd, G)[:, 1, :] @ p
    st = SimpleNamespace(k=2, step="straight", time=t, q=q, qd=qd, qdd=qdd, qd_coulomb=qd.copy(),
                         motor_torque=np.zeros((n, 4)), cycle_time=TS, omega_g=filtering.OMEGA_G)
    keep = np.ones(n, dtype=bool)
    ctx = StepContext(st, SHEET, p, np.zeros((n, 3)), H, np.zeros((n, 2)), keep, np.zeros(n, dtype=bool))
    return ChannelData("straight/x_ch", "torque", "N", 1, y, np.zeros((n, 10)), model, qd[:, 0],
                       qdd[:, 0], keep, ctx), extra


def test_odometry_column_undoes_the_toe_rolling_the_odometry_read_as_chassis_motion():
    """The rear wheels' toe rolling passes into the least-squares chassis velocity; the model evaluated
    at that motion misses the true generalized force by exactly the third column (coefficient 1)."""
    from qomni.diagnosis.hypotheses.steering_compliance import _rear_toe_rolling

    ch, extra = _toed_straight_step(toe_rolling=True)
    assert np.allclose(_rear_toe_rolling(ch.context), extra, atol=1e-9)
    residual = ch.y - ch.model
    column = STEERING_COMPLIANCE.columns(ch, 1.0)[:, 1]
    assert np.std(residual) > 5.0                          # N: the error is there to be removed
    assert np.allclose(column, residual, atol=1e-6 * np.abs(residual).max())


def test_odometry_column_is_zero_without_toe_rolling_and_where_the_steering_moves():
    clean, _ = _toed_straight_step(toe_rolling=False)
    assert np.abs(STEERING_COMPLIANCE.columns(clean, 1.0)[:, 1]).max() < 1e-9
    steering, _ = _toed_straight_step(toe_rolling=True, alpha_dot=0.3)
    assert np.all(STEERING_COMPLIANCE.columns(steering, 1.0)[:, 1] == 0)
