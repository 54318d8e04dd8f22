"""Excitation trajectories for the identification campaign (paper section 6.2).

The campaign (section 6.2) runs four simple movements, in this order:

1. ``steer_left``  – motion mode k = 1, α_l(t) excited, α_r ≡ 0;
2. ``steer_right`` – k = 1, α_r(t) excited, α_l ≡ 0;
3. ``straight``    – k = 2 with α_v ≡ 0, x_ch(t) excited;
4. ``rotation``    – k = 4, α = arctan(l/b)·(−1, +1), γ_ch(t) excited.

Each excited coordinate is a finite Fourier series (Swevers et al. 1997 form)

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

The validation movement (:func:`lane_change`) is a mode-2 lane change: a symmetric sin² speed profile
ẋ_ch(t) and an antisymmetric S-shaped virtual steering angle α_v(t); its amplitude is solved (brentq)
so the chassis moves sideways by one lane width and ends with the original heading.

All quantities SI: m, rad, s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy import integrate, linalg, optimize

__all__ = [
    "FourierTrajectory",
    "AnalyticTrajectory",
    "ExcitationStep",
    "design_fourier_trajectory",
    "steer_left_excitation",
    "steer_right_excitation",
    "straight_excitation",
    "rotation_excitation",
    "identification_campaign",
    "lane_change",
    "mode2_path",
    "occupied_rectangle",
    "ALPHA_MAX_DEFAULT",
]

#: Default steering amplitude limit, 0.6 · π/2 rad (stops are at ±π/2).
ALPHA_MAX_DEFAULT = 0.6 * math.pi / 2

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

    def scale_of(f: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> float:
        """Largest factor keeping f (= q − q_start), q̇, q̈ within the limits."""
        s = min(qd_max / np.max(np.abs(qd)), qdd_max / np.max(np.abs(qdd)))
        if f.max() > 0:
            s = min(s, (q_max - q_start) / f.max())
        if f.min() < 0:
            s = min(s, (q_start - q_min) / (-f.min()))
        return float(s)

    def objective(z: np.ndarray) -> float:
        qd, qdd = vc_n @ z, ac_n @ z
        if not np.any(qd) or not np.any(qdd):
            return 1e3
        keep = np.abs(qd) >= stiction_fraction * np.max(np.abs(qd))
        cond = _richness_cond(qd[keep], qdd[keep])
        if not math.isfinite(cond):
            return 1e3
        s = scale_of(pc_n @ z, qd, qdd)
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
    f, qd, qdd = pf @ c, vf @ c, af @ c
    scales = [qd_max / np.max(np.abs(qd)), qdd_max / np.max(np.abs(qdd))]
    if f.max() > 0:
        scales.append((q_max - q_start) / f.max())
    if f.min() < 0:
        scales.append((q_start - q_min) / (-f.min()))
    c = c * (margin * min(scales))
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


# --------------------------------------------------------------------------------------------
# Campaign steps
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ExcitationStep:
    """One campaign movement: excited coordinates plus coordinates held constant.

    Attributes
    ----------
    name : str
        ``"steer_left"``, ``"steer_right"``, ``"straight"``, ``"rotation"`` or ``"lane_change"``.
    mode : int
        Motion mode k of (9) (1, 2 or 4).
    trajectories : Mapping[str, Trajectory]
        Excited coordinates, e.g. ``{"alpha_l": FourierTrajectory}``.
    held : Mapping[str, float]
        Coordinates held constant during the step (rad or m).
    """

    name: str
    mode: int
    trajectories: Mapping[str, Trajectory]
    held: Mapping[str, float] = field(default_factory=dict)

    @property
    def duration(self) -> float:
        """Length of the step (s): the longest excited trajectory."""
        return max(tr.duration for tr in self.trajectories.values())

    @property
    def channels(self) -> tuple[str, ...]:
        """Channel labels ``"<step>/<coordinate>"`` of the excited coordinates."""
        return tuple(f"{self.name}/{c}" for c in self.trajectories)

    def time(self, T_s: float = 2e-3) -> np.ndarray:
        """Sample times 0, T_s, …, ≤ duration (s), shape (N,)."""
        return np.arange(0.0, self.duration + 0.5 * T_s, T_s)

    def evaluate(self, t: ArrayLike) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """``{coordinate: (q, q̇, q̈)}`` for excited and held coordinates, arrays of t's shape."""
        t = np.asarray(t, dtype=float)
        out = {c: tr.evaluate(t) for c, tr in self.trajectories.items()}
        zero = np.zeros_like(t)
        for c, v in self.held.items():
            out[c] = (np.full_like(t, float(v)), zero.copy(), zero.copy())
        return out


