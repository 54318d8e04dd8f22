"""Identifiability of p (18) per motion mode: the paper's Section 6.1 and Table 1.

The stacked regressor Theta-hat of (22) is filled with random generalized velocities and
accelerations (and, in mode 2, random alpha_v with alpha = f_ICR(alpha_v); in mode 1 random
independent alpha; otherwise the fixed configuration of (9)), and a QR decomposition (Gautier 1991)
tells which columns are linearly independent.

Which member of a set of collinear columns counts as "independent" is a choice: the QR keeps the
first in a priority order. Columns are normalized to unit norm (scale-free tolerance); the numerical
rank is cross-checked with scipy's column-pivoted QR. The default priority
:data:`TABLE1_PRIORITY` reproduces the paper's Table 1: chassis parameters before steering parameters
(in rotation the yaw inertia C_ch + C_l + C_r is attributed to C_ch), B_w (the data-sheet value, p_2 of
(23)-(24)) last. Taking p's own order (18) instead would report C_l rather than C_ch for mode 4.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from qomni.ident import dynamics as _dyn
from qomni.ident import kinematics as _kin
from qomni.ident.symbolic import PARAMETER_NAMES

TABLE1_PRIORITY = ("m_ch", "C_ch", "C_l", "d_vl", "d_cl", "C_r", "d_vr", "d_cr", "d_vw", "d_cw", "B_w")
"""Column priority of the QR: among collinear columns the first one listed is kept."""

STRAIGHT = "2s"
"""Mode spec of the straight special case of mode 2 (alpha_v = alpha_v_dot = alpha_v_ddot = 0)."""

TABLE1_ROWS = (
    ("1", (1,)),
    ("2", (2,)),
    ("3", (3,)),
    ("4", (4,)),
    ("2 (alpha_v=0)", (STRAIGHT,)),
    ("1, 2 (alpha_v=0), 4", (1, STRAIGHT, 4)),
)
"""Rows of the paper's Table 1: label and the mode specs whose data are stacked."""

DEFAULT_TOL = 1e-8
"""Threshold on |R_jj| of the column-normalized QR below which a column is dependent."""


@dataclass(frozen=True)
class Identifiability:
    """Result of the QR analysis of a stacked regressor Theta-hat (22).

    Attributes:
        modes: the mode specs the data came from (1..4 or ``"2s"``).
        independent: names of the independent parameters p_1, in the order of p (18).
        dependent: names of the other parameters p_2 (collinear or not excited), order of p.
        rank: numerical rank of Theta-hat (column-pivoted QR).
        kappa: (len(independent), len(dependent)) with Theta_2 = Theta_1 kappa (23); base
            parameters p_B = p_1 + kappa p_2.
    """

    modes: tuple
    independent: tuple[str, ...]
    dependent: tuple[str, ...]
    rank: int
    kappa: np.ndarray

    def base_parameters(self, p) -> np.ndarray:
        """p_B = p_1 + kappa p_2 of Section 6.3 for a full p (11,), shape (len(independent),)."""
        p = np.asarray(p, dtype=float)
        if p.shape != (len(PARAMETER_NAMES),):
            raise ValueError(f"p must have shape ({len(PARAMETER_NAMES)},), got {p.shape}")
        idx = {n: j for j, n in enumerate(PARAMETER_NAMES)}
        p1 = p[[idx[n] for n in self.independent]]
        p2 = p[[idx[n] for n in self.dependent]]
        return p1 + self.kappa @ p2


def random_regressor(mode, geometry, n_samples: int = 200, rng=None, eps: float = _dyn.EPS,
                     scale: float = 1.0) -> np.ndarray:
    """Theta-hat of (22) for one mode filled with random data, shape (n_samples * n_k, 11).

    Args:
        mode: 1, 2, 3, 4 or ``"2s"`` (straight: mode 2 with alpha_v identically 0).
        geometry: l, b, a, r.
        n_samples: number of random samples.
        rng: numpy Generator or seed.
        eps: tanh smoothing, rad/s.
        scale: standard deviation of the random s_dot, s_ddot (SI).
    Raises:
        ValueError: unknown mode spec.
    """
    rng = np.random.default_rng(rng)
    q = np.zeros((n_samples, 9))
    alpha_v = None
    if mode == 1:
        q[:, 3:5] = rng.uniform(-np.pi / 2, np.pi / 2, (n_samples, 2))
    elif mode == 2:
        alpha_v = rng.uniform(-0.95, 0.95, n_samples) * _kin.alpha_v_max(geometry)
        q[:, 3:5] = _kin.f_icr(alpha_v, geometry)
    elif mode in (3, 4):
        q[:, 3:5] = _kin.mode_alpha(mode, geometry)
    elif mode != STRAIGHT:
        raise ValueError(f"mode must be one of 1, 2, 3, 4, {STRAIGHT!r}; got {mode!r}")
    k = 2 if mode == STRAIGHT else mode
    nk = _kin.N_GENERALIZED[k]
    sd = scale * rng.standard_normal((n_samples, nk))
    sdd = scale * rng.standard_normal((n_samples, nk))
    if mode == STRAIGHT:
        alpha_v = np.zeros(n_samples)
        sd[:, 0] = sdd[:, 0] = 0.0
    qd, qdd = _dyn.generalized_state(k, q, sd, sdd, geometry, alpha_v=alpha_v)
    Yk = _dyn.reduced_regressor(k, q, qd, qdd, geometry, eps=eps, alpha_v=alpha_v)
    return Yk.reshape(-1, Yk.shape[-1])


