"""The paper's model as ONE symbolic (sympy) source: constraints (1)-(2), kinematic models (4)-(13),
parameter-linear dynamics (14)-(18) and the reduced equations (19)-(20).

Everything numeric in ``ident`` (``kinematics``, ``dynamics``) is generated from — or tested equal
to — the matrices built here, and the same matrices can be fed to ``sympy.codegen`` to produce the
C code of an FMU. Frames, signs and orderings follow ``docs/conventions.md``:

* ``q = (x_ch, y_ch, gamma_ch, alpha_l, alpha_r, beta_fl, beta_rl, beta_fr, beta_rr)``; ``x_ch``,
  ``y_ch`` velocities are chassis-frame quasi-velocities.
* wheel order fl, rl, fr, rr; side sign ``s_i = (+1, +1, -1, -1)``; steering joint angle
  ``phi_i = sigma_i * alpha_side`` with ``sigma_i = (+1, -1, +1, -1)`` (front/rear mirror coupling).
* ``p = (C_l, d_vl, d_cl, C_r, d_vr, d_cr, m_ch, C_ch, d_vw, d_cw, B_w)`` (18).

Symbols (all real; geometry and ``eps`` positive): geometry ``l, b, a, r`` (m), gear ratio ``i_G``,
tanh smoothing ``eps`` (rad/s), coordinates ``q``, velocities ``qd`` (names ``*_dot``), accelerations
``qdd`` (names ``*_ddot``), virtual steering angle ``alpha_v`` with ``alpha_v_dot``, parameters ``p``,
motor torques ``u = (M_mot_fl, M_mot_rl, M_mot_fr, M_mot_rr)`` (N m, motor side).

Every builder is cached and returns a ``sympy.ImmutableMatrix``.
"""
from __future__ import annotations

from functools import cache

import sympy as sp

from qomni.conventions import FRONT_SIGN, PARAMETER_NAMES, SIDE_INDEX, SIDE_SIGN, WHEELS
"""Index of the steering angle (0: alpha_l, 1: alpha_r) that drives wheel i."""

COORDINATE_NAMES = ("x_ch", "y_ch", "gamma_ch", "alpha_l", "alpha_r",
                    "beta_fl", "beta_rl", "beta_fr", "beta_rr")
GENERALIZED_VELOCITY_NAMES = {1: ("alpha_l_dot", "alpha_r_dot"), 2: ("alpha_v_dot", "x_ch_dot"),
                              3: ("y_ch_dot",), 4: ("gamma_ch_dot",)}
"""s_dot_k of (10)-(13) per motion mode k."""
MODES = (1, 2, 3, 4)

# --- symbols -------------------------------------------------------------------------------------
l, b, a, r = sp.symbols("l b a r", positive=True)
i_G, eps = sp.symbols("i_G eps", positive=True)

q = sp.ImmutableMatrix(sp.symbols(" ".join(COORDINATE_NAMES), real=True))
qd = sp.ImmutableMatrix(sp.symbols(" ".join(n + "_dot" for n in COORDINATE_NAMES), real=True))
qdd = sp.ImmutableMatrix(sp.symbols(" ".join(n + "_ddot" for n in COORDINATE_NAMES), real=True))

x_ch, y_ch, gamma_ch, alpha_l, alpha_r = q[:5]
x_ch_dot, y_ch_dot, gamma_ch_dot, alpha_l_dot, alpha_r_dot = qd[:5]
alpha = sp.ImmutableMatrix([alpha_l, alpha_r])
alpha_dot = sp.ImmutableMatrix([alpha_l_dot, alpha_r_dot])
beta_dot = sp.ImmutableMatrix(qd[5:])
beta_ddot = sp.ImmutableMatrix(qdd[5:])

alpha_v, alpha_v_dot = sp.symbols("alpha_v alpha_v_dot", real=True)

