"""Parameter-linear dynamics (14)-(18), reduced equations (19) and feed-forward control (20)-(21),
vectorized over N samples.

``Theta(q, q_dot, q_ddot) p = B(q) u + A^T(alpha) lambda`` (15) with Theta p = Y p, where the regressor
Y (9, 11) is written out here in numpy and tested equal to :func:`ident.symbolic.regressor`.
p = (C_l, d_vl, d_cl, C_r, d_vr, d_cr, m_ch, C_ch, d_vw, d_cw, B_w) (18); u = motor-side torques
M_mot (N m), wheel order fl, rl, fr, rr; B u = (0, 0, 0, 0, 0, i_G M_mot) (17).

Shapes: q, qd, qdd (N, 9) (a single (9,) sample is accepted as N = 1); sd, sdd (N, n_k); u (N, 4).
Conventions: docs/conventions.md.
"""
from __future__ import annotations

import numpy as np

from qomni.ident import kinematics as _kin
from qomni.ident.symbolic import PARAMETER_NAMES

from qomni.conventions import EPSILON as EPS

_J = {name: j for j, name in enumerate(PARAMETER_NAMES)}


def _samples(x, width: int, name: str) -> np.ndarray:
    return _kin._samples(x, width, name)


def _same_n(*arrays_and_names) -> int:
    ns = {a.shape[0] for a, _ in arrays_and_names}
    if len(ns) != 1:
        detail = ", ".join(f"{name}: {a.shape[0]}" for a, name in arrays_and_names)
        raise ValueError(f"all inputs need the same number of samples N ({detail})")
    return ns.pop()


def coulomb(v, eps: float = EPS) -> np.ndarray:
    """Smoothed Coulomb characteristic tanh(v / eps) of (16); eps = 0 gives sign(v).

    Raises:
        ValueError: eps < 0.
    """
    if not eps >= 0:
        raise ValueError(f"eps must be >= 0 rad/s, got {eps!r}")
    v = np.asarray(v, dtype=float)
    return np.sign(v) if eps == 0 else np.tanh(v / eps)


def regressor(q, qd, qdd, geometry=None, eps: float = EPS) -> np.ndarray:
    """Regressor Y with Theta(q, q_dot, q_ddot) p = Y p, (15)-(16).

    Args:
        q, qd, qdd: (N, 9) coordinates, velocities (chassis-frame quasi-velocities for x_ch, y_ch),
            accelerations, SI / rad.
        geometry: unused (Theta does not depend on geometry); accepted for a uniform signature.
        eps: tanh smoothing, rad/s (0: sign).
    Returns:
        (N, 9, 11), columns in the order of p (18).
    Raises:
        ValueError: bad shapes or eps < 0.
    """
    q, qd, qdd = _samples(q, 9, "q"), _samples(qd, 9, "qd"), _samples(qdd, 9, "qdd")
    n = _same_n((q, "q"), (qd, "qd"), (qdd, "qdd"))
    Y = np.zeros((n, 9, 11))
    Y[:, 0, _J["m_ch"]] = qdd[:, 0] - qd[:, 1] * qd[:, 2]
    Y[:, 1, _J["m_ch"]] = qdd[:, 1] + qd[:, 0] * qd[:, 2]
    for name in ("C_l", "C_r", "C_ch"):
        Y[:, 2, _J[name]] = qdd[:, 2]
    for row, side in ((3, "l"), (4, "r")):
        Y[:, row, _J["C_" + side]] = qdd[:, row]
        Y[:, row, _J["d_v" + side]] = qd[:, row]
        Y[:, row, _J["d_c" + side]] = coulomb(qd[:, row], eps)
    Y[:, 5:, _J["B_w"]] = qdd[:, 5:]
    Y[:, 5:, _J["d_vw"]] = qd[:, 5:]
    Y[:, 5:, _J["d_cw"]] = coulomb(qd[:, 5:], eps)
    return Y


def input_matrix(q, i_G: float) -> np.ndarray:
    """B(q) of (17), shape (N, 9, 4): zeros on the 5 chassis/steering rows, i_G I_4 on the beta rows,
    so that B u = (0, 0, 0, 0, 0, i_G M_mot) for motor-side torques u (N m).

    Raises:
        ValueError: bad shape of q or i_G <= 0.
    """
    if not i_G > 0:
        raise ValueError(f"i_G must be > 0, got {i_G!r}")
    q = _samples(q, 9, "q")
    B = np.zeros((q.shape[0], 9, 4))
    B[:, 5:, :] = i_G * np.eye(4)
    return B


