"""Odometry (3): chassis velocities from steering and wheel rates, and pose integration in the world
frame, vectorized over N samples.

``q_dot_ch = -A_ch^+(alpha) (A_alpha alpha_dot + A_beta beta_dot)`` with the partition (2) of A and
the Moore-Penrose pseudoinverse A_ch^+ = (A_ch^T A_ch)^-1 A_ch^T (least squares over the 8 rolling
constraints). ``q_dot_ch = (x_dot, y_dot, gamma_dot)``: x_dot, y_dot in the chassis frame (m/s),
gamma_dot yaw rate (rad/s). World pose ``(x_w, y_w, gamma)``, world frame z up, docs/conventions.md.
"""
from __future__ import annotations

import numpy as np

from qomni.ident import kinematics as _kin


def chassis_velocity(alpha, alpha_dot, beta_dot, geometry) -> np.ndarray:
    """Chassis velocities q_dot_ch of (3).

    Args:
        alpha: (N, 2) steering angles, rad; alpha_dot: (N, 2) rad/s.
        beta_dot: (N, 4) wheel rolling rates (wheel side, fl, rl, fr, rr), rad/s.
        geometry: l, b, a, r.
    Returns:
        (N, 3): (x_dot, y_dot) in the chassis frame, m/s, and gamma_dot, rad/s.
    Raises:
        ValueError: bad shapes or different N.
    """
    alpha = _kin._samples(alpha, 2, "alpha")
    alpha_dot = _kin._samples(alpha_dot, 2, "alpha_dot")
    beta_dot = _kin._samples(beta_dot, 4, "beta_dot")
    if not alpha.shape[0] == alpha_dot.shape[0] == beta_dot.shape[0]:
        raise ValueError("alpha, alpha_dot and beta_dot need the same number of samples N, got "
                         f"{alpha.shape[0]}, {alpha_dot.shape[0]}, {beta_dot.shape[0]}")
    A = _kin.constraint_matrix(alpha, geometry)
    if A.shape[0] == 1:                    # one sample (a controller's cycle): 2-D products, no batching
        a = A[0]
        rhs = -(a[:, 3:5] @ alpha_dot[0] + a[:, 5:] @ beta_dot[0])
        return np.linalg.solve(a[:, :3].T @ a[:, :3], a[:, :3].T @ rhs)[None]
    A_ch = A[:, :, :3]
    rhs = -(np.einsum("nij,nj->ni", A[:, :, 3:5], alpha_dot) + np.einsum("nij,nj->ni", A[:, :, 5:], beta_dot))
    AtA = np.einsum("nki,nkj->nij", A_ch, A_ch)
    Atb = np.einsum("nki,nk->ni", A_ch, rhs)
    return np.linalg.solve(AtA, Atb[..., None])[..., 0]


def chassis_velocity_map(alpha, geometry) -> np.ndarray:
    """The linear map of (3) at one configuration: q_dot_ch = P (alpha_dot, beta_dot).

    P = -A_ch^+(alpha) [A_alpha A_beta], so that ``P @ np.concatenate([alpha_dot, beta_dot])`` is
    :func:`chassis_velocity` of that sample (equal to rounding). For a controller that meets the same
    measured steering angles cycle after cycle (sensor counts) and keeps P per configuration.

    Args:
        alpha: (2,) steering angles, rad. geometry: l, b, a, r.
    Returns:
        (3, 6): rows x_dot, y_dot [m/s] and gamma_dot [rad/s]; columns alpha_l_dot, alpha_r_dot [rad/s]
        and the four beta_dot (fl, rl, fr, rr) [rad/s].
    Raises:
        ValueError: alpha is not two angles.
    """
    alpha = np.asarray(alpha, dtype=float)
    if alpha.shape != (2,):
        raise ValueError(f"alpha must have shape (2,), got {alpha.shape}")
    a = _kin.constraint_matrix(alpha[None], geometry)[0]
    a_ch = a[:, :3]
    return -np.linalg.solve(a_ch.T @ a_ch, a_ch.T @ a[:, 3:])