p = sp.ImmutableMatrix(sp.symbols(" ".join(PARAMETER_NAMES), real=True))
C_l, d_vl, d_cl, C_r, d_vr, d_cr, m_ch, C_ch, d_vw, d_cw, B_w = p
u = sp.ImmutableMatrix(sp.symbols(" ".join("M_mot_" + w for w in WHEELS), real=True))

GEOMETRY_SYMBOLS = (l, b, a, r)


# --- geometry of one wheel -------------------------------------------------------------------------
def wheel_geometry(i: int) -> dict:
    """Symbolic geometry of wheel ``i`` (0..3 = fl, rl, fr, rr) per docs/conventions.md.

    Returns a dict with ``phi`` (steering joint angle), ``e_long``, ``e_lat`` (2-vectors), ``P``
    (steering axis), ``c`` (wheel centre ``P + s a e_lat``), ``s``, ``sigma``.
    """
    s, sigma = SIDE_SIGN[i], FRONT_SIGN[i]
    phi = sigma * alpha[SIDE_INDEX[i]]
    e_long = sp.Matrix([sp.cos(phi), sp.sin(phi)])
    e_lat = sp.Matrix([-sp.sin(phi), sp.cos(phi)])
    P = sp.Matrix([sigma * l / 2, s * b / 2])
    c = P + s * a * e_lat
    return {"phi": phi, "e_long": e_long, "e_lat": e_lat, "P": P, "c": c, "s": s, "sigma": sigma}


def _simp(expr):
    return sp.trigsimp(sp.expand(expr))


# --- constraints (1), (2) -------------------------------------------------------------------------
@cache
def constraint_matrix() -> sp.ImmutableMatrix:
    """A(alpha) of (1)-(2), shape (8, 9): rows 0..3 lateral wheel-centre velocities
    ``e_lat . v_c,i``, rows 4..7 ``e_long . v_c,i - r beta_dot_i`` with
    ``v_c,i = (x_dot, y_dot) + gamma_dot (-c_iy, c_ix) - s_i a phi_dot_i e_long(phi_i)``.
    Symbols: alpha_l, alpha_r, l, b, a, r."""
    A = sp.zeros(8, 9)
    for i in range(4):
        w = wheel_geometry(i)
        e_long, e_lat, c = w["e_long"], w["e_lat"], w["c"]
        rot = sp.Matrix([-c[1], c[0]])  # velocity of c per unit yaw rate
        A[i, 0], A[i, 1] = e_lat
        A[i, 2] = _simp(e_lat.dot(rot))
        A[4 + i, 0], A[4 + i, 1] = e_long
        A[4 + i, 2] = _simp(e_long.dot(rot))
        # phi_dot_i = sigma_i alpha_dot_side; e_long . (-s a phi_dot e_long) = -s a sigma alpha_dot_side
        A[4 + i, 3 + SIDE_INDEX[i]] = -w["s"] * a * w["sigma"]
        A[4 + i, 5 + i] = -r
    return sp.ImmutableMatrix(A)


# --- ICR relation (6)-(8) ---------------------------------------------------------------------------
@cache
def f_icr() -> sp.ImmutableMatrix:
    """alpha = f_ICR(alpha_v) of (8), shape (2, 1), principal branch:
    ``(l/2)/tan(alpha_l) = (l/2)/tan(alpha_v) - b/2``, ``(l/2)/tan(alpha_r) = (l/2)/tan(alpha_v) + b/2``,
    written with atan2 so it is smooth at alpha_v = 0. Valid for |alpha_v| <= arctan(l/b), where
    alpha_l, alpha_r, alpha_v share the sign and lie in [-pi/2, pi/2]."""
    sv, cv = sp.sin(alpha_v), sp.cos(alpha_v)
    return sp.ImmutableMatrix([sp.atan2(l * sv, l * cv - b * sv), sp.atan2(l * sv, l * cv + b * sv)])