def _steer_excitation(side: str, *, duration: float, alpha_max: float, alpha_dot_max: float,
                      alpha_ddot_max: float, n_harmonics: int, seed: int, **kw) -> ExcitationStep:
    """Mode-1 step: α of ``side`` ("l" or "r") excited, the other side held at 0 (section 6.2)."""
    tr = design_fourier_trajectory(
        duration=duration, q_min=-alpha_max, q_max=alpha_max, qd_max=alpha_dot_max,
        qdd_max=alpha_ddot_max, n_harmonics=n_harmonics, seed=seed, **kw,
    )
    other = "r" if side == "l" else "l"
    name = "steer_left" if side == "l" else "steer_right"
    return ExcitationStep(name, 1, {f"alpha_{side}": tr}, {f"alpha_{other}": 0.0})


def steer_left_excitation(
    *,
    duration: float = 15.0,
    alpha_max: float = ALPHA_MAX_DEFAULT,
    alpha_dot_max: float = 1.0,
    alpha_ddot_max: float = 4.0,
    n_harmonics: int = 6,
    seed: int = 1,
    **kw,
) -> ExcitationStep:
    """Step 1 (mode k = 1): α_l(t) Fourier excitation with |α_l| ≤ alpha_max (rad), α_r ≡ 0.

    Limits in rad, rad/s, rad/s². Extra keywords go to :func:`design_fourier_trajectory`.
    """
    return _steer_excitation("l", duration=duration, alpha_max=alpha_max, alpha_dot_max=alpha_dot_max,
                             alpha_ddot_max=alpha_ddot_max, n_harmonics=n_harmonics, seed=seed, **kw)


def steer_right_excitation(
    *,
    duration: float = 15.0,
    alpha_max: float = ALPHA_MAX_DEFAULT,
    alpha_dot_max: float = 1.0,
    alpha_ddot_max: float = 4.0,
    n_harmonics: int = 6,
    seed: int = 2,
    **kw,
) -> ExcitationStep:
    """Step 2 (mode k = 1): α_r(t) Fourier excitation with |α_r| ≤ alpha_max (rad), α_l ≡ 0."""
    return _steer_excitation("r", duration=duration, alpha_max=alpha_max, alpha_dot_max=alpha_dot_max,
                             alpha_ddot_max=alpha_ddot_max, n_harmonics=n_harmonics, seed=seed, **kw)


def straight_excitation(
    *,
    duration: float = 15.0,
    x_max: float = 1.0,
    x_dot_max: float = 0.5,
    x_ddot_max: float = 0.5,
    n_harmonics: int = 6,
    seed: int = 3,
    **kw,
) -> ExcitationStep:
    """Step 3 (mode k = 2, α_v ≡ 0): x_ch(t) with |x_ch| ≤ x_max (m), limits in m/s, m/s².

    Held: α_v = α_l = α_r = 0.
    """
    tr = design_fourier_trajectory(
        duration=duration, q_min=-x_max, q_max=x_max, qd_max=x_dot_max, qdd_max=x_ddot_max,
        n_harmonics=n_harmonics, seed=seed, **kw,
    )
    return ExcitationStep("straight", 2, {"x_ch": tr}, {"alpha_v": 0.0, "alpha_l": 0.0, "alpha_r": 0.0})


def rotation_excitation(
    *,
    l: float,
    b: float,
    duration: float = 15.0,
    gamma_max: float = math.pi / 2,
    gamma_dot_max: float = 0.5,
    gamma_ddot_max: float = 0.5,
    n_harmonics: int = 6,
    seed: int = 4,
    **kw,
) -> ExcitationStep:
    """Step 4 (mode k = 4): γ_ch(t) with |γ_ch| ≤ gamma_max (rad); limits in rad/s, rad/s².

    ``l``, ``b`` (m) give the held steering angles α = arctan(l/b)·(−1, +1) of mode 4.
    """
    tr = design_fourier_trajectory(
        duration=duration, q_min=-gamma_max, q_max=gamma_max, qd_max=gamma_dot_max,
        qdd_max=gamma_ddot_max, n_harmonics=n_harmonics, seed=seed, **kw,
    )
    alpha4 = math.atan2(l, b)
    return ExcitationStep("rotation", 4, {"gamma_ch": tr}, {"alpha_l": -alpha4, "alpha_r": alpha4})