def world_velocity(gamma, qd_ch) -> np.ndarray:
    """World-frame velocities (x_w_dot, y_w_dot, gamma_dot), shape (N, 3), from the chassis-frame
    q_dot_ch (N, 3) at yaw angles gamma (N,) rad."""
    qd_ch = _kin._samples(qd_ch, 3, "qd_ch")
    g = _kin._per_sample(gamma, qd_ch.shape[0], "gamma")
    c, s = np.cos(g), np.sin(g)
    return np.stack([c * qd_ch[:, 0] - s * qd_ch[:, 1], s * qd_ch[:, 0] + c * qd_ch[:, 1], qd_ch[:, 2]],
                    axis=1)


def integrate_pose(t, qd_ch, pose0=(0.0, 0.0, 0.0)) -> np.ndarray:
    """World pose (x_w, y_w, gamma) by time integration of chassis-frame velocities.

    Between samples the twist is taken constant at the mean of the two samples and integrated
    exactly on SE(2) (arc of constant curvature), so constant body velocities give exact circles.

    Args:
        t: (N,) increasing sample times, s.
        qd_ch: (N, 3) chassis-frame (x_dot, y_dot) m/s and gamma_dot rad/s at the samples.
        pose0: world pose at t[0]: (x_w, y_w) m, gamma rad.
    Returns:
        (N, 3) world poses at the sample times; row 0 equals pose0.
    Raises:
        ValueError: bad shapes or t not increasing.
    """
    qd_ch = _kin._samples(qd_ch, 3, "qd_ch")
    t = np.asarray(t, dtype=float)
    n = qd_ch.shape[0]
    if t.shape != (n,):
        raise ValueError(f"t must have shape ({n},), got {t.shape}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise ValueError("t must be strictly increasing")
    pose0 = np.asarray(pose0, dtype=float)
    if pose0.shape != (3,):
        raise ValueError(f"pose0 must have shape (3,), got {pose0.shape}")
    mean = (qd_ch[1:] + qd_ch[:-1]) / 2
    dth = mean[:, 2] * dt
    gamma = pose0[2] + np.concatenate([[0.0], np.cumsum(dth)])
    # exact SE(2) increment in the frame at the start of the step: V(dth) (v dt)
    small = np.abs(dth) < 1e-6
    th = np.where(small, 1.0, dth)
    sinc = np.where(small, 1 - dth**2 / 6, np.sin(th) / th)
    cosc = np.where(small, dth / 2 - dth**3 / 24, (1 - np.cos(th)) / th)
    vx, vy = mean[:, 0] * dt, mean[:, 1] * dt
    dx_b, dy_b = sinc * vx - cosc * vy, cosc * vx + sinc * vy
    c, s = np.cos(gamma[:-1]), np.sin(gamma[:-1])
    xw = pose0[0] + np.concatenate([[0.0], np.cumsum(c * dx_b - s * dy_b)])
    yw = pose0[1] + np.concatenate([[0.0], np.cumsum(s * dx_b + c * dy_b)])
    return np.stack([xw, yw, gamma], axis=1)


def odometry(t, alpha, beta, geometry, pose0=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Dead reckoning from sampled steering and wheel angles: rates by ``numpy.gradient`` (second
    order central differences; filter noisy data before), (3), then :func:`integrate_pose`.

    Args:
        t: (N,) s; alpha: (N, 2) rad; beta: (N, 4) wheel-side rolling angles, rad (unwrapped).
    Returns:
        (pose, qd_ch): world poses (N, 3) and chassis velocities (N, 3).
    Raises:
        ValueError: bad shapes, N < 2, or t not increasing.
    """
    t = np.asarray(t, dtype=float)
    alpha = _kin._samples(alpha, 2, "alpha")
    beta = _kin._samples(beta, 4, "beta")
    if t.ndim != 1 or t.shape[0] < 2:
        raise ValueError(f"t must have shape (N,) with N >= 2, got {t.shape}")
    qd_ch = chassis_velocity(alpha, np.gradient(alpha, t, axis=0), np.gradient(beta, t, axis=0), geometry)
    return integrate_pose(t, qd_ch, pose0), qd_ch


__all__ = ["chassis_velocity", "chassis_velocity_map", "world_velocity", "integrate_pose", "odometry"]