@cache
def f_icr_prime() -> sp.ImmutableMatrix:
    """d f_ICR / d alpha_v, shape (2, 1), in a form without the atan2 (smooth for all alpha_v)."""
    sv, cv = sp.sin(alpha_v), sp.cos(alpha_v)
    return sp.ImmutableMatrix([l**2 / ((l * cv - b * sv) ** 2 + l**2 * sv**2),
                               l**2 / ((l * cv + b * sv) ** 2 + l**2 * sv**2)])


# --- kinematic models (4), (10)-(13) --------------------------------------------------------------
def _chassis_and_steering_columns(k: int) -> tuple[sp.Matrix, sp.Matrix]:
    if k == 1:
        return sp.zeros(3, 2), sp.eye(2)
    if k == 2:
        fp = f_icr_prime()
        H_ch = sp.Matrix([[0, 1], [0, 0], [0, 2 * sp.tan(alpha_v) / l]])
        H_alpha = sp.Matrix([[fp[0], 0], [fp[1], 0]])
        return H_ch, H_alpha
    if k == 3:
        return sp.Matrix([0, 1, 0]), sp.zeros(2, 1)
    if k == 4:
        return sp.Matrix([0, 0, 1]), sp.zeros(2, 1)
    raise ValueError(f"motion mode k must be one of {MODES}, got {k!r}")


@cache
def H(k: int) -> sp.ImmutableMatrix:
    """H_k(alpha) of (4), shape (9, n_k) with n_k = 2, 2, 1, 1 for k = 1..4, q_dot = H_k s_dot_k.

    Chassis and steering rows follow (10)-(13) (k=2: y_dot = 0, gamma_dot = x_dot tan(alpha_v)/(l/2),
    alpha_dot = f_ICR'(alpha_v) alpha_v_dot); the beta rows solve the longitudinal constraints
    (rows 4..7 of A) exactly for any alpha. The lateral constraints hold only in mode k's
    configuration (k=2: alpha = f_ICR(alpha_v); k=3, 4: the fixed angles of (9)). Symbols: alpha_l,
    alpha_r (+ alpha_v for k=2), l, b, a, r."""
    H_ch, H_alpha = _chassis_and_steering_columns(k)
    A = constraint_matrix()
    A_ch2, A_alpha2 = A[4:, 0:3], A[4:, 3:5]
    H_beta = ((A_ch2 * H_ch + A_alpha2 * H_alpha) / r).applyfunc(sp.expand)  # A_beta,2 = -r I
    return sp.ImmutableMatrix(sp.Matrix.vstack(H_ch, H_alpha, H_beta))


@cache
def H_dot(k: int) -> sp.ImmutableMatrix:
    """Time derivative of H_k for (20), shape (9, n_k):
    ``sum_j dH_k/d alpha_j alpha_j_dot (+ dH_k/d alpha_v alpha_v_dot for k=2)``.
    For k=2 the caller supplies alpha_dot = f_ICR'(alpha_v) alpha_v_dot (consistent rates)."""
    Hk = H(k)
    Hd = Hk.diff(alpha_l) * alpha_l_dot + Hk.diff(alpha_r) * alpha_r_dot
    if k == 2:
        Hd += Hk.diff(alpha_v) * alpha_v_dot
    return sp.ImmutableMatrix(Hd)


# --- dynamics (15)-(18) ---------------------------------------------------------------------------
@cache
def regressor() -> sp.ImmutableMatrix:
    """Regressor Y(q, q_dot, q_ddot), shape (9, 11), with Theta(q, q_dot, q_ddot) p = Y p (16), p (18).
    Coulomb friction ``d_c tanh(v / eps)``. Symbols: qd, qdd, eps (Y does not depend on q)."""
    xd, yd, gd = qd[0], qd[1], qd[2]
    Y = sp.zeros(9, 11)
    j = {n: i for i, n in enumerate(PARAMETER_NAMES)}
    Y[0, j["m_ch"]] = qdd[0] - yd * gd
    Y[1, j["m_ch"]] = qdd[1] + xd * gd
    for name in ("C_ch", "C_l", "C_r"):
        Y[2, j[name]] = qdd[2]
    for row, side in ((3, "l"), (4, "r")):
        Y[row, j["C_" + side]] = qdd[row]
        Y[row, j["d_v" + side]] = qd[row]
        Y[row, j["d_c" + side]] = sp.tanh(qd[row] / eps)
    for row in range(5, 9):
        Y[row, j["B_w"]] = qdd[row]
        Y[row, j["d_vw"]] = qd[row]
        Y[row, j["d_cw"]] = sp.tanh(qd[row] / eps)
    return sp.ImmutableMatrix(Y)


