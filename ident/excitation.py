"""Excitation trajectories for the identification campaign (paper section 6.2).

The campaign (section 6.2) runs four simple movements, in this order:

1. ``steer_left``  – motion mode k = 1, α_l(t) excited, α_r ≡ 0;
2. ``steer_right`` – k = 1, α_r(t) excited, α_l ≡ 0;
3. ``straight``    – k = 2 with α_v ≡ 0, x_ch(t) excited;
4. ``rotation``    – k = 4, α = arctan(l/b)·(−1, +1), γ_ch(t) excited.

Each excited coordinate is a rest-to-rest finite Fourier series, designed by one of :data:`CRITERIA`:
:func:`qomni.ident.fourier.design_fourier_trajectory` (richness) or
:func:`qomni.ident.min_cond_design.design_min_cond_trajectory` (the viscous/Coulomb pair's condition
number; an option, ``CampaignSettings.excitation``).

After it the campaign drives two arcs (:func:`arc_excitation`), one to each side: mode 2 at a held virtual
steering angle, the chassis yawing about an instantaneous centre beside it, a configuration no
identification step yaws in.

The validation movement (:func:`lane_change`) is a mode-2 lane change (by default of the campaign a
double one, out and back): a symmetric sin² speed profile ẋ_ch(t) and S-shaped virtual steering angles
α_v along the way; the amplitude is solved (brentq) so the chassis moves sideways by one lane width and
ends each change with the original heading.

All quantities SI: m, rad, s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike
from scipy import integrate, optimize

from .fourier import AnalyticTrajectory, Trajectory, design_fourier_trajectory
from .min_cond_design import design_min_cond_trajectory
from .kinematics import f_icr_lb

__all__ = [
    "ExcitationStep",
    "steer_left_excitation",
    "steer_right_excitation",
    "straight_excitation",
    "rotation_excitation",
    "identification_campaign",
    "lane_change",
    "arc_excitation",
    "arc_alpha_v",
    "mode2_path",
    "occupied_rectangle",
    "ALPHA_MAX_DEFAULT",
]

#: Default steering amplitude limit, 0.6 · π/2 rad (stops are at ±π/2).
ALPHA_MAX_DEFAULT = 0.6 * math.pi / 2


# --------------------------------------------------------------------------------------------
# Campaign steps
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ExcitationStep:
    """One campaign movement: excited coordinates plus coordinates held constant.

    Attributes
    ----------
    name : str
        ``"steer_left"``, ``"steer_right"``, ``"straight"``, ``"rotation"``, ``"lane_change"``, ``"arc_left"`` or ``"arc_right"``.
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


#: Design criteria of the identification steps' Fourier coefficients: ``"richness"`` the random-start
#: richness design (:func:`design_fourier_trajectory`), ``"min_cond"`` the viscous/Coulomb pair's condition
#: number (:func:`design_min_cond_trajectory`; needs the estimator's ``threshold``).
CRITERIA = ("richness", "min_cond")


def _design(criterion: str, threshold: float | None, *, duration: float, q_max: float, qd_max: float,
            qdd_max: float, n_harmonics: int, seed: int, **kw) -> Trajectory:
    """One excited coordinate over ±q_max, by ``criterion`` (:data:`CRITERIA`).

    ``min_cond`` takes ``cond_cap`` (:func:`design_min_cond_trajectory`) among ``kw``.

    Raises: ValueError: an unknown criterion, ``min_cond`` without a threshold or with richness-only
    keywords, or limits the design cannot meet."""
    if criterion == "richness":
        return design_fourier_trajectory(duration=duration, q_min=-q_max, q_max=q_max, qd_max=qd_max,
                                         qdd_max=qdd_max, n_harmonics=n_harmonics, seed=seed, **kw)
    if criterion == "min_cond":
        cap = kw.pop("cond_cap", None)
        if threshold is None or kw:
            raise ValueError(f"the min_cond design needs the threshold and takes no {sorted(kw)}")
        return design_min_cond_trajectory(duration=duration, q_min=-q_max, q_max=q_max, qd_max=qd_max,
                                          qdd_max=qdd_max, threshold=threshold, n_harmonics=n_harmonics,
                                          cond_cap=cap)
    raise ValueError(f"unknown excitation criterion {criterion!r}; one of {CRITERIA}")


