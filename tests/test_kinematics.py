"""Kinematics (1)-(13): constraints, ICR relation, motion modes, H_k and its derivative."""

import numpy as np
import pytest

from qomni.ident import kinematics as K
from qomni.ident import symbolic as S
from qomni.datasheet import DataSheet, Geometry

G = DataSheet.load().geometry
RNG = np.random.default_rng(1)


def _reference_constraints(alpha, qd, g):
    """A q_dot straight from docs/conventions.md: wheel-centre world velocity by finite differences."""
    l, b, a, r = g.l, g.b, g.a, g.r
    P = np.array([[l / 2, b / 2], [-l / 2, b / 2], [l / 2, -b / 2], [-l / 2, -b / 2]])
    s = np.array([1, 1, -1, -1])
    sigma = np.array([1, -1, 1, -1])
    gamma0 = 0.37

    def centres(tau):
        gam = gamma0 + tau * qd[2]
        al = alpha + tau * qd[3:5]
        phi = sigma * al[[0, 0, 1, 1]]
        c = P + (s * a)[:, None] * np.stack([-np.sin(phi), np.cos(phi)], axis=1)
        R = np.array([[np.cos(gam), -np.sin(gam)], [np.sin(gam), np.cos(gam)]])
        vw = np.array([[np.cos(gamma0), -np.sin(gamma0)], [np.sin(gamma0), np.cos(gamma0)]]) @ qd[:2]
        return tau * vw + c @ R.T, phi + gam

    h = 1e-6
    (cp, _), (cm, _), (_, head) = centres(h), centres(-h), centres(0.0)
    v = (cp - cm) / (2 * h)
    lat = -np.sin(head) * v[:, 0] + np.cos(head) * v[:, 1]
    lon = np.cos(head) * v[:, 0] + np.sin(head) * v[:, 1] - r * qd[5:]
    return np.concatenate([lat, lon])


def _mode_states(k, n):
    """alpha (n, 2) and alpha_v (or None) of mode k."""
    if k == 1:
        return RNG.uniform(-np.pi / 2, np.pi / 2, (n, 2)), None
    if k == 2:
        av = RNG.uniform(-1, 1, n) * K.alpha_v_max(G)
        av[:3] = [0.0, K.alpha_v_max(G), -K.alpha_v_max(G)]
        return K.f_icr(av, G), av
    return np.tile(K.mode_alpha(k, G), (n, 1)), None


def test_constraint_matrix_matches_conventions():
    for _ in range(20):
        alpha = RNG.uniform(-np.pi / 2, np.pi / 2, 2)
        qd = RNG.standard_normal(9)
        A = K.constraint_matrix(alpha, G)[0]
        np.testing.assert_allclose(A @ qd, _reference_constraints(alpha, qd, G), atol=1e-7)


def test_constraint_matrix_shape_and_partition():
    A = K.constraint_matrix(RNG.uniform(-1, 1, (7, 2)), G)
    assert A.shape == (7, 8, 9)
    assert np.all(A[:, :4, 3:] == 0)  # lateral rows: A_alpha,1 = A_beta,1 = 0 (2)
    np.testing.assert_array_equal(A[:, 4:, 5:], np.broadcast_to(-G.r * np.eye(4), (7, 4, 4)))


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_A_H_is_zero(k):
    alpha, av = _mode_states(k, 200)
    Hk = K.H(k, alpha, G, alpha_v=av)
    assert Hk.shape == (200, 9, K.N_GENERALIZED[k])
    AH = K.constraint_matrix(alpha, G) @ Hk
    assert np.abs(AH).max() < 1e-12


@pytest.mark.parametrize("k", [3, 4])
def test_longitudinal_constraints_hold_off_configuration(k):
    alpha = RNG.uniform(-np.pi / 2, np.pi / 2, (50, 2))
    AH = K.constraint_matrix(alpha, G) @ K.H(k, alpha, G)
    assert np.abs(AH[:, 4:]).max() < 1e-12


def test_documented_wheel_rates():
    a_r = G.a / G.r
    H1 = K.H(1, RNG.uniform(-1, 1, (3, 2)), G)
    np.testing.assert_allclose(H1[:, 5:, 0], np.tile([-a_r, a_r, 0, 0], (3, 1)), atol=1e-15)
    np.testing.assert_allclose(H1[:, 5:, 1], np.tile([0, 0, a_r, -a_r], (3, 1)), atol=1e-15)
    R = np.hypot(G.l, G.b) / 2
    H4 = K.H(4, K.mode_alpha(4, G), G)[0, :, 0]
    np.testing.assert_allclose(H4, [0, 0, 1, 0, 0, *(np.array([-1, -1, 1, 1]) * (R + G.a) / G.r)],
                               atol=1e-12)
    H3 = K.H(3, K.mode_alpha(3, G), G)[0, :, 0]
    np.testing.assert_allclose(H3, [0, 1, 0, 0, 0, -10, 10, 10, -10], atol=1e-12)
    av = 0.2
    H2 = K.H(2, K.f_icr(av, G), G, alpha_v=av)[0]
    np.testing.assert_allclose(H2[:5, 1], [1, 0, np.tan(av) / (G.l / 2), 0, 0], atol=1e-15)
    np.testing.assert_allclose(H2[3:5, 0], K.f_icr_prime(av, G)[0])