@cache
def Theta_p() -> sp.ImmutableMatrix:
    """Left-hand side Theta(q, q_dot, q_ddot) p of (15)/(16), shape (9, 1)."""
    return sp.ImmutableMatrix(regressor() * p)


@cache
def input_matrix() -> sp.ImmutableMatrix:
    """B(q) of (17), shape (9, 4): zeros for the 5 chassis/steering rows, i_G I_4 on the beta rows;
    B u = (0, 0, 0, 0, 0, i_G M_mot) with u the motor-side torques."""
    return sp.ImmutableMatrix(sp.Matrix.vstack(sp.zeros(5, 4), i_G * sp.eye(4)))


@cache
def mass_matrix() -> sp.ImmutableMatrix:
    """M(p) of (14), shape (9, 9): d(Theta p)/d q_ddot (constant, diagonal)."""
    return sp.ImmutableMatrix(Theta_p().jacobian(qdd))


@cache
def nonlinear_terms() -> sp.ImmutableMatrix:
    """g(q, q_dot, p) of (14), shape (9, 1): Theta p - M q_ddot (centripetal terms and friction)."""
    return sp.ImmutableMatrix((Theta_p() - mass_matrix() * qdd).applyfunc(sp.expand))


# --- reduced equations (19), (20) ---------------------------------------------------------------
@cache
def reduced_regressor(k: int) -> sp.ImmutableMatrix:
    """H_k^T Y of (19), shape (n_k, 11)."""
    return sp.ImmutableMatrix(H(k).T * regressor())


@cache
def reduced_input_matrix(k: int) -> sp.ImmutableMatrix:
    """H_k^T B of (19)/(21), shape (n_k, 4)."""
    return sp.ImmutableMatrix(H(k).T * input_matrix())


def s_dot(k: int) -> sp.ImmutableMatrix:
    """Symbols of the generalized velocities s_dot_k (10)-(13), shape (n_k, 1)."""
    names = GENERALIZED_VELOCITY_NAMES[k] if k in MODES else None
    if names is None:
        raise ValueError(f"motion mode k must be one of {MODES}, got {k!r}")
    table = {str(s): s for s in (*qd, alpha_v_dot)}
    return sp.ImmutableMatrix([table[n] for n in names])


@cache
def reduced_mass_matrix(k: int) -> sp.ImmutableMatrix:
    """H_k^T M H_k, shape (n_k, n_k): the reduced inertia of (19) with (20) inserted."""
    return sp.ImmutableMatrix(H(k).T * mass_matrix() * H(k))


__all__ = [
    "PARAMETER_NAMES", "WHEELS", "SIDE_SIGN", "FRONT_SIGN", "SIDE_INDEX", "COORDINATE_NAMES",
    "GENERALIZED_VELOCITY_NAMES", "MODES", "GEOMETRY_SYMBOLS",
    "l", "b", "a", "r", "i_G", "eps", "q", "qd", "qdd", "alpha", "alpha_dot", "alpha_v", "alpha_v_dot",
    "p", "u", "wheel_geometry", "constraint_matrix", "f_icr", "f_icr_prime", "H", "H_dot", "regressor",
    "Theta_p", "input_matrix", "mass_matrix", "nonlinear_terms", "reduced_regressor",
    "reduced_input_matrix", "reduced_mass_matrix", "s_dot",
]