def independent_parameters(theta_hat, priority=TABLE1_PRIORITY, tol: float = DEFAULT_TOL,
                           modes: tuple = ()) -> Identifiability:
    """Base-parameter analysis of Theta-hat (22) by QR (Gautier 1991).

    Columns are scaled to unit norm (all-zero columns are not excited and dependent); an unpivoted
    QR of the columns in ``priority`` order marks column j independent if |R_jj| > tol. The count is
    checked against the rank from scipy's column-pivoted QR.

    Args:
        theta_hat: (rows, 11) (or (N, n_k, 11)), columns in the order of p (18).
        priority: the 11 parameter names, most preferred first.
        tol: threshold on the normalized |R_jj|.
    Raises:
        ValueError: bad shape, priority not a permutation of the names, or the two rank estimates
            disagree (ill-conditioned data: change tol or the data).
    """
    X = np.asarray(theta_hat, dtype=float)
    X = X.reshape(-1, X.shape[-1])
    if X.shape[1] != len(PARAMETER_NAMES):
        raise ValueError(f"theta_hat needs {len(PARAMETER_NAMES)} columns, got {X.shape[1]}")
    if sorted(priority) != sorted(PARAMETER_NAMES):
        raise ValueError(f"priority must be a permutation of {PARAMETER_NAMES}, got {priority}")
    norms = np.linalg.norm(X, axis=0)
    excited = norms > 1e-12 * max(norms.max(), 1e-300)
    Xn = np.where(excited, X / np.where(excited, norms, 1.0), 0.0)
    order = [PARAMETER_NAMES.index(name) for name in priority]
    R = scipy.linalg.qr(Xn[:, order], mode="r")[0]
    diag = np.abs(np.diag(R)) if R.shape[0] >= R.shape[1] else np.r_[np.abs(np.diag(R)),
                                                                          np.zeros(R.shape[1] - R.shape[0])]
    chosen = {order[j] for j in range(len(order)) if diag[j] > tol and excited[order[j]]}
    Rp = scipy.linalg.qr(Xn, mode="r", pivoting=True)[0]
    rank = int(np.sum(np.abs(np.diag(Rp)) > tol))
    if rank != len(chosen):
        raise ValueError(f"rank from pivoted QR ({rank}) differs from the ordered QR ({len(chosen)}); "
                         f"the data are ill-conditioned for tol={tol}")
    ind = [j for j in range(X.shape[1]) if j in chosen]
    dep = [j for j in range(X.shape[1]) if j not in chosen]
    if ind and dep:
        kappa = np.linalg.lstsq(X[:, ind], X[:, dep], rcond=None)[0]
        kappa[np.abs(kappa) < 1e-9 * max(1.0, np.abs(kappa).max())] = 0.0
    else:
        kappa = np.zeros((len(ind), len(dep)))
    return Identifiability(modes=tuple(modes), independent=tuple(PARAMETER_NAMES[j] for j in ind),
                           dependent=tuple(PARAMETER_NAMES[j] for j in dep), rank=rank, kappa=kappa)


def analyse(modes, geometry=None, n_samples: int = 200, seed: int = 0, eps: float = _dyn.EPS,
            tol: float = DEFAULT_TOL, priority=TABLE1_PRIORITY) -> Identifiability:
    """Identifiability for a set of modes: random Theta-hat of each (:func:`random_regressor`),
    stacked, analysed by :func:`independent_parameters`. ``geometry`` defaults to the packaged
    prototype data sheet; ``eps = 0`` uses sign() for Coulomb friction."""
    if geometry is None:
        from qomni.datasheet import DataSheet
        geometry = DataSheet.load().geometry
    rng = np.random.default_rng(seed)
    theta = np.vstack([random_regressor(m, geometry, n_samples, rng, eps=eps) for m in modes])
    return independent_parameters(theta, priority=priority, tol=tol, modes=tuple(modes))


def table1(geometry=None, n_samples: int = 200, seed: int = 0, eps: float = _dyn.EPS,
           tol: float = DEFAULT_TOL, priority=TABLE1_PRIORITY) -> dict[str, Identifiability]:
    """The paper's Table 1: label -> :class:`Identifiability` for each row of :data:`TABLE1_ROWS`."""
    return {label: analyse(modes, geometry, n_samples, seed, eps, tol, priority)
            for label, modes in TABLE1_ROWS}


__all__ = ["TABLE1_PRIORITY", "TABLE1_ROWS", "STRAIGHT", "DEFAULT_TOL", "Identifiability",
           "random_regressor", "independent_parameters", "analyse", "table1"]
