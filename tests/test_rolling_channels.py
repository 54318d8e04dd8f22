"""The rolling channels of the diagnosis: the redundant part of the rolling constraints (1) in the
rotation step, checked on exact kinematics without a campaign."""
from types import SimpleNamespace

import numpy as np

from diagnosis.channels import rolling_constraints
from ident import kinematics
from ident.datasheet import DataSheet

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
    A = kinematics.constraint_matrix(q[:, 3:5], G)
    # longitudinal rows: A[4+i, :3]·v + A[4+i, 5+i]·β̇_i = 0
    qd[:, 5:9] = -np.einsum("nij,nj->ni", A[:, 4:8, :3], qd[:, :3]) / np.diagonal(A[:, 4:8, 5:9], axis1=1, axis2=2)
    return SimpleNamespace(k=4, q=q, qd=qd, cycle_time=TS)


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