def reduced_regressor(k: int, q, qd, qdd, geometry, eps: float = EPS, alpha_v=None) -> np.ndarray:
    """H_k^T Y of (19), shape (N, n_k, 11): rows of the regressor matrix Theta-hat of (22).

    ``alpha_v`` (k = 2 only, (N,) or scalar) defaults to the value implied by alpha = q[:, 3:5].
    Raises: ValueError for k not in 1..4 or bad shapes.
    """
    q = _samples(q, 9, "q")
    Hk = _kin.H(k, q[:, 3:5], geometry, alpha_v=alpha_v)
    return np.einsum("nik,nij->nkj", Hk, regressor(q, qd, qdd, eps=eps))


def reduced_input(k: int, q, u, geometry, i_G: float, alpha_v=None) -> np.ndarray:
    """H_k^T B u of (19), shape (N, n_k): generalized torques of mode k from motor torques u (N, 4),
    N m motor side. Raises: ValueError for k not in 1..4, bad shapes, i_G <= 0."""
    q = _samples(q, 9, "q")
    u = _samples(u, 4, "u")
    _same_n((q, "q"), (u, "u"))
    Hk = _kin.H(k, q[:, 3:5], geometry, alpha_v=alpha_v)
    return np.einsum("nik,nij,nj->nk", Hk, input_matrix(q, i_G), u)


def reduced(k: int, q, qd, qdd, u, geometry, i_G: float, eps: float = EPS, alpha_v=None):
    """Both sides of (19) for mode k: ``(H_k^T Y, H_k^T B u)`` with shapes (N, n_k, 11) and (N, n_k);
    the second is None when ``u`` is None. See :func:`reduced_regressor`, :func:`reduced_input`."""
    Yk = reduced_regressor(k, q, qd, qdd, geometry, eps=eps, alpha_v=alpha_v)
    tau = None if u is None else reduced_input(k, q, u, geometry, i_G, alpha_v=alpha_v)
    return Yk, tau


def generalized_state(k: int, q, sd, sdd, geometry, alpha_v=None) -> tuple[np.ndarray, np.ndarray]:
    """q_dot = H_k s_dot_k (4) and q_ddot = H_dot_k s_dot_k + H_k s_ddot_k (20).

    Args:
        q: (N, 9); only alpha = q[:, 3:5] is used.
        sd, sdd: (N, n_k) generalized velocities / accelerations (10)-(13).
        alpha_v: k = 2 only, (N,) or scalar rad; default implied by alpha.
    Returns:
        (qd, qdd), each (N, 9).
    Raises:
        ValueError: k not in 1..4 or bad shapes.
    """
    k = _kin._check_mode(k)
    nk = _kin.N_GENERALIZED[k]
    q, sd, sdd = _samples(q, 9, "q"), _samples(sd, nk, "sd"), _samples(sdd, nk, "sdd")
    _same_n((q, "q"), (sd, "sd"), (sdd, "sdd"))
    alpha = q[:, 3:5]
    if k == 2 and alpha_v is None:
        alpha_v = _kin.alpha_v_from_alpha(alpha, geometry)
    Hk = _kin.H(k, alpha, geometry, alpha_v=alpha_v)
    qd = np.einsum("nik,nk->ni", Hk, sd)
    Hd = _kin.H_dot(k, alpha, qd[:, 3:5], geometry, alpha_v=alpha_v,
                    alpha_v_dot=sd[:, 0] if k == 2 else None)
    qdd = np.einsum("nik,nk->ni", Hd, sd) + np.einsum("nik,nk->ni", Hk, sdd)
    return qd, qdd


def feedforward(k: int, q, sd, sdd, p, geometry, i_G: float, eps: float = EPS,
                alpha_v=None) -> np.ndarray:
    """Feed-forward motor torques of (21): u = [H_k^T B]^+ H_k^T Theta(q, q_dot, q_ddot) p with
    q_dot, q_ddot from (4), (20) (Moore-Penrose pseudoinverse, the minimum-norm right inverse).

    Args:
        k: motion mode 1..4.
        q: (N, 9) desired coordinates (alpha must satisfy mode k's configuration (9)).
        sd, sdd: (N, n_k) desired generalized velocities and accelerations.
        p: (11,) parameters in the order of (18).
        geometry: l, b, a, r; i_G: gear ratio; eps: tanh smoothing, rad/s.
        alpha_v: k = 2 only, (N,) or scalar rad; default implied by alpha.
    Returns:
        (N, 4) motor-side torques M_mot (N m), wheel order fl, rl, fr, rr.
    Raises:
        ValueError: k not in 1..4, bad shapes, p not of shape (11,), i_G <= 0.
    """
    p = np.asarray(p, dtype=float)
    if p.shape != (len(PARAMETER_NAMES),):
        raise ValueError(f"p must have shape ({len(PARAMETER_NAMES)},), got {p.shape}")
    q = _samples(q, 9, "q")
    if k == 2 and alpha_v is None:
        alpha_v = _kin.alpha_v_from_alpha(q[:, 3:5], geometry)
    qd, qdd = generalized_state(k, q, sd, sdd, geometry, alpha_v=alpha_v)
    Hk = _kin.H(k, q[:, 3:5], geometry, alpha_v=alpha_v)
    tau = np.einsum("nik,nij,j->nk", Hk, regressor(q, qd, qdd, eps=eps), p)
    HB = np.einsum("nik,nij->nkj", Hk, input_matrix(q, i_G))
    return np.einsum("njk,nk->nj", np.linalg.pinv(HB), tau)


