"""Rest-to-rest excitation trajectories: finite Fourier series and analytic profiles (generic, no vehicle).

A finite Fourier series (Swevers et al. 1997 form)

    q(t)   = q0 + Σ_k [ a_k/(k ω_f) sin(k ω_f t) − b_k/(k ω_f) cos(k ω_f t) ]
    q̇(t)  = Σ_k [ a_k cos(k ω_f t) + b_k sin(k ω_f t) ]
    q̈(t)  = Σ_k k ω_f [ −a_k sin(k ω_f t) + b_k cos(k ω_f t) ]

over an integer number of periods T = periods · 2π/ω_f, so q(T) = q(0). The rest conditions
q̇(0) = q̇(T) = 0 and q̈(0) = q̈(T) = 0 are the linear constraints Σ a_k = 0 and Σ k b_k = 0 on the
coefficients; q0 is chosen so that q(0) = q_start. Outside [0, T] a trajectory holds q_start at rest.

Design (:func:`design_fourier_trajectory`): random harmonics from a seed, projected onto the
null space of the rest constraints, refined by Nelder–Mead (scipy.optimize) to minimise the condition
number of the column-normalised simple regressor [q̈, q̇, sign(q̇)] (the structure of one steering or
wheel row of (16)), and finally scaled as large as the position, velocity and acceleration limits
allow. The normalised condition number is scale invariant, so richness and amplitude are decoupled.

The paper's campaign steps built from these are in :mod:`qomni.ident.excitation`. All quantities SI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping, Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy import linalg, optimize

__all__ = ["Trajectory", "FourierTrajectory", "AnalyticTrajectory", "design_fourier_trajectory"]

_REST_TOL = 1e-9


class Trajectory(Protocol):
    """Anything with a duration (s) and ``evaluate(t) -> (q, q̇, q̈)``."""

    duration: float

    def evaluate(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...


# --------------------------------------------------------------------------------------------
# Finite Fourier series
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FourierTrajectory:
    """Finite Fourier series trajectory that starts and ends at rest.

    Parameters
    ----------
    omega_f : float
        Fundamental angular frequency ω_f (rad/s), > 0.
    a, b : array_like, shape (n_h,)
        Sine/cosine coefficients of the *velocity* series (unit of q per s), harmonics k = 1..n_h.
        Must satisfy the rest conditions Σ a_k = 0 and Σ k b_k = 0.
    q0 : float
        Offset of the position series (unit of q).
    periods : int
        Number of fundamental periods; duration T = periods · 2π/ω_f.

    Raises
    ------
    ValueError
        If ω_f ≤ 0, periods < 1, the coefficient shapes differ, or the rest conditions are violated.
    """

    omega_f: float
    a: np.ndarray
    b: np.ndarray
    q0: float = 0.0
    periods: int = 1

    def __post_init__(self) -> None:
        a = np.asarray(self.a, dtype=float).reshape(-1)
        b = np.asarray(self.b, dtype=float).reshape(-1)
        if a.shape != b.shape or a.size == 0:
            raise ValueError(f"a and b must be non-empty with equal shapes, got {a.shape}, {b.shape}")
        if not (self.omega_f > 0 and math.isfinite(self.omega_f)):
            raise ValueError(f"omega_f must be positive and finite, got {self.omega_f}")
        if int(self.periods) != self.periods or self.periods < 1:
            raise ValueError(f"periods must be a positive integer, got {self.periods}")
        k = np.arange(1, a.size + 1)
        scale = max(float(np.max(np.abs(np.concatenate([a, k * b])))), 1.0)
        if abs(a.sum()) > _REST_TOL * scale or abs((k * b).sum()) > _REST_TOL * scale:
            raise ValueError(
                "coefficients violate the rest conditions sum(a) = 0 and sum(k*b) = 0 "
                f"(got {a.sum():.3e}, {(k * b).sum():.3e}); use project_to_rest()"
            )
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "q0", float(self.q0))
        object.__setattr__(self, "periods", int(self.periods))

    @property
    def n_harmonics(self) -> int:
        return int(self.a.size)

    @property
    def duration(self) -> float:
        """T = periods · 2π/ω_f (s)."""
        return self.periods * 2.0 * math.pi / self.omega_f

    @property
    def q_start(self) -> float:
        """Position at t = 0 and t = T: q0 − Σ b_k/(k ω_f)."""
        k = np.arange(1, self.n_harmonics + 1)
        return float(self.q0 - np.sum(self.b / (k * self.omega_f)))

    @staticmethod
    def rest_constraint_matrix(n_harmonics: int) -> np.ndarray:
        """Matrix G, shape (2, 2 n_h), with G @ [a; b] = (q̇(0), q̈(0)/ω_f)."""
        k = np.arange(1, n_harmonics + 1, dtype=float)
        g = np.zeros((2, 2 * n_harmonics))
        g[0, :n_harmonics] = 1.0
        g[1, n_harmonics:] = k
        return g

    @staticmethod
    def project_to_rest(a: ArrayLike, b: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Orthogonal projection of (a, b), shapes (n_h,), onto the rest conditions."""
        a = np.asarray(a, dtype=float).reshape(-1)
        b = np.asarray(b, dtype=float).reshape(-1)
        n = a.size
        ns = linalg.null_space(FourierTrajectory.rest_constraint_matrix(n))
        c = ns @ (ns.T @ np.concatenate([a, b]))
        return c[:n], c[n:]

    @classmethod
    def from_start(
        cls, omega_f: float, a: ArrayLike, b: ArrayLike, q_start: float = 0.0, periods: int = 1
    ) -> "FourierTrajectory":
        """Build with q0 chosen so that q(0) = q(T) = ``q_start``."""
        b_arr = np.asarray(b, dtype=float).reshape(-1)
        k = np.arange(1, b_arr.size + 1)
        q0 = q_start + float(np.sum(b_arr / (k * omega_f)))
        return cls(omega_f=omega_f, a=np.asarray(a, dtype=float), b=b_arr, q0=q0, periods=periods)

    def evaluate(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Analytic position, velocity and acceleration.

        Parameters
        ----------
        t : array_like, shape (N,) or scalar
            Time (s). Outside [0, T] the trajectory rests at ``q_start``.

        Returns
        -------
        q, q_dot, q_ddot : ndarray, each of the shape of ``t``.
        """
        t = np.asarray(t, dtype=float)
        tt = np.clip(t, 0.0, self.duration)
        k = np.arange(1, self.n_harmonics + 1)
        wk = k * self.omega_f
        ph = np.multiply.outer(tt, wk)
        s, c = np.sin(ph), np.cos(ph)
        q = self.q0 + s @ (self.a / wk) - c @ (self.b / wk)
        qd = c @ self.a + s @ self.b
        qdd = -s @ (self.a * wk) + c @ (self.b * wk)
        outside = (t < 0.0) | (t > self.duration)
        q = np.where(outside, self.q_start, q)
        qd = np.where(outside, 0.0, qd)
        qdd = np.where(outside, 0.0, qdd)
        return q, qd, qdd

    def position(self, t: ArrayLike) -> np.ndarray:
        return self.evaluate(t)[0]

    def velocity(self, t: ArrayLike) -> np.ndarray:
        return self.evaluate(t)[1]

    def acceleration(self, t: ArrayLike) -> np.ndarray:
        return self.evaluate(t)[2]

    def to_json_dict(self) -> dict:
        return {
            "type": "fourier",
            "omega_f": self.omega_f,
            "a": self.a.tolist(),
            "b": self.b.tolist(),
            "q0": self.q0,
            "periods": self.periods,
        }

    @classmethod
    def from_json_dict(cls, d: Mapping) -> "FourierTrajectory":
        return cls(
            omega_f=float(d["omega_f"]),
            a=np.asarray(d["a"], dtype=float),
            b=np.asarray(d["b"], dtype=float),
            q0=float(d["q0"]),
            periods=int(d.get("periods", 1)),
        )


def _basis(n_h: int, omega_f: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Matrices P, V, A, shape (N, 2 n_h), with q − q_start = P c, q̇ = V c, q̈ = A c, c = [a; b]."""
    k = np.arange(1, n_h + 1)
    wk = k * omega_f
    ph = np.multiply.outer(t, wk)
    s, c = np.sin(ph), np.cos(ph)
    p = np.hstack([s / wk, (1.0 - c) / wk])
    v = np.hstack([c, s])
    a = np.hstack([-s * wk, c * wk])
    return p, v, a


def _limit_scale(f: np.ndarray, qd: np.ndarray, qdd: np.ndarray, room_up: float, room_down: float,
                 qd_max: float, qdd_max: float) -> float:
    """Largest factor keeping f = q − q_start within [−room_down, room_up], |q̇| ≤ qd_max, |q̈| ≤ qdd_max;
    f, qd, qdd (N,) samples of one unscaled trajectory."""
    s = min(qd_max / np.max(np.abs(qd)), qdd_max / np.max(np.abs(qdd)))
    if f.max() > 0:
        s = min(s, room_up / f.max())
    if f.min() < 0:
        s = min(s, room_down / (-f.min()))
    return float(s)


def _richness_cond(qd: np.ndarray, qdd: np.ndarray) -> float:
    """Condition number of the column-normalised regressor [q̈, q̇, sign(q̇)], shape (N, 3)."""
    r = np.column_stack([qdd, qd, np.sign(qd)])
    nrm = np.linalg.norm(r, axis=0)
    if np.any(nrm == 0.0):
        return math.inf
    sv = np.linalg.svd(r / nrm, compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf


def design_fourier_trajectory(
    *,
    duration: float,
    q_min: float,
    q_max: float,
    qd_max: float,
    qdd_max: float,
    q_start: float = 0.0,
    n_harmonics: int = 6,
    periods: int = 1,
    seed: int = 0,
    optimize_richness: bool = True,
    n_candidates: int = 16,
    max_evaluations: int = 2000,
    margin: float = 0.995,
    stiction_fraction: float = 0.1,
    stiction_penalty: float = 3.0,
    amplitude_weight: float = 1.0,
) -> FourierTrajectory:
    """Design a rest-to-rest Fourier excitation within limits, deterministically from ``seed``.

    Parameters
    ----------
    duration : float
        Trajectory length T (s); ω_f = periods · 2π / T.
    q_min, q_max : float
        Position range (unit of q); ``q_min < q_start < q_max`` required.
    qd_max, qdd_max : float
        Limits on |q̇| (unit/s) and |q̈| (unit/s²), > 0.
    q_start : float
        Position at t = 0 and t = T.
    n_harmonics : int
        Number of harmonics n_h ≥ 2 (two degrees of freedom are used by the rest conditions).
    periods : int
        Number of repeated fundamental periods.
    seed : int
        Seed of the random initial harmonics (numpy default_rng) – same seed, same trajectory.
    optimize_richness : bool
        If True, refine the best of ``n_candidates`` random starts by Nelder–Mead on the design
        criterion below; otherwise use the best random candidate.
    stiction_fraction, stiction_penalty, amplitude_weight : float
        Design criterion (minimised), evaluated on one period:
        ``log cond(R_kept) + stiction_penalty · (1 − kept) − amplitude_weight · ½ log(u)``, where
        R = [q̈, q̇, sign q̇] column normalised over the samples with
        |q̇| ≥ stiction_fraction · max|q̇| (fraction ``kept``; the others are lost to the stiction
        threshold of the estimator), and u = RMS(q̇)·RMS(q̈)/(qd_max·qdd_max) after scaling to the
        limits (rewards using the velocity/acceleration budget rather than only the position range).
    max_evaluations : int
        Objective evaluation budget of the Nelder–Mead refinement.
    margin : float
        Fraction (0, 1] of the admissible scale actually used (guards grid sampling of extrema).

    Returns
    -------
    FourierTrajectory

    Raises
    ------
    ValueError
        On inconsistent limits (non-positive limits, q_start not strictly inside the range,
        n_harmonics < 2, duration ≤ 0).
    """
    if duration <= 0:
        raise ValueError(f"duration must be > 0, got {duration}")
    if n_harmonics < 2:
        raise ValueError("n_harmonics must be >= 2 (the rest conditions use two degrees of freedom)")
    if not (q_min < q_start < q_max):
        raise ValueError(f"need q_min < q_start < q_max, got {q_min}, {q_start}, {q_max}")
    if qd_max <= 0 or qdd_max <= 0:
        raise ValueError(f"velocity and acceleration limits must be > 0, got {qd_max}, {qdd_max}")
    if not 0 < margin <= 1:
        raise ValueError(f"margin must be in (0, 1], got {margin}")
    omega_f = periods * 2.0 * math.pi / duration
    n = n_harmonics
    k = np.arange(1, n + 1, dtype=float)
    ns = linalg.null_space(FourierTrajectory.rest_constraint_matrix(n))  # (2n, 2n-2)

    # Coarse grid for the objective, fine grid for the limit scaling.
    n_coarse = int(max(400, 30 * n * periods))
    n_fine = int(max(4000, 200 * n * periods))
    t_c = np.linspace(0.0, duration / periods, n_coarse, endpoint=False)  # one period suffices
    t_f = np.linspace(0.0, duration / periods, n_fine, endpoint=False)
    pc, vc, ac = _basis(n, omega_f, t_c)
    pc_n, vc_n, ac_n = pc @ ns, vc @ ns, ac @ ns

    def objective(z: np.ndarray) -> float:
        qd, qdd = vc_n @ z, ac_n @ z
        if not np.any(qd) or not np.any(qdd):
            return 1e3
        keep = np.abs(qd) >= stiction_fraction * np.max(np.abs(qd))
        cond = _richness_cond(qd[keep], qdd[keep])
        if not math.isfinite(cond):
            return 1e3
        s = _limit_scale(pc_n @ z, qd, qdd, q_max - q_start, q_start - q_min, qd_max, qdd_max)
        use = math.sqrt(np.mean(qd**2)) * math.sqrt(np.mean(qdd**2)) * s**2 / (qd_max * qdd_max)
        return (
            math.log(cond)
            + stiction_penalty * (1.0 - float(keep.mean()))
            - amplitude_weight * 0.5 * math.log(max(use, 1e-300))
        )

    rng = np.random.default_rng(seed)
    weights = np.concatenate([1.0 / k, 1.0 / k])  # decaying harmonic amplitudes
    starts = [ns.T @ (rng.standard_normal(2 * n) * weights) for _ in range(max(1, n_candidates))]
    vals = [objective(z) for z in starts]
    z = starts[int(np.argmin(vals))]
    if optimize_richness:
        res = optimize.minimize(
            objective,
            z,
            method="Nelder-Mead",
            options={"maxfev": int(max_evaluations), "xatol": 1e-6, "fatol": 1e-6},
        )
        if res.fun <= min(vals):
            z = res.x
    c = ns @ z

    pf, vf, af = _basis(n, omega_f, t_f)
    c = c * (margin * _limit_scale(pf @ c, vf @ c, af @ c, q_max - q_start, q_start - q_min, qd_max, qdd_max))
    return FourierTrajectory.from_start(omega_f, c[:n], c[n:], q_start=q_start, periods=periods)


# --------------------------------------------------------------------------------------------
# Generic analytic trajectory (used for the lane change)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AnalyticTrajectory:
    """Trajectory given by a function of normalised time τ = t/T ∈ [0, 1].

    ``func(tau) -> (q, dq/dτ, d²q/dτ²)``; held at its end values, at rest, outside [0, T].
    """

    duration: float
    func: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]

    def evaluate(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration at times ``t`` (s); each of the shape of ``t``."""
        t = np.asarray(t, dtype=float)
        tau = np.clip(t / self.duration, 0.0, 1.0)
        q, dq, ddq = self.func(tau)
        outside = (t < 0.0) | (t > self.duration)
        qd = np.where(outside, 0.0, dq / self.duration)
        qdd = np.where(outside, 0.0, ddq / self.duration**2)
        return np.asarray(q, dtype=float), qd, qdd