def _eval_symbolic(matrix, subs):
    return np.array(matrix.subs(subs).evalf(), dtype=float)


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_numeric_equals_symbolic(k):
    alpha, av = _mode_states(k, 4)
    alpha_dot = RNG.standard_normal((4, 2))
    avd = RNG.standard_normal(4)
    if k == 1:
        alpha = RNG.uniform(-1.5, 1.5, (4, 2))
    geo = {S.l: G.l, S.b: G.b, S.a: G.a, S.r: G.r}
    Hn = K.H(k, alpha, G, alpha_v=av)
    Hdn = K.H_dot(k, alpha, alpha_dot, G, alpha_v=av, alpha_v_dot=avd if k == 2 else None)
    An = K.constraint_matrix(alpha, G)
    for j in range(4):
        subs = {**geo, S.alpha_l: alpha[j, 0], S.alpha_r: alpha[j, 1], S.alpha_v: 0 if av is None else av[j],
                S.alpha_l_dot: alpha_dot[j, 0], S.alpha_r_dot: alpha_dot[j, 1], S.alpha_v_dot: avd[j]}
        np.testing.assert_allclose(Hn[j], _eval_symbolic(S.H(k), subs), atol=1e-12)
        np.testing.assert_allclose(Hdn[j], _eval_symbolic(S.H_dot(k), subs), atol=1e-10)
        np.testing.assert_allclose(An[j], _eval_symbolic(S.constraint_matrix(), subs), atol=1e-12)


def test_f_icr_relation_and_branch():
    av = np.linspace(-K.alpha_v_max(G), K.alpha_v_max(G), 401)
    alpha = K.f_icr(av, G)
    assert alpha.shape == (401, 2)
    np.testing.assert_array_equal(K.f_icr(0.0, G), [[0.0, 0.0]])
    assert np.all(np.abs(alpha) <= np.pi / 2 + 1e-12)
    assert np.all(np.sign(alpha[:, 0]) == np.sign(av)) and np.all(np.sign(alpha[:, 1]) == np.sign(av))
    nz = np.abs(av) > 1e-3
    hl = G.l / 2
    np.testing.assert_allclose(hl / np.tan(alpha[nz, 0]), hl / np.tan(av[nz]) - G.b / 2, atol=1e-9)
    np.testing.assert_allclose(hl / np.tan(alpha[nz, 1]), hl / np.tan(av[nz]) + G.b / 2, atol=1e-9)
    # the inner wheel is steered more
    pos, neg = av > 1e-9, av < -1e-9
    assert np.all(alpha[pos, 0] > alpha[pos, 1]) and np.all(alpha[neg, 1] < alpha[neg, 0])
    # inverse
    np.testing.assert_allclose(K.alpha_v_from_alpha(alpha, G), av, atol=1e-12)
    with pytest.raises(ValueError, match="alpha_v"):
        K.f_icr(K.alpha_v_max(G) + 0.01, G)


def test_f_icr_prime_matches_derivative_and_symbolic():
    av = RNG.uniform(-0.9, 0.9, 50)
    h = 1e-6
    fd = (K.f_icr(av + h, G) - K.f_icr(av - h, G)) / (2 * h)
    np.testing.assert_allclose(K.f_icr_prime(av, G), fd, rtol=1e-7)
    d = S.f_icr().diff(S.alpha_v) - S.f_icr_prime()
    subs = {S.l: G.l, S.b: G.b, S.alpha_v: 0.3}
    assert np.abs(np.array(d.subs(subs).evalf(), dtype=float)).max() < 1e-12
    subs[S.alpha_v] = 0.3
    np.testing.assert_allclose(np.array(S.f_icr().subs(subs).evalf(), dtype=float).ravel(),
                               K.f_icr(0.3, G)[0])


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_H_dot_matches_finite_difference(k):
    h = 1e-6
    if k == 2:
        av0, avd = RNG.uniform(-0.8, 0.8, 30), RNG.standard_normal(30)

        def Ht(tau):
            av = av0 + tau * avd
            return K.H(2, K.f_icr(av, G), G, alpha_v=av)

        alpha = K.f_icr(av0, G)
        alpha_dot = K.f_icr_prime(av0, G) * avd[:, None]
        Hd = K.H_dot(2, alpha, alpha_dot, G, alpha_v=av0, alpha_v_dot=avd)
        # default alpha_v_dot from alpha_dot (least squares) gives the same
        np.testing.assert_allclose(K.H_dot(2, alpha, alpha_dot, G), Hd, atol=1e-10)
    else:
        alpha, alpha_dot = RNG.uniform(-1.4, 1.4, (30, 2)), RNG.standard_normal((30, 2))

        def Ht(tau):
            return K.H(k, alpha + tau * alpha_dot, G)

        Hd = K.H_dot(k, alpha, alpha_dot, G)
    np.testing.assert_allclose(Hd, (Ht(h) - Ht(-h)) / (2 * h), atol=1e-6)
    if k == 1:
        assert np.all(Hd == 0)