def identification_campaign(
    *, l: float, b: float, duration: float = 15.0, seed: int = 0, **limits
) -> list[ExcitationStep]:
    """The four steps in the paper's order (steer left, steer right, straight, rotation).

    ``limits`` may hold any keyword of the four step generators (e.g. ``x_max``, ``gamma_max``);
    each goes to the generators that accept it. Step i uses seed ``seed + i + 1``.
    """
    import inspect

    gens = [steer_left_excitation, steer_right_excitation, straight_excitation, rotation_excitation]
    known = set().union(*(inspect.signature(g).parameters for g in gens)) - {"kw"}
    unknown = set(limits) - known
    if unknown:
        raise TypeError(f"unknown limit keywords: {sorted(unknown)}")
    steps = []
    for i, g in enumerate(gens):
        params = inspect.signature(g).parameters
        kw = {k: v for k, v in limits.items() if k in params}
        if g is rotation_excitation:
            kw.update(l=l, b=b)
        steps.append(g(duration=duration, seed=seed + i + 1, **kw))
    return steps


# --------------------------------------------------------------------------------------------
# Lane change (validation, mode 2)
# --------------------------------------------------------------------------------------------


def mode2_path(
    t: ArrayLike, x_dot: ArrayLike, alpha_v: ArrayLike, l: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World path of the chassis centre in mode 2 by trapezoidal integration.

    γ̇_ch = ẋ_ch · tan(α_v) / (l/2) (ICR at (0, (l/2)/tan α_v)), ẏ_ch = 0 in the chassis frame.

    Parameters
    ----------
    t, x_dot, alpha_v : array_like, shape (N,)
        Time (s), chassis-frame forward speed (m/s), virtual steering angle (rad).
    l : float
        Distance between front and rear steering axes (m).

    Returns
    -------
    x_w, y_w, gamma_ch : ndarray, shape (N,)   (m, m, rad), starting at 0.
    """
    t = np.asarray(t, dtype=float)
    xd = np.asarray(x_dot, dtype=float)
    av = np.asarray(alpha_v, dtype=float)
    gamma = integrate.cumulative_trapezoid(xd * np.tan(av) / (0.5 * l), t, initial=0.0)
    x_w = integrate.cumulative_trapezoid(xd * np.cos(gamma), t, initial=0.0)
    y_w = integrate.cumulative_trapezoid(xd * np.sin(gamma), t, initial=0.0)
    return x_w, y_w, gamma


def lane_change(
    *,
    l: float,
    duration: float = 12.0,
    distance: float = 6.0,
    lane_width: float = 1.5,
    alpha_v_max: float = ALPHA_MAX_DEFAULT,
    x_dot_max: float | None = None,
    x_ddot_max: float | None = None,
) -> ExcitationStep:
    """Mode-2 lane change for validation: x_ch(t) and α_v(t), rest to rest, α_v(0) = α_v(T) = 0.

    With τ = t/T:
      ẋ_ch = v̂ sin²(πτ), v̂ = 2·distance/T   (symmetric about T/2, ẋ = ẍ = 0 at the ends);
      α_v  = A (½ sin 2πτ − ¼ sin 4πτ) = A sin(2πτ) sin²(πτ)   (antisymmetric: heading returns to 0;
             α_v, α̇_v, α̈_v = 0 at the ends).
    A is found by brentq so that the world lateral displacement is ``lane_width``.

    Parameters
    ----------
    l : float
        Distance between front and rear steering axes (m).
    duration, distance, lane_width : float
        T (s), travelled chassis-frame distance x_ch(T) (m), sideways displacement (m).
    alpha_v_max : float
        Admissible |α_v| (rad).
    x_dot_max, x_ddot_max : float, optional
        Admissible |ẋ_ch| (m/s), |ẍ_ch| (m/s²); not checked if None.

    Returns
    -------
    ExcitationStep
        name ``"lane_change"``, mode 2, trajectories ``{"alpha_v", "x_ch"}``.

    Raises
    ------
    ValueError
        If the speed limits are exceeded or the lane width is not reachable with |α_v| ≤ alpha_v_max.
    """
    if duration <= 0 or distance <= 0 or l <= 0:
        raise ValueError("duration, distance and l must be > 0")
    v_hat = 2.0 * distance / duration
    if x_dot_max is not None and v_hat > x_dot_max:
        raise ValueError(f"peak speed {v_hat:.3g} m/s exceeds x_dot_max = {x_dot_max}")
    a_hat = v_hat * math.pi / duration
    if x_ddot_max is not None and a_hat > x_ddot_max:
        raise ValueError(f"peak acceleration {a_hat:.3g} m/s² exceeds x_ddot_max = {x_ddot_max}")
    two_pi = 2.0 * math.pi

    def x_func(tau):
        x = distance * (tau - np.sin(two_pi * tau) / two_pi)
        dx = distance * (1.0 - np.cos(two_pi * tau))  # = 2 distance sin²(πτ)
        ddx = distance * two_pi * np.sin(two_pi * tau)
        return x, dx, ddx

    def s_func(tau):
        s = 0.5 * np.sin(two_pi * tau) - 0.25 * np.sin(2 * two_pi * tau)
        ds = 0.5 * two_pi * (np.cos(two_pi * tau) - np.cos(2 * two_pi * tau))
        dds = 0.5 * two_pi**2 * (-np.sin(two_pi * tau) + 2.0 * np.sin(2 * two_pi * tau))
        return s, ds, dds

    tau = np.linspace(0.0, 1.0, 4001)
    t = tau * duration
    xd = x_func(tau)[1] / duration
    s = s_func(tau)[0]
    s_peak = float(np.max(np.abs(s)))

    def lateral(amp: float) -> float:
        return float(mode2_path(t, xd, amp * s, l)[1][-1]) - lane_width

    # Lateral offset grows with A until the heading approaches π/2; bracket the first crossing.
    amp_max = min(alpha_v_max, 0.999 * math.pi / 2) / s_peak
    grid = np.linspace(0.0, amp_max, 65)
    vals = np.array([lateral(g) for g in grid])
    above = np.nonzero(vals >= 0.0)[0]
    if above.size == 0:
        raise ValueError(
            f"lane width {lane_width} m not reachable with |alpha_v| <= {alpha_v_max:.3g} rad over "
            f"{distance} m; increase distance or alpha_v_max"
        )
    i = int(above[0])
    if vals[i] == 0.0:
        amp = float(grid[i])
    else:
        amp = optimize.brentq(lateral, grid[i - 1], grid[i], xtol=1e-12)

    def av_func(tau):
        s_, ds_, dds_ = s_func(tau)
        return amp * s_, amp * ds_, amp * dds_

    return ExcitationStep(
        "lane_change",
        2,
        {"alpha_v": AnalyticTrajectory(duration, av_func), "x_ch": AnalyticTrajectory(duration, x_func)},
    )


# --------------------------------------------------------------------------------------------
# Space requirement
# --------------------------------------------------------------------------------------------


def occupied_rectangle(x_traj: ArrayLike | Trajectory, l: float, b: float, a: float) -> tuple[float, float]:
    """Rectangle occupied during the campaign (section 6.2).

    Parameters
    ----------
    x_traj : array_like, shape (N,), or a trajectory with ``evaluate``/``duration``
        Longitudinal chassis positions x_ch (m) of the straight step.
    l, b, a : float
        Steering-axis distances and wheel offset (m).

    Returns
    -------
    (length, width) : tuple of float (m)
        length = l + 2 max|x_ch(t)|, width = sqrt(l² + b²) + 2a.
    """
    if hasattr(x_traj, "evaluate"):
        t = np.linspace(0.0, x_traj.duration, 20001)
        x = x_traj.evaluate(t)[0]
    else:
        x = np.asarray(x_traj, dtype=float)
    if x.size == 0:
        raise ValueError("x_traj is empty")
    return float(l + 2.0 * np.max(np.abs(x))), float(math.hypot(l, b) + 2.0 * a)
