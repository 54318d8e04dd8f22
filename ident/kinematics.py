"""Numeric kinematics, vectorized over N samples: constraints (1)-(2), ICR relation (6)-(8), motion
modes (9), kinematic models (4) with their time derivative for (20).

The matrices are generated from :mod:`ident.symbolic` with ``sympy.lambdify`` (numpy, common
subexpressions) the first time they are used and cached; the small scalar relations (f_ICR, its
inverse, mode detection) are written out in numpy and tested equal to the symbolic source.

Shapes: ``alpha`` (N, 2) = (alpha_l, alpha_r) in rad (a single (2,) sample is accepted as N = 1);
``alpha_v`` (N,) or scalar; outputs carry the leading N. ``geometry`` is any object with attributes
``l, b, a, r`` in m (e.g. :class:`ident.datasheet.Geometry`). Conventions: docs/conventions.md.
"""
from __future__ import annotations

from functools import cache

import numpy as np

from qomni.datasheet import Geometry

N_GENERALIZED = {1: 2, 2: 2, 3: 1, 4: 1}
"""Number n_k of generalized velocities s_dot_k (10)-(13) per motion mode k."""
MODES = (1, 2, 3, 4)
DEFAULT_MODE_TOL = 1e-3
"""rad; default tolerance of :func:`motion_mode` (~3 LSB of a 14-bit steering sensor)."""


# --- argument handling -----------------------------------------------------------------------------
def _geometry(geometry) -> tuple[float, float, float, float]:
    try:
        return float(geometry.l), float(geometry.b), float(geometry.a), float(geometry.r)
    except AttributeError as exc:
        raise TypeError(f"geometry needs attributes l, b, a, r; got {geometry!r}") from exc


def _samples(x, width: int, name: str) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim == 1 and x.shape[0] == width:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != width:
        raise ValueError(f"{name} must have shape (N, {width}), got {x.shape}")
    return x


def _per_sample(x, n: int, name: str) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim == 0:
        return np.full(n, float(x))
    x = x.reshape(-1) if x.ndim == 2 and x.shape[1] == 1 else x
    if x.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) or be a scalar, got {x.shape}")
    return x


def _check_mode(k) -> int:
    if k not in MODES:
        raise ValueError(f"motion mode k must be one of {MODES}, got {k!r}")
    return int(k)


# --- lambdified symbolic matrices -------------------------------------------------------------------
def _compile(matrix, args):
    import sympy as sp

    rows, cols = matrix.shape
    fn = sp.lambdify(args, list(matrix), modules="numpy", cse=True)
    # One sample (the controller's every cycle): the same expressions on Python floats, where numpy's
    # per-call overhead on (1,) arrays would cost several times the arithmetic. A float division by zero
    # raises there; that sample then goes through numpy, which gives inf or nan as for N samples.
    scalar = sp.lambdify(args, list(matrix), modules="math", cse=True)

    def evaluate(n: int, *values) -> np.ndarray:
        if n == 1:
            try:
                return np.array(scalar(*(float(v[0]) if isinstance(v, np.ndarray) else float(v)
                                         for v in values)), dtype=float).reshape(1, rows, cols)
            except (ZeroDivisionError, ValueError, OverflowError):
                pass
        out = np.empty((n, rows * cols))
        with np.errstate(divide="ignore", invalid="ignore"):
            for j, entry in enumerate(fn(*values)):
                out[:, j] = entry
        return out.reshape(n, rows, cols)

    return evaluate


@cache
def _compiled(name: str, k: int = 0):
    from qomni.ident import symbolic as S

    geo = S.GEOMETRY_SYMBOLS
    if name == "A":
        return _compile(S.constraint_matrix(), (S.alpha_l, S.alpha_r, *geo))
    if name == "H":
        return _compile(S.H(k), (S.alpha_l, S.alpha_r, S.alpha_v, *geo))
    if name == "H_dot":
        return _compile(S.H_dot(k), (S.alpha_l, S.alpha_r, S.alpha_v, S.alpha_l_dot, S.alpha_r_dot,
                                     S.alpha_v_dot, *geo))
    raise KeyError(name)


