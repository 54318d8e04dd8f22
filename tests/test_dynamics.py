"""Dynamics (14)-(21): regressor, input matrix, reduced equations, feed-forward."""
import numpy as np
import pytest
import sympy as sp

from qomni.ident import dynamics as D
from qomni.ident import kinematics as K
from qomni.ident import symbolic as S
from qomni.datasheet import DataSheet

SHEET = DataSheet.load()
G, I_G = SHEET.geometry, SHEET.drive.i_G
P_TABLE2 = np.array([0.3342, 4.4649, 12.9458, 0.4501, 2.4820, 17.1071, 842.0684, 286.5955, 0.7316,
                     3.9656, 0.121])
RNG = np.random.default_rng(2)


def _theta_p(qd, qdd, p, eps):
    """Theta p written out as in (16)."""
    C_l, d_vl, d_cl, C_r, d_vr, d_cr, m_ch, C_ch, d_vw, d_cw, B_w = p
    xd, yd, gd = qd[:, 0], qd[:, 1], qd[:, 2]
    out = np.empty_like(qd)
    out[:, 0] = m_ch * qdd[:, 0] - m_ch * yd * gd
    out[:, 1] = m_ch * qdd[:, 1] + m_ch * xd * gd
    out[:, 2] = (C_ch + C_l + C_r) * qdd[:, 2]
    out[:, 3] = C_l * qdd[:, 3] + d_vl * qd[:, 3] + d_cl * np.tanh(qd[:, 3] / eps)
    out[:, 4] = C_r * qdd[:, 4] + d_vr * qd[:, 4] + d_cr * np.tanh(qd[:, 4] / eps)
    out[:, 5:] = B_w * qdd[:, 5:] + d_vw * qd[:, 5:] + d_cw * np.tanh(qd[:, 5:] / eps)
    return out


@pytest.mark.parametrize("eps", [0.01, 0.5])
def test_regressor_equals_paper_and_symbolic(eps):
    n = 50
    q, qd, qdd = RNG.standard_normal((3, n, 9)) * 0.3
    Y = D.regressor(q, qd, qdd, eps=eps)
    assert Y.shape == (n, 9, 11)
    np.testing.assert_allclose(Y @ P_TABLE2, _theta_p(qd, qdd, P_TABLE2, eps), rtol=1e-13, atol=1e-12)
    f = sp.lambdify((*S.qd, *S.qdd, S.eps), S.regressor(), modules="numpy")
    for j in range(3):
        np.testing.assert_allclose(Y[j], np.array(f(*qd[j], *qdd[j], eps), dtype=float), rtol=1e-14)


def test_coulomb_sign_limit():
    v = np.array([-1.0, 0.0, 2.0])
    np.testing.assert_array_equal(D.coulomb(v, 0.0), [-1, 0, 1])
    with pytest.raises(ValueError, match="eps"):
        D.coulomb(v, -1.0)


def test_input_matrix_and_mode1_generalized_torque():
    q = np.zeros((5, 9))
    q[:, 3:5] = RNG.uniform(-1, 1, (5, 2))
    B = D.input_matrix(q, I_G)
    np.testing.assert_array_equal(B[0], np.array(S.input_matrix().subs(S.i_G, I_G), dtype=float))
    u = RNG.standard_normal((5, 4))
    tau = D.reduced_input(1, q, u, G, I_G)
    a_r = G.a / G.r
    np.testing.assert_allclose(tau[:, 0], a_r * I_G * (u[:, 1] - u[:, 0]), rtol=1e-13)
    np.testing.assert_allclose(tau[:, 1], a_r * I_G * (u[:, 2] - u[:, 3]), rtol=1e-13)
    with pytest.raises(ValueError, match="i_G"):
        D.input_matrix(q, 0.0)