def mass_matrix(p) -> np.ndarray:
    """M(p) of (14), shape (9, 9): diag(m_ch, m_ch, C_ch + C_l + C_r, C_l, C_r, B_w, B_w, B_w, B_w),
    the q_ddot coefficients of Theta p (16) (constant). Raises ValueError if p is not of shape (11,)."""
    p = np.asarray(p, dtype=float)
    if p.shape != (len(PARAMETER_NAMES),):
        raise ValueError(f"p must have shape ({len(PARAMETER_NAMES)},), got {p.shape}")
    v = {name: p[j] for name, j in _J.items()}
    return np.diag([v["m_ch"], v["m_ch"], v["C_ch"] + v["C_l"] + v["C_r"], v["C_l"], v["C_r"],
                    v["B_w"], v["B_w"], v["B_w"], v["B_w"]])


def forward_dynamics(k: int, q, sd, u, p, geometry, i_G: float, eps: float = EPS,
                     alpha_v=None) -> np.ndarray:
    """Generalized accelerations of mode k from motor torques: (19) with (20) solved for s_ddot_k,

    ``H_k^T M H_k s_ddot_k = H_k^T B u - H_k^T Theta(q, q_dot, H_dot_k s_dot_k) p``, q_dot = H_k s_dot_k,

    where Theta(q, q_dot, H_dot_k s_dot_k) p = M H_dot_k s_dot_k + g(q, q_dot) (centripetal terms and
    viscous + tanh-Coulomb friction). The constraint forces A^T lambda drop out (5): torque components
    outside the range of H_k are taken by the constraints.

    Args:
        k: motion mode 1..4; q: (N, 9) (only alpha = q[:, 3:5] is used); sd: (N, n_k) s_dot_k;
        u: (N, 4) motor-side torques, N m; p: (11,); geometry: l, b, a, r; i_G; eps (rad/s, > 0);
        alpha_v: k = 2 only, (N,) or scalar rad; default implied by alpha.
    Returns:
        (N, n_k) s_ddot_k (rad/s^2 or m/s^2).
    Raises:
        ValueError: k not in 1..4, bad shapes, p not (11,), i_G <= 0, eps <= 0.
    """
    if not eps > 0:
        raise ValueError(f"eps must be > 0 rad/s, got {eps!r}")
    k = _kin._check_mode(k)
    q = _samples(q, 9, "q")
    u = _samples(u, 4, "u")
    if k == 2 and alpha_v is None:
        alpha_v = _kin.alpha_v_from_alpha(q[:, 3:5], geometry)
    nk = _kin.N_GENERALIZED[k]
    sd = _samples(sd, nk, "sd")
    _same_n((q, "q"), (sd, "sd"), (u, "u"))
    M = mass_matrix(p)
    qd, qdd0 = generalized_state(k, q, sd, np.zeros_like(sd), geometry, alpha_v=alpha_v)
    Hk = _kin.H(k, q[:, 3:5], geometry, alpha_v=alpha_v)
    bias = np.einsum("nik,nij,j->nk", Hk, regressor(q, qd, qdd0, eps=eps), np.asarray(p, dtype=float))
    tau = np.einsum("nik,nij,nj->nk", Hk, input_matrix(q, i_G), u)
    Mk = np.einsum("nik,ij,njl->nkl", Hk, M, Hk)
    return np.linalg.solve(Mk, (tau - bias)[..., None])[..., 0]


__all__ = ["EPS", "PARAMETER_NAMES", "coulomb", "regressor", "input_matrix", "reduced_regressor",
           "reduced_input", "reduced", "generalized_state", "feedforward",
           "mass_matrix", "forward_dynamics"]