def test_motion_mode_detection():
    for k in (3, 4):
        alpha = K.mode_alpha(k, G) + RNG.uniform(-5e-4, 5e-4, (20, 2))
        assert np.all(K.motion_mode(alpha, G) == k)
        assert np.all(K.motion_mode(K.mode_alpha(k, G) + 0.01, G) == 1)
    alpha, _ = _mode_states(2, 100)
    assert np.all(K.motion_mode(alpha[:, :], G)[3:] == 2)  # first 3 include the +-pi/2 boundary
    assert K.motion_mode(np.zeros(2), G)[0] == 2  # straight
    assert np.all(K.motion_mode(K.f_icr([0.3, -0.5], G) + [[0.01, 0], [0, -0.01]], G) == 1)
    assert np.all(K.motion_mode([[0.3, -0.3], [-0.2, 0.4], [0.5, 0.0]], G) == 1)
    near = K.f_icr(0.3, G) + [0.02, 0.0]
    assert K.motion_mode(near, G, tol=0.05)[0] == 2
    assert K.motion_mode(near, G, tol=1e-4)[0] == 1
    with pytest.raises(ValueError):
        K.motion_mode(np.zeros(2), G, tol=-1)


def test_sdot_from_qdot_inverts_H():
    for k in (1, 2, 3, 4):
        alpha, av = _mode_states(k, 40)
        sd = RNG.standard_normal((40, K.N_GENERALIZED[k]))
        qd = np.einsum("nik,nk->ni", K.H(k, alpha, G, alpha_v=av), sd)
        np.testing.assert_allclose(K.sdot_from_qdot(k, alpha, qd, G, alpha_v=av), sd, atol=1e-10)


def test_errors_and_shapes():
    with pytest.raises(ValueError, match="motion mode"):
        K.H(5, np.zeros(2), G)
    with pytest.raises(ValueError, match="alpha"):
        K.constraint_matrix(np.zeros((3, 3)), G)
    with pytest.raises(TypeError, match="geometry"):
        K.constraint_matrix(np.zeros(2), object())
    with pytest.raises(ValueError):
        K.mode_alpha(1, G)
    assert K.H(2, np.zeros(2), G).shape == (1, 9, 2)
    geo = Geometry(l=2.0, b=1.0, a=0.1, r=0.2)
    alpha, av = K.f_icr(np.array([0.2, -0.4]), geo), np.array([0.2, -0.4])
    assert np.abs(K.constraint_matrix(alpha, geo) @ K.H(2, alpha, geo, alpha_v=av)).max() < 1e-12


@pytest.mark.parametrize("k", K.MODES)
def test_one_sample_evaluates_as_a_batch_does(k):
    """A single sample goes through the math-module lambdification (the controller's every cycle); it
    must give the batch's numbers, including H_dot and the constraint matrix."""
    alpha, av = _mode_states(k, 40)
    alpha_dot = RNG.normal(size=(40, 2))
    batch = K.H(k, alpha, G, alpha_v=av), K.H_dot(k, alpha, alpha_dot, G, alpha_v=av), K.constraint_matrix(alpha, G)
    for i in range(40):
        one_av = None if av is None else av[i:i + 1]
        single = (K.H(k, alpha[i:i + 1], G, alpha_v=one_av),
                  K.H_dot(k, alpha[i:i + 1], alpha_dot[i:i + 1], G, alpha_v=one_av),
                  K.constraint_matrix(alpha[i:i + 1], G))
        for b, s in zip(batch, single):
            assert s.shape == (1, *b.shape[1:])
            np.testing.assert_allclose(s[0], b[i], rtol=1e-13, atol=1e-13)


def test_one_sample_that_float_arithmetic_refuses_gives_numpys_value():
    """Where Python's math raises (sin of an infinite angle, a division by zero) the one-sample path falls
    back to numpy and gives what a batch gives (nan here), never an exception the batch would not raise."""
    alpha = np.array([[np.inf, 0.1], [0.2, 0.1]])
    batch = K.constraint_matrix(alpha, G)
    single = K.constraint_matrix(alpha[:1], G)
    np.testing.assert_array_equal(single[0], batch[0])
    assert np.isnan(single).any()
