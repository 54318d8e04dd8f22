"""The rolling channels of the diagnosis: the redundant part of the rolling constraints (1) in the
rotation step, checked on exact kinematics without a campaign."""
from types import SimpleNamespace

import numpy as np

from qomni.diagnosis.channels import _misalignment_sliding, rolling_constraints
from qomni.diagnosis.hypotheses.stribeck import steering_held_off
from qomni.ident.controller import INTEGRAL_DEADBAND_LSB
from qomni.ident import kinematics
from qomni.datasheet import DataSheet

SHEET = DataSheet.load()
G = SHEET.geometry
TS = SHEET.drive.cycle_time


def _rotation(n=500, alpha=None):
    """Mode-4 step signals: the chassis turns about its centre, each wheel rolls without slip."""
    t = np.arange(n) * TS
    omega = 0.6 * np.sin(2 * np.pi * t / 0.8)
    alpha = kinematics.mode_alpha(4, G) if alpha is None else np.asarray(alpha)
    q = np.zeros((n, 9))
    q[:, 3:5] = alpha
    qd = np.zeros((n, 9))
    qd[:, 2] = omega
    _roll_wheels(q, qd)
    return SimpleNamespace(k=4, q=q, qd=qd, cycle_time=TS, time=t)


def _roll_wheels(q, qd):
    """Set each wheel's β̇ so that it rolls along its heading with the chassis twist qd[:, :3]."""
    A = kinematics.constraint_matrix(q[:, 3:5], G)
    # longitudinal rows: A[4+i, :3]·v + A[4+i, 5+i]·β̇_i = 0
    qd[:, 5:9] = -np.einsum("nij,nj->ni", A[:, 4:8, :3], qd[:, :3]) / np.diagonal(A[:, 4:8, 5:9], axis1=1, axis2=2)


def test_the_redundant_directions_are_those_no_chassis_twist_reaches():
    rc = rolling_constraints(_rotation(), SHEET)
    assert rc.basis.shape == (8, 5)
    assert np.allclose(rc.basis.T @ rc.basis, np.eye(5))
    twists = np.random.default_rng(0).normal(size=(3, 20))
    assert np.allclose(rc.basis.T @ rc.A_ch_nominal @ twists, 0.0, atol=1e-12)


def test_rolling_without_slip_leaves_nothing_and_a_lateral_slip_does():
    st = _rotation()
    rc = rolling_constraints(st, SHEET)
    measured = np.einsum("nij,nj->ni", rc.A[:, :, 3:], st.qd[:, 3:])
    assert np.max(np.abs(rc.integrate(measured))) < 1e-9                  # m
    # A rigid sideways drift of 1 cm/s that the wheels do not roll with (tyres slipping across):
    violation = np.zeros_like(measured)
    violation[:, :4] = rc.A_ch_nominal[:4] @ np.array([0.01, 0.0, 0.0])
    drift = rc.integrate(violation)
    duration = len(drift) * TS
    assert np.allclose(drift[-1], rc.basis.T @ violation[0] * duration)
    # most of it is redundant: the wheels' rolling says the chassis did not move sideways
    assert np.linalg.norm(drift[-1]) > 0.5 * 0.01 * duration


def _misaligned_rotation(offset):
    """Mode-4 step with each side's steering ``offset`` (left, right) rad off the mode's angles: the wheels
    share no centre of rotation, so the chassis turns about the point that least-squares their side
    slip while every wheel rolls along its heading and slides across it."""
    alpha = kinematics.mode_alpha(4, G) + np.asarray(offset)
    st = _rotation(alpha=alpha)
    lateral = kinematics.constraint_matrix(alpha[None, :], G)[0, :4, :3]
    st.qd[:, :2] = -np.outer(st.qd[:, 2], np.linalg.lstsq(lateral[:, :2], lateral[:, 2], rcond=None)[0])
    _roll_wheels(st.q, st.qd)
    return st


def _context(st):
    return SimpleNamespace(st=st, sheet=SHEET, rolling=rolling_constraints(st, SHEET),
                           keep=np.ones(len(st.q), dtype=bool))


def test_misaligned_steering_slides_in_the_rolling_channels_and_its_column_holds_it():
    """3 mrad of right-side steering offset (8 sensor LSB) makes the wheels slide sideways as the chassis
    turns: the redundant constraints move by a tenth of a millimetre, all of it in the misalignment
    column."""
    st = _misaligned_rotation([0.0, 3e-3])
    ctx = _context(st)
    rc = ctx.rolling
    y = rc.integrate(np.einsum("nij,nj->ni", rc.A[:, :, 3:], st.qd[:, 3:]))
    column = _misalignment_sliding(ctx)
    assert column.shape == (len(y), 5, 1)               # only the right side misses the mode's angle
    assert np.max(np.abs(y)) > 1e-5                      # m
    for m in range(5):
        X = np.column_stack([np.ones(len(y)), column[:, m, 0]])
        coef, *_ = np.linalg.lstsq(X, y[:, m], rcond=None)
        assert np.sqrt(np.mean((y[:, m] - X @ coef) ** 2)) < 1e-3 * np.sqrt(np.mean(y[:, m] ** 2)) + 1e-9
        assert np.std(y[:, m]) > 0.3 * np.sqrt(np.mean(y[:, m] ** 2))  # the constant alone would not


def test_steering_within_a_few_sensor_lsb_of_the_mode_gets_no_misalignment_column():
    lsb = SHEET.drive.steering_lsb
    assert _misalignment_sliding(_context(_misaligned_rotation([1.9 * lsb, -1.9 * lsb]))).shape[2] == 0
    assert _misalignment_sliding(_context(_misaligned_rotation([-2.2 * lsb, 17.8 * lsb]))).shape[2] == 2
    assert _misalignment_sliding(_context(_misaligned_rotation([5 * lsb, 5 * lsb]))).shape[2] == 2


def _rotation_problem(offset):
    """A stand-in for a diagnosis problem holding one rotation channel whose steering is ``offset`` off."""
    return SimpleNamespace(channels=[SimpleNamespace(context=_context(_misaligned_rotation(offset)))])


def test_a_steering_held_off_the_rotations_angles_is_reported_only_beyond_the_reference_run():
    lsb = SHEET.drive.steering_lsb
    # the controller leaves a held steering anywhere within its integral deadband: no reading there
    deadband = INTEGRAL_DEADBAND_LSB * lsb
    assert steering_held_off(_rotation_problem([deadband, -deadband])) is None
    # ... read to the nearest LSB: half an LSB more
    assert steering_held_off(_rotation_problem([1.9 * lsb, -1.9 * lsb])) is None
    assert "left -2.2 LSB" in steering_held_off(_rotation_problem([-2.2 * lsb, 0.0]))
    assert "right -3.0 LSB" in steering_held_off(_rotation_problem([0.0, -3 * lsb]))
    text = steering_held_off(_rotation_problem([5 * lsb, -1 * lsb]), _rotation_problem([lsb, lsb]))
    assert "left +5.0 LSB" in text and "right" not in text.split("(")[0] and "reference run +1.0" in text
    # a reference run holding a side off itself (either side): its controller does not hold even the
    # model's friction on target, so the offset says nothing of the friction
    assert steering_held_off(_rotation_problem([5 * lsb, 0.0]), _rotation_problem([-6 * lsb, 0.0])) is None
    assert steering_held_off(_rotation_problem([5 * lsb, 0.0]), _rotation_problem([0.0, 19 * lsb])) is None
    # a run without a rotation step has nothing to say
    assert steering_held_off(SimpleNamespace(channels=[])) is None