# --- constraints (1), (2) ---------------------------------------------------------------------------
def constraint_matrix(alpha, geometry) -> np.ndarray:
    """A(alpha) of (1)-(2).

    Args:
        alpha: (N, 2) steering angles (alpha_l, alpha_r), rad.
        geometry: object with l, b, a, r (m).
    Returns:
        (N, 8, 9): rows 0..3 lateral, 4..7 longitudinal constraints (wheel order fl, rl, fr, rr);
        columns q = (x_ch, y_ch, gamma_ch, alpha_l, alpha_r, beta_fl, beta_rl, beta_fr, beta_rr).
        Partition (2): A_ch = A[:, :, :3], A_alpha = A[:, :, 3:5], A_beta = A[:, :, 5:].
    Raises:
        ValueError: wrong shape of ``alpha``.
    """
    alpha = _samples(alpha, 2, "alpha")
    return _compiled("A")(alpha.shape[0], alpha[:, 0], alpha[:, 1], *_geometry(geometry))


def constraint_residual(alpha, qd, geometry) -> np.ndarray:
    """A(alpha) q_dot of (1), shape (N, 8), m/s: zero for rolling without slip; rows as in
    :func:`constraint_matrix`. ``qd`` is (N, 9) (chassis velocities in the chassis frame)."""
    alpha = _samples(alpha, 2, "alpha")
    qd = _samples(qd, 9, "qd")
    if qd.shape[0] != alpha.shape[0]:
        raise ValueError(f"alpha and qd need the same N, got {alpha.shape[0]} and {qd.shape[0]}")
    return np.einsum("nij,nj->ni", constraint_matrix(alpha, geometry), qd)


# --- ICR relation (6)-(8) -----------------------------------------------------------------------
def alpha_v_max(geometry) -> float:
    """Largest |alpha_v| of mode 2, arctan(l/b) rad: there the inner wheels reach +-pi/2 (the stops)."""
    l, b, _, _ = _geometry(geometry)
    return float(np.arctan2(l, b))


def f_icr(alpha_v, geometry) -> np.ndarray:
    """alpha = f_ICR(alpha_v) of (6)-(8): steering angles that hold the ICR at (0, (l/2)/tan alpha_v).

    ``(l/2)/tan alpha_l = (l/2)/tan alpha_v - b/2``, ``(l/2)/tan alpha_r = (l/2)/tan alpha_v + b/2``;
    alpha_v = 0 gives alpha = 0; alpha_l, alpha_r have the sign of alpha_v and lie in [-pi/2, pi/2].

    Args:
        alpha_v: (N,) or scalar virtual steering angle, rad, |alpha_v| <= arctan(l/b).
    Returns:
        (N, 2) (alpha_l, alpha_r), rad.
    Raises:
        ValueError: |alpha_v| > arctan(l/b) (an inner wheel would pass its stop at pi/2).
    """
    l, b, _, _ = _geometry(geometry)
    return f_icr_lb(alpha_v, l, b)


def f_icr_lb(alpha_v, l: float, b: float) -> np.ndarray:
    """:func:`f_icr` from the steering-axis distances ``l``, ``b`` (m) alone; shapes, units and errors as there."""
    av = np.atleast_1d(np.asarray(alpha_v, dtype=float)).reshape(-1)
    av_max = np.arctan2(l, b)
    if np.any(~(np.abs(av) <= av_max + 1e-12)):
        raise ValueError(f"alpha_v must satisfy |alpha_v| <= arctan(l/b) = {av_max:.6f} rad, "
                         f"got max |alpha_v| = {np.nanmax(np.abs(av)) if av.size else 0}")
    s, c = np.sin(av), np.cos(av)
    return np.stack([np.arctan2(l * s, l * c - b * s), np.arctan2(l * s, l * c + b * s)], axis=-1)


def f_icr_prime(alpha_v, geometry) -> np.ndarray:
    """d f_ICR / d alpha_v, shape (N, 2), dimensionless (equals 1 at alpha_v = 0)."""
    l, b, _, _ = _geometry(geometry)
    av = np.atleast_1d(np.asarray(alpha_v, dtype=float)).reshape(-1)
    s, c = np.sin(av), np.cos(av)
    return np.stack([l**2 / ((l * c - b * s) ** 2 + (l * s) ** 2),
                     l**2 / ((l * c + b * s) ** 2 + (l * s) ** 2)], axis=-1)