def _mode_trajectory(k, n):
    q = np.zeros((n, 9))
    q[:, [0, 1, 2, 5, 6, 7, 8]] = RNG.standard_normal((n, 7))
    av = None
    if k == 1:
        q[:, 3:5] = RNG.uniform(-1.5, 1.5, (n, 2))
    elif k == 2:
        av = RNG.uniform(-0.9, 0.9, n)
        q[:, 3:5] = K.f_icr(av, G)
    else:
        q[:, 3:5] = K.mode_alpha(k, G)
    nk = K.N_GENERALIZED[k]
    return q, av, RNG.standard_normal((n, nk)), RNG.standard_normal((n, nk))


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_feedforward_round_trip(k):
    q, av, sd, sdd = _mode_trajectory(k, 100)
    u = D.feedforward(k, q, sd, sdd, P_TABLE2, G, I_G, alpha_v=av)
    assert u.shape == (100, 4)
    qd, qdd = D.generalized_state(k, q, sd, sdd, G, alpha_v=av)
    Yk, tau = D.reduced(k, q, qd, qdd, u, G, I_G, alpha_v=av)
    assert Yk.shape == (100, K.N_GENERALIZED[k], 11)
    np.testing.assert_allclose(tau, Yk @ P_TABLE2, rtol=1e-9, atol=1e-9)
    # minimum norm: u is orthogonal to the null space of H_k^T B
    HB = np.einsum("nik,nij->nkj", K.H(k, q[:, 3:5], G, alpha_v=av), D.input_matrix(q, I_G))
    null = np.linalg.svd(HB)[2][:, K.N_GENERALIZED[k]:, :]
    assert np.abs(np.einsum("nij,nj->ni", null, u)).max() < 1e-9 * max(1, np.abs(u).max())
    if k == 2:  # default alpha_v from alpha
        np.testing.assert_allclose(D.feedforward(2, q, sd, sdd, P_TABLE2, G, I_G), u, rtol=1e-9, atol=1e-9)


def test_generalized_state_is_consistent_with_time_derivative():
    # mode 2: alpha_v(t), x_dot(t) smooth; q_ddot from (20) equals the finite difference of q_dot
    t0, h = 0.3, 1e-5

    def s(t):
        return np.array([[0.4 * np.sin(t), 0.5 * np.sin(2 * t) + 0.8 * np.cos(t)]])

    def av(t):
        return 0.4 * (1 - np.cos(t))

    def state(t):
        q = np.zeros((1, 9))
        q[:, 3:5] = K.f_icr(av(t), G)
        sd = s(t)
        sdd = (s(t + h) - s(t - h)) / (2 * h)
        return D.generalized_state(2, q, sd, sdd, G, alpha_v=av(t))

    qd0, qdd0 = state(t0)
    fd = (state(t0 + h)[0] - state(t0 - h)[0]) / (2 * h)
    np.testing.assert_allclose(qdd0, fd, atol=1e-5)
    q = np.zeros((1, 9))
    q[:, 3:5] = K.f_icr(av(t0), G)
    assert np.abs(K.constraint_residual(q[:, 3:5], qd0, G)).max() < 1e-12


def test_symbolic_mass_matrix_and_bias_rebuild_theta():
    lhs = S.mass_matrix() * S.qdd + S.nonlinear_terms() - S.Theta_p()
    assert sp.simplify(lhs) == sp.zeros(9, 1)
    assert S.reduced_regressor(4).shape == (1, 11) and S.reduced_input_matrix(2).shape == (2, 4)


def test_errors():
    q = np.zeros((2, 9))
    with pytest.raises(ValueError, match="p must"):
        D.feedforward(1, q, np.zeros((2, 2)), np.zeros((2, 2)), np.ones(10), G, I_G)
    with pytest.raises(ValueError, match="sd"):
        D.feedforward(3, q, np.zeros((2, 2)), np.zeros((2, 2)), P_TABLE2, G, I_G)
    with pytest.raises(ValueError, match="same number"):
        D.regressor(q, np.zeros((3, 9)), q)
    with pytest.raises(ValueError, match="motion mode"):
        D.reduced_regressor(0, q, q, q, G)