def _steer_excitation(side: str, *, duration: float, alpha_max: float, alpha_dot_max: float,
                      alpha_ddot_max: float, n_harmonics: int, seed: int, criterion: str = "richness",
                      threshold: float | None = None, **kw) -> ExcitationStep:
    """Mode-1 step: α of ``side`` ("l" or "r") excited, the other side held at 0 (section 6.2)."""
    tr = _design(criterion, threshold, duration=duration, q_max=alpha_max, qd_max=alpha_dot_max,
                 qdd_max=alpha_ddot_max, n_harmonics=n_harmonics, seed=seed, **kw)
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
    criterion: str = "richness",
    threshold: float | None = None,
    **kw,
) -> ExcitationStep:
    """Step 1 (mode k = 1): α_l(t) Fourier excitation with |α_l| ≤ alpha_max (rad), α_r ≡ 0.

    Limits in rad, rad/s, rad/s². ``criterion`` (:data:`CRITERIA`) and ``threshold`` (rad/s, the
    estimator's stiction threshold, for ``min_cond``) choose the design; extra keywords go to
    :func:`design_fourier_trajectory`.
    """
    return _steer_excitation("l", duration=duration, alpha_max=alpha_max, alpha_dot_max=alpha_dot_max,
                             alpha_ddot_max=alpha_ddot_max, n_harmonics=n_harmonics, seed=seed,
                             criterion=criterion, threshold=threshold, **kw)


def steer_right_excitation(
    *,
    duration: float = 15.0,
    alpha_max: float = ALPHA_MAX_DEFAULT,
    alpha_dot_max: float = 1.0,
    alpha_ddot_max: float = 4.0,
    n_harmonics: int = 6,
    seed: int = 2,
    criterion: str = "richness",
    threshold: float | None = None,
    **kw,
) -> ExcitationStep:
    """Step 2 (mode k = 1): α_r(t) Fourier excitation with |α_r| ≤ alpha_max (rad), α_l ≡ 0."""
    return _steer_excitation("r", duration=duration, alpha_max=alpha_max, alpha_dot_max=alpha_dot_max,
                             alpha_ddot_max=alpha_ddot_max, n_harmonics=n_harmonics, seed=seed,
                             criterion=criterion, threshold=threshold, **kw)


def straight_excitation(
    *,
    duration: float = 15.0,
    x_max: float = 1.0,
    x_dot_max: float = 0.5,
    x_ddot_max: float = 0.5,
    n_harmonics: int = 6,
    seed: int = 3,
    criterion: str = "richness",
    threshold: float | None = None,
    **kw,
) -> ExcitationStep:
    """Step 3 (mode k = 2, α_v ≡ 0): x_ch(t) with |x_ch| ≤ x_max (m), limits in m/s, m/s².

    Held: α_v = α_l = α_r = 0.
    """
    tr = _design(criterion, threshold, duration=duration, q_max=x_max, qd_max=x_dot_max,
                 qdd_max=x_ddot_max, n_harmonics=n_harmonics, seed=seed, **kw)
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
    criterion: str = "richness",
    threshold: float | None = None,
    **kw,
) -> ExcitationStep:
    """Step 4 (mode k = 4): γ_ch(t) with |γ_ch| ≤ gamma_max (rad); limits in rad/s, rad/s².

    ``l``, ``b`` (m) give the held steering angles α = arctan(l/b)·(−1, +1) of mode 4.
    """
    tr = _design(criterion, threshold, duration=duration, q_max=gamma_max, qd_max=gamma_dot_max,
                 qdd_max=gamma_ddot_max, n_harmonics=n_harmonics, seed=seed, **kw)
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


def arc_alpha_v(l: float, b: float, inner_alpha: float) -> float:
    """The arcs' |α_v|, rad, for the inner steering units at ``inner_alpha`` (rad, 0 < inner_alpha < π/2):
    eq. (6)-(8), (l/2)/tan α_v = (l/2)/tan α_inner + b/2, the ICR at (l/2)/tan α_v beside the centre.

    Raises:
        ValueError: ``inner_alpha`` outside (0, π/2).
    """
    if not 0.0 < inner_alpha < math.pi / 2:
        raise ValueError(f"inner_alpha must lie in (0, pi/2) rad, got {inner_alpha}")
    return math.atan2(0.5 * l, 0.5 * l / math.tan(inner_alpha) + 0.5 * b)