def alpha_v_from_alpha(alpha, geometry) -> np.ndarray:
    """Inverse of (8): virtual steering angle alpha_v from alpha, shape (N,), rad.

    Uses the mean of the path curvatures 1/R_v implied by the left and the right angle
    (``kappa_l = 2 sin a_l / (l cos a_l + b sin a_l)``, ``kappa_r = 2 sin a_r / (l cos a_r - b sin a_r)``),
    ``alpha_v = arctan(kappa l / 2)``; exact in mode 2, a least-squares-like compromise near it,
    meaningless (possibly nan or +-pi/2) far from mode 2 (e.g. in mode 4 where R_v = 0).
    """
    l, b, _, _ = _geometry(geometry)
    alpha = _samples(alpha, 2, "alpha")
    sl, cl, sr, cr = np.sin(alpha[:, 0]), np.cos(alpha[:, 0]), np.sin(alpha[:, 1]), np.cos(alpha[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = (2 * sl / (l * cl + b * sl) + 2 * sr / (l * cr - b * sr)) / 2
        return np.arctan(kappa * l / 2)


def icr_residual(alpha, geometry) -> np.ndarray:
    """Distance of alpha from the mode-2 manifold f_ICR,lr(alpha) = 0 of (9), shape (N,), rad:
    ``max |alpha - f_ICR(alpha_v_from_alpha(alpha))|``; +inf where no admissible alpha_v exists."""
    alpha = _samples(alpha, 2, "alpha")
    av = alpha_v_from_alpha(alpha, geometry)
    ok = np.abs(av) <= alpha_v_max(geometry) + 1e-12  # False for nan
    res = np.full(alpha.shape[0], np.inf)
    if np.any(ok):
        res[ok] = np.max(np.abs(alpha[ok] - f_icr(av[ok], geometry)), axis=1)
    return res


# --- motion modes (9) ---------------------------------------------------------------------------
def mode_alpha(k: int, geometry, alpha_v: float = 0.0) -> np.ndarray:
    """Steering angles of the configuration of mode k per (9), shape (2,), rad:
    k = 2: f_ICR(alpha_v) (straight for alpha_v = 0); k = 3: (-pi/2, +pi/2); k = 4: arctan(l/b)(-1, +1).

    Raises:
        ValueError: k = 1 (any alpha off the other configurations) or k not in 1..4.
    """
    k = _check_mode(k)
    if k == 1:
        raise ValueError("mode 1 has no fixed configuration: alpha_l, alpha_r are free")
    if k == 2:
        return f_icr(alpha_v, geometry)[0]
    if k == 3:
        return np.array([-np.pi / 2, np.pi / 2])
    t = alpha_v_max(geometry)
    return np.array([-t, t])


def motion_mode(alpha, geometry, tol: float = DEFAULT_MODE_TOL) -> np.ndarray:
    """Motion mode k of (9) for each sample, shape (N,), int in 1..4.

    k = 3 if max|alpha - (-pi/2, pi/2)| <= tol; else k = 4 if max|alpha - arctan(l/b)(-1, 1)| <= tol;
    else k = 2 if :func:`icr_residual` <= tol (includes straight, alpha = 0); else k = 1.

    Args:
        alpha: (N, 2) rad. tol: rad, >= 0.
    Raises:
        ValueError: bad shape or negative tol.
    """
    if not tol >= 0:
        raise ValueError(f"tol must be >= 0, got {tol!r}")
    alpha = _samples(alpha, 2, "alpha")
    k = np.ones(alpha.shape[0], dtype=int)
    k[icr_residual(alpha, geometry) <= tol] = 2
    k[np.max(np.abs(alpha - mode_alpha(4, geometry)), axis=1) <= tol] = 4
    k[np.max(np.abs(alpha - mode_alpha(3, geometry)), axis=1) <= tol] = 3
    return k


# --- kinematic models (4), (20) -------------------------------------------------------------------
def _alpha_v_for(k, alpha, geometry, alpha_v):
    n = alpha.shape[0]
    if k != 2:
        return np.zeros(n)
    if alpha_v is None:
        return alpha_v_from_alpha(alpha, geometry)
    return _per_sample(alpha_v, n, "alpha_v")


def H(k: int, alpha, geometry, alpha_v=None) -> np.ndarray:
    """Kinematic model H_k(alpha) of (4): q_dot = H_k s_dot_k with s_dot_k of (10)-(13).

    Args:
        k: motion mode 1..4 (s_dot_1 = (alpha_l_dot, alpha_r_dot), s_dot_2 = (alpha_v_dot, x_ch_dot),
            s_dot_3 = y_ch_dot, s_dot_4 = gamma_ch_dot).
        alpha: (N, 2) steering angles, rad. For k = 3, 4 the measured angles are used in the beta rows;
            pass :func:`mode_alpha` for the ideal configuration.
        alpha_v: k = 2 only, (N,) or scalar, rad; default :func:`alpha_v_from_alpha` (alpha).
    Returns:
        (N, 9, n_k). The longitudinal constraints hold for any alpha; A H_k = 0 holds in mode k's
        configuration (k = 2: alpha = f_ICR(alpha_v)).
    Raises:
        ValueError: k not in 1..4 or bad shapes.
    """
    k = _check_mode(k)
    alpha = _samples(alpha, 2, "alpha")
    av = _alpha_v_for(k, alpha, geometry, alpha_v)
    return _compiled("H", k)(alpha.shape[0], alpha[:, 0], alpha[:, 1], av, *_geometry(geometry))


def H_dot(k: int, alpha, alpha_dot, geometry, alpha_v=None, alpha_v_dot=None) -> np.ndarray:
    """Time derivative of H_k for (20): q_ddot = H_dot_k s_dot_k + H_k s_ddot_k.

    Args:
        alpha: (N, 2) rad; alpha_dot: (N, 2) rad/s.
        alpha_v, alpha_v_dot: k = 2 only, (N,) or scalar (rad, rad/s); defaults: alpha_v from alpha,
            alpha_v_dot the least-squares solution of alpha_dot = f_ICR'(alpha_v) alpha_v_dot.
    Returns:
        (N, 9, n_k): units of H_k per second (zero for k = 1; for k = 3, 4 zero when alpha_dot = 0).
    Raises:
        ValueError: k not in 1..4 or bad shapes.
    """
    k = _check_mode(k)
    alpha = _samples(alpha, 2, "alpha")
    alpha_dot = _samples(alpha_dot, 2, "alpha_dot")
    n = alpha.shape[0]
    if alpha_dot.shape[0] != n:
        raise ValueError(f"alpha and alpha_dot need the same N, got {n} and {alpha_dot.shape[0]}")
    av = _alpha_v_for(k, alpha, geometry, alpha_v)
    if k != 2:
        avd = np.zeros(n)
    elif alpha_v_dot is None:
        fp = f_icr_prime(av, geometry)
        avd = np.sum(fp * alpha_dot, axis=1) / np.sum(fp * fp, axis=1)
    else:
        avd = _per_sample(alpha_v_dot, n, "alpha_v_dot")
    return _compiled("H_dot", k)(n, alpha[:, 0], alpha[:, 1], av, alpha_dot[:, 0], alpha_dot[:, 1],
                                 avd, *_geometry(geometry))


def sdot_from_qdot(k: int, alpha, qd, geometry, alpha_v=None) -> np.ndarray:
    """Generalized velocities s_dot_k (10)-(13) from q_dot, shape (N, n_k): k = 1 (alpha_l_dot,
    alpha_r_dot); k = 2 (alpha_v_dot, x_ch_dot) with alpha_v_dot the least-squares fit of
    alpha_dot = f_ICR'(alpha_v) alpha_v_dot; k = 3 y_ch_dot; k = 4 gamma_ch_dot."""
    k = _check_mode(k)
    alpha = _samples(alpha, 2, "alpha")
    qd = _samples(qd, 9, "qd")
    if k == 1:
        return qd[:, 3:5].copy()
    if k == 3:
        return qd[:, 1:2].copy()
    if k == 4:
        return qd[:, 2:3].copy()
    av = _alpha_v_for(2, alpha, geometry, alpha_v)
    fp = f_icr_prime(av, geometry)
    avd = np.sum(fp * qd[:, 3:5], axis=1) / np.sum(fp * fp, axis=1)
    return np.stack([avd, qd[:, 0]], axis=1)


__all__ = [
    "Geometry", "MODES", "N_GENERALIZED", "DEFAULT_MODE_TOL", "constraint_matrix", "constraint_residual",
    "alpha_v_max", "f_icr", "f_icr_lb", "f_icr_prime", "alpha_v_from_alpha", "icr_residual", "mode_alpha",
    "motion_mode", "H", "H_dot", "sdot_from_qdot",
]
