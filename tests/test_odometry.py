"""Odometry (3) and pose integration."""
import numpy as np
import pytest

from qomni.ident import kinematics as K
from qomni.ident import odometry as O
from qomni.datasheet import DataSheet

G = DataSheet.load().geometry
RNG = np.random.default_rng(3)


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_chassis_velocity_recovered_from_wheel_and_steering_rates(k):
    n = 100
    av = None
    if k == 1:
        alpha = RNG.uniform(-1.5, 1.5, (n, 2))
    elif k == 2:
        av = RNG.uniform(-0.9, 0.9, n)
        alpha = K.f_icr(av, G)
    else:
        alpha = np.tile(K.mode_alpha(k, G), (n, 1))
    sd = RNG.standard_normal((n, K.N_GENERALIZED[k]))
    qd = np.einsum("nik,nk->ni", K.H(k, alpha, G, alpha_v=av), sd)
    v = O.chassis_velocity(alpha, qd[:, 3:5], qd[:, 5:], G)
    assert v.shape == (n, 3)
    np.testing.assert_allclose(v, qd[:, :3], atol=1e-12)
    if k == 1:
        assert np.abs(v).max() < 1e-12


def test_least_squares_with_slip():
    alpha = K.f_icr([0.2], G)
    qd = np.einsum("nik,nk->ni", K.H(2, alpha, G, alpha_v=[0.2]), [[0.0, 1.0]])
    beta_dot = qd[:, 5:] + [[0.5, 0, 0, 0]]  # one slipping wheel
    v = O.chassis_velocity(alpha, qd[:, 3:5], beta_dot, G)
    assert 1.0 < v[0, 0] < 1.0 + 0.5 * G.r  # biased, but a compromise over the four wheels


def test_integrate_pose_circle_rotation_and_line():
    t = np.linspace(0, 7, 701)
    n = t.size
    v, w = 0.8, 0.3
    pose = O.integrate_pose(t, np.tile([v, 0, w], (n, 1)), pose0=(1.0, -2.0, 0.5))
    R = v / w
    gam = 0.5 + w * t
    np.testing.assert_allclose(pose[:, 2], gam, atol=1e-12)
    np.testing.assert_allclose(pose[:, 0], 1.0 + R * (np.sin(gam) - np.sin(0.5)), atol=1e-10)
    np.testing.assert_allclose(pose[:, 1], -2.0 - R * (np.cos(gam) - np.cos(0.5)), atol=1e-10)
    pose = O.integrate_pose(t, np.tile([0, 0.4, 0], (n, 1)), pose0=(0, 0, np.pi / 2))
    np.testing.assert_allclose(pose[-1], [-0.4 * 7, 0, np.pi / 2], atol=1e-12)
    pose = O.integrate_pose(t, np.tile([0, 0, -1.0], (n, 1)))
    np.testing.assert_allclose(pose[-1], [0, 0, -7], atol=1e-12)
    np.testing.assert_allclose(O.world_velocity([np.pi / 2], [[1.0, 0, 0.2]]), [[0, 1, 0.2]], atol=1e-15)


def test_odometry_from_sampled_angles():
    t = np.linspace(0, 5, 2501)
    av = 0.25 * np.sin(0.6 * t)
    alpha = K.f_icr(av, G)
    xd = 0.5 + 0.2 * np.sin(t)
    sd = np.stack([0.25 * 0.6 * np.cos(0.6 * t), xd], axis=1)
    qd = np.einsum("nik,nk->ni", K.H(2, alpha, G, alpha_v=av), sd)
    dt = np.diff(t)
    beta = np.concatenate([np.zeros((1, 4)), np.cumsum((qd[1:, 5:] + qd[:-1, 5:]) / 2 * dt[:, None], axis=0)])
    pose, v = O.odometry(t, alpha, beta, G)
    ref = O.integrate_pose(t, qd[:, :3])
    np.testing.assert_allclose(pose, ref, atol=2e-4)


def test_errors():
    with pytest.raises(ValueError, match="same number"):
        O.chassis_velocity(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((3, 4)), G)
    with pytest.raises(ValueError, match="increasing"):
        O.integrate_pose([0, 0], np.zeros((2, 3)))
    with pytest.raises(ValueError, match="beta"):
        O.odometry([0, 1], np.zeros((2, 2)), np.zeros((2, 3)), G)


def test_one_sample_and_the_map_of_one_configuration_equal_the_batch():
    """A single sample (2-D products) and the controller's cached map P(α) (3, 6) applied to (α̇, β̇) give
    the batch's velocities of (3)."""
    rng = np.random.default_rng(5)
    alpha = rng.uniform(-1.4, 1.4, (50, 2))
    alpha_dot, beta_dot = rng.normal(size=(50, 2)), rng.normal(size=(50, 4))
    batch = O.chassis_velocity(alpha, alpha_dot, beta_dot, G)
    for i in range(50):
        one = O.chassis_velocity(alpha[i:i + 1], alpha_dot[i:i + 1], beta_dot[i:i + 1], G)
        assert one.shape == (1, 3)
        np.testing.assert_allclose(one[0], batch[i], rtol=1e-12, atol=1e-14)
        p = O.chassis_velocity_map(alpha[i], G)
        assert p.shape == (3, 6)
        np.testing.assert_allclose(p @ np.concatenate([alpha_dot[i], beta_dot[i]]), batch[i],
                                   rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match="alpha"):
        O.chassis_velocity_map(np.zeros(3), G)