def arc_excitation(
    *,
    l: float,
    b: float,
    side: int,
    inner_alpha: float = 1.25,
    duration: float = 10.0,
    gamma_max: float = 1.0,
    gamma_dot_max: float = 0.8,
    gamma_ddot_max: float = 3.0,
    x_ddot_max: float = 1.6,
    n_harmonics: int = 6,
    seed: int = 5,
    **kw,
) -> ExcitationStep:
    """Mode 2 at a held α_v = side·:func:`arc_alpha_v`, the inner steering units at ``inner_alpha``: x_ch(t)
    excited, the chassis yawing by γ = κ·x_ch about the ICR at (0, 1/κ), κ = tan(α_v)/(l/2).

    The yaw inertia of a mass carried by the steering units depends on the steering angles; the
    identification steps yaw the chassis only in mode 4, so the lumped C_ch holds that inertia at mode 4's
    angles. In an arc the inner units stand at arctan(l/b) turned the other way, their wheel centres
    closer to the chassis centre the further they turn (docs/diagnosis.md, heavy steering units). A first moment of the chassis
    mass across the driving direction (an off-centre payload) adds −2κ·s_y to the arc's path inertia:
    it changes sign with the turning direction, the steering units' inertia does not, so the campaign
    drives one arc to each side. The yaw motion is bounded by the rotation's limits through κ:
    |x_ch| ≤ gamma_max/|κ|, |ẋ_ch| ≤ gamma_dot_max/|κ|, |ẍ_ch| ≤ min(gamma_ddot_max/|κ|, x_ddot_max).

    Parameters
    ----------
    l, b : float
        Steering-axis distances (m).
    side : int
        +1: turning left (ICR on the left, step ``"arc_left"``), −1: right (``"arc_right"``).
    inner_alpha : float
        |α| of the inner units (rad, below the stops at π/2).
    duration : float
        Length (s).
    gamma_max, gamma_dot_max, gamma_ddot_max : float
        Yaw limits (rad, rad/s, rad/s²); x_ddot_max (m/s²) caps the path acceleration.
    n_harmonics, seed : int
        Fourier design (as the straight step; ``kw`` goes to the design, e.g. ``periods``).

    Returns
    -------
    ExcitationStep
        mode 2, trajectory ``{"x_ch"}``, held α_v, α_l, α_r.

    Raises
    ------
    ValueError
        ``side`` is not ±1, or ``inner_alpha`` is outside (0, π/2).
    """
    if side not in (1, -1):
        raise ValueError(f"side must be +1 (left) or -1 (right), got {side}")
    alpha_v = side * arc_alpha_v(l, b, inner_alpha)
    kappa = abs(math.tan(alpha_v)) / (0.5 * l)
    tr = design_fourier_trajectory(
        duration=duration, q_min=-gamma_max / kappa, q_max=gamma_max / kappa,
        qd_max=gamma_dot_max / kappa, qdd_max=min(gamma_ddot_max / kappa, x_ddot_max),
        n_harmonics=n_harmonics, seed=seed, **kw,
    )
    alpha_l, alpha_r = (float(a) for a in f_icr_lb(alpha_v, l, b)[0])
    return ExcitationStep("arc_left" if side > 0 else "arc_right", 2, {"x_ch": tr},
                          {"alpha_v": alpha_v, "alpha_l": alpha_l, "alpha_r": alpha_r})


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
    changes: int = 1,
    alpha_v_max: float = ALPHA_MAX_DEFAULT,
    alpha_dot_max: float | None = None,
    alpha_ddot_max: float | None = None,
    x_dot_max: float | None = None,
    x_ddot_max: float | None = None,
    narrow_to_limits: bool = False,
) -> ExcitationStep:
    """Mode-2 lane change(s) for validation: x_ch(t) and α_v(t), rest to rest, α_v(0) = α_v(T) = 0.

    With τ = t/T and u = x_ch/distance the share of the way travelled:
      ẋ_ch = v̂ sin²(πτ), v̂ = 2·distance/T   (ẋ = ẍ = 0 at the ends);
      α_v  = A·S(u): ``changes`` equal lane changes along the way, alternately to one side and back
             (1: a lane change; 2: a double lane change that returns to its lane). Each change is
             ±s(v) = ±(½ sin 2πv − ¼ sin 4πv) over its share v ∈ [0, 1] of the way: s, s′, s″ vanish
             at both ends (C² joints) and s(1 − v) = −s(v).
    The steering is a function of the way, not of time: the heading rate per metre is tan(α_v)/(l/2),
    so each change returns the heading exactly to 0 and moves the chassis sideways by the same amount
    whatever the speed profile. A is found by brentq so that the largest sideways displacement is
    ``lane_width``. More changes over the same way steer faster: a single slow lane change keeps
    |α̇_v| below the steering's stiction threshold and leaves its friction untested.

    Parameters
    ----------
    l : float
        Distance between front and rear steering axes (m).
    duration, distance, lane_width : float
        T (s), travelled chassis-frame distance x_ch(T) (m), largest sideways displacement (m).
    changes : int
        Number of lane changes (≥ 1).
    alpha_v_max : float
        Admissible |α_v| (rad).
    alpha_dot_max, alpha_ddot_max : float, optional
        Admissible |α̇_v| (rad/s), |α̈_v| (rad/s²); not checked if None.
    x_dot_max, x_ddot_max : float, optional
        Admissible |ẋ_ch| (m/s), |ẍ_ch| (m/s²); not checked if None.
    narrow_to_limits : bool
        Where ``lane_width`` needs more steering than ``alpha_v_max``, ``alpha_dot_max`` or
        ``alpha_ddot_max`` allow, drive the widest lane within them instead of raising. A longer vehicle
        steers further for the same path (α_v ≈ l·κ/2): the campaign's lane change narrows for it.

    Returns
    -------
    ExcitationStep
        name ``"lane_change"``, mode 2, trajectories ``{"alpha_v", "x_ch"}``.

    Raises
    ------
    ValueError
        If a limit is exceeded (the steering's only without ``narrow_to_limits``), ``changes`` < 1, or the
        lane width is not reachable with |α_v| ≤ alpha_v_max (without ``narrow_to_limits``).
    """
    if duration <= 0 or distance <= 0 or l <= 0:
        raise ValueError("duration, distance and l must be > 0")
    if int(changes) != changes or changes < 1:
        raise ValueError(f"changes must be an integer >= 1, got {changes}")
    n = int(changes)
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

    def shape(u):
        """S(u), S′(u), S″(u) on the share u ∈ [0, 1] of the way."""
        u = np.clip(np.asarray(u, dtype=float), 0.0, 1.0)
        k = np.minimum(np.floor(u * n), n - 1)
        v = u * n - k
        sign = np.where(k % 2 == 0, 1.0, -1.0)
        s = 0.5 * np.sin(two_pi * v) - 0.25 * np.sin(2 * two_pi * v)
        ds = 0.5 * two_pi * (np.cos(two_pi * v) - np.cos(2 * two_pi * v))
        dds = 0.5 * two_pi**2 * (-np.sin(two_pi * v) + 2.0 * np.sin(2 * two_pi * v))
        return sign * s, sign * ds * n, sign * dds * n * n

    def s_func(tau):
        """S(x(τ)/d) and its first two derivatives with respect to τ."""
        x, dx, ddx = x_func(tau)
        s, ds, dds = shape(x / distance)
        return s, ds * dx / distance, dds * (dx / distance) ** 2 + ds * ddx / distance

    tau = np.linspace(0.0, 1.0, 4001)
    t = tau * duration
    xd = x_func(tau)[1] / duration
    s = s_func(tau)[0]
    s_peak = float(np.max(np.abs(s)))

    def lateral(amp: float) -> float:
        return float(np.max(np.abs(mode2_path(t, xd, amp * s, l)[1]))) - lane_width

    # Lateral offset grows with A until the heading approaches π/2; bracket the first crossing.
    amp_max = min(alpha_v_max, 0.999 * math.pi / 2) / s_peak
    grid = np.linspace(0.0, amp_max, 65)
    vals = np.array([lateral(g) for g in grid])
    above = np.nonzero(vals >= 0.0)[0]
    if above.size == 0 and narrow_to_limits:
        amp = float(grid[int(np.argmax(vals))])          # the widest lane |α_v| ≤ alpha_v_max reaches
    elif above.size == 0:
        raise ValueError(
            f"lane width {lane_width} m not reachable with |alpha_v| <= {alpha_v_max:.3g} rad over "
            f"{distance} m in {n} change(s); increase distance or alpha_v_max"
        )
    elif vals[int(above[0])] == 0.0:
        amp = float(grid[int(above[0])])
    else:
        i = int(above[0])
        amp = optimize.brentq(lateral, grid[i - 1], grid[i], xtol=1e-12)

    _, ds_, dds_ = s_func(tau)
    peaks = (("alpha_dot", amp * np.max(np.abs(ds_)) / duration, alpha_dot_max),
             ("alpha_ddot", amp * np.max(np.abs(dds_)) / duration**2, alpha_ddot_max))
    if narrow_to_limits:          # α̇_v and α̈_v are A times the shape's: scale A down to the tighter limit
        amp *= min([1.0] + [limit / peak for _, peak, limit in peaks if limit is not None and peak > limit])
    else:
        for name, peak, limit in peaks:
            if limit is not None and peak > limit:
                raise ValueError(f"lane change: peak |{name}_v| {peak:.3g} exceeds {name}_max = {limit} "
                                 f"({n} change(s) of {lane_width} m over {distance} m in {duration} s)")

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
