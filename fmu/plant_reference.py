"""Python reference of the plant FMU: the same hybrid model and integrator as ``fmu/c/plant/plant.c``,
written with ident's numpy model (:func:`ident.dynamics.forward_dynamics`, :func:`ident.kinematics.H`,
:func:`ident.kinematics.f_icr`). Slow (one sample at a time); used by the tests to check the C plant.

**The model.** In the engaged mode k the generalized velocities s_dot_k of (10)-(13) obey the paper's
reduced dynamics (19) with (20),

    H_k^T M H_k s_ddot_k = H_k^T B u - H_k^T Theta(q, H_k s_dot_k, H_dot_k s_dot_k) p,

with viscous + tanh-Coulomb friction (16) (sharpness ``eps``), q_dot = H_k s_dot_k (4), and the world pose
integrated from the chassis-frame velocities. The constraint forces A^T lambda take every torque component
outside the range of H_k.

**The hybrid rules** (with the torques u of the communication step; when they are checked: 'Events'):

1. *Rest, k = 1* (the vehicle starts here). The chassis stands still; the steering moves with mode 1's
   dynamics (s_dot_1 = alpha_dot, the wheels roll by H_1's beta rows as they swing about their steering
   axes). The stops hold |alpha_j| <= steering_limit: an angle beyond is set back onto the stop (the
   wheels rolled back with it) and an outward rate is absorbed.
2. *Engaging a chassis mode.* If alpha is within ``mode_tol`` of mode k_c's configuration (9) (k_c = 3
   before 4 before 2) and the drive force on that mode's chassis coordinate, tau_c = h_c^T B u (h_c: the
   x_ch column of H_2, the only column of H_3 / H_4), exceeds its static Coulomb level
   F_c = d_cw sum_i |h_c,beta_i|, the chassis breaks loose in mode k_c. In mode 3 each side must moreover
   stay on its stop: a side whose steering torque (H_1^T B u)_j pulls it off the stop by more than its
   static steering friction d_cj + d_cw sum |H_1,beta| steers instead (rule 1) -- H_3^T B is the sum of
   the H_1^T B rows over a, so only the side pressing into its stop may take the drive. On engaging,
   alpha is set onto the configuration (mode 2: f_ICR(alpha_v(alpha)); the wheels roll with it) and the
   steering rate is projected onto the mode (mode 2: alpha_v_dot = f'.alpha_dot / |f'|^2; modes 3, 4: 0),
   the chassis rate starts from 0.
3. *Moving, k = 2, 3, 4.* Torques that violate the mode's constraints -- steering off the configuration,
   mode 3's side pulled off its stop, driving against the ICR -- are absorbed by the constraint forces:
   the mode stays. Mode 2 keeps alpha = f_ICR(alpha_v) with |alpha_v| <= arctan(l/b) (there the inner
   wheel is at its stop; an outward alpha_v_dot is absorbed).
4. *Coming to rest.* When the chassis rate, as the largest wheel rate |h_c,beta| |s_dot_c|, falls below
   ``omega_rest`` or crosses zero during a sub-step while |tau_c| <= F_c, the chassis stops (stiction):
   k = 1 with alpha_dot = f' alpha_v_dot (mode 2) or 0.

**Integration.** Classic RK4 on n = ceil(h / h_s) equal sub-steps of a communication step h, with
h_s = min(max_step, 2 / lambda) and lambda = max((d_vl + d_cl/eps)/C_l, (d_vr + d_cr/eps)/C_r,
(d_vw + d_cw/eps)/B_w), an upper bound of the friction stiffness of every mode, so the result is
stable for any communication step size and any eps. Torques are held constant over a communication step.

**Events.** A transition due at the start of a sub-step (a torque that changed at the communication point)
is taken there. Within a sub-step, an event -- a transition becoming due, or a steering stop (mode 2: the
alpha_v limit) reached -- is located by bisection on the RK4 step length to within 2^-50 of the remaining
sub-step, taken there, and the rest of the sub-step integrated from that point (at most 8 events per
sub-step). The switching times thus belong to the trajectory, not to the sub-step grid: the result does
not depend on the communication step beyond the RK4 truncation error.

State vector (13,): ``x_w, y_w, gamma_ch, alpha_l, alpha_r, alpha_v, beta_fl, beta_rl, beta_fr, beta_rr,
s_dot[0], s_dot[1], k`` (the C layout, plant.h).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from qomni.ident import dynamics, kinematics
from qomni.ident.symbolic import PARAMETER_NAMES

N_STATE = 13
X, Y, GAMMA, ALPHA, ALPHA_V, BETA, SDOT, K = 0, 1, 2, 3, 5, 6, 10, 12
DEFAULTS = {"mode_tol": 1e-3, "omega_rest": 0.02, "max_step": 2.5e-4}
"""Defaults of the plant's numerical settings (the FMU parameters of the same names)."""

_J = {name: j for j, name in enumerate(PARAMETER_NAMES)}


@dataclass(frozen=True)
class _Geometry:
    l: float
    b: float
    a: float
    r: float


@dataclass
class PlantParameters:
    """Parameters of the plant (the FMU's parameters of the same names, SI units).

    Attributes:
        p: (11,) p of (18). geometry: l, b, a, r (m). steering_limit: rad. i_G: gear ratio.
        eps: rad/s tanh sharpness. mode_tol: rad. omega_rest: rad/s (wheel side). max_step: s.
    """

    p: np.ndarray
    geometry: object
    i_G: float
    eps: float = dynamics.EPS
    steering_limit: float = math.pi / 2
    mode_tol: float = DEFAULTS["mode_tol"]
    omega_rest: float = DEFAULTS["omega_rest"]
    max_step: float = DEFAULTS["max_step"]
    _g: _Geometry = field(init=False, repr=False)

    def __post_init__(self):
        self.p = np.asarray(self.p, dtype=float)
        if self.p.shape != (11,):
            raise ValueError(f"p must have shape (11,), got {self.p.shape}")
        g = self.geometry
        self._g = _Geometry(float(g.l), float(g.b), float(g.a), float(g.r))
        if not (self.i_G > 0 and self.eps > 0 and self.max_step > 0 and self.mode_tol >= 0
                and self.omega_rest >= 0):
            raise ValueError("i_G, eps, max_step must be > 0 and mode_tol, omega_rest >= 0")

    def substep(self) -> float:
        """Largest RK4 sub-step h_s = min(max_step, 2 / lambda), s (module docstring)."""
        v = {n: self.p[j] for n, j in _J.items()}
        lam = max((v["d_vl"] + v["d_cl"] / self.eps) / v["C_l"], (v["d_vr"] + v["d_cr"] / self.eps) / v["C_r"],
                  (v["d_vw"] + v["d_cw"] / self.eps) / v["B_w"])
        return min(self.max_step, 2.0 / lam) if lam > 0 else self.max_step


def initial_state(P: "PlantParameters", pose0=(0.0, 0.0, 0.0), alpha0=(0.0, 0.0),
                  velocity0=(0.0, 0.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """Initial state (13,): world pose (x_w, y_w in m, gamma in rad), steering angles (rad) and velocity0 =
    (x_ch_dot, y_ch_dot, gamma_ch_dot, alpha_l_dot, alpha_r_dot). A zero chassis velocity starts at rest
    (k = 1); otherwise alpha0 must be within mode_tol of mode 2, 3 or 4's configuration: alpha is set onto
    it and the velocity projected onto that mode's s_dot_k (others dropped); beta = 0.

    Raises:
        ValueError: alpha0 beyond the stops, or a chassis velocity with alpha0 in no chassis mode.
    """
    alpha0 = np.asarray(alpha0, dtype=float)
    velocity0 = np.asarray(velocity0, dtype=float)
    if np.any(np.abs(alpha0) > P.steering_limit):
        raise ValueError(f"alpha0 {alpha0} beyond the stops +-{P.steering_limit}")
    s = np.zeros(N_STATE)
    s[X:X + 3] = pose0
    s[ALPHA:ALPHA + 2] = alpha0
    s[SDOT:SDOT + 2] = velocity0[3:5]
    s[K] = 1
    if not np.any(velocity0[:3] != 0):
        return s
    kc = configuration_mode(alpha0, P)
    if kc == 1:
        raise ValueError("an initial chassis velocity needs alpha0 in mode 2, 3 or 4's configuration")
    cfg, av = _configuration(kc, alpha0, P)
    _engage(s, kc, cfg, av, P)
    s[SDOT + _chassis_column(kc)] = velocity0[0] if kc == 2 else velocity0[1 if kc == 3 else 2]
    s[BETA:BETA + 4] = 0.0
    s[K] = kc
    return s


def configuration_mode(alpha, P: PlantParameters) -> int:
    """Motion mode (9) of alpha (2,) with tolerance P.mode_tol: 3, else 4, else 2, else 1."""
    alpha = np.asarray(alpha, dtype=float)
    g = P._g
    if np.max(np.abs(alpha - kinematics.mode_alpha(3, g))) <= P.mode_tol:
        return 3
    if np.max(np.abs(alpha - kinematics.mode_alpha(4, g))) <= P.mode_tol:
        return 4
    if kinematics.icr_residual(alpha, g)[0] <= P.mode_tol:
        return 2
    return 1


def _H(k, alpha, alpha_v, P):
    return kinematics.H(k, np.asarray(alpha, dtype=float)[None], P._g,
                        alpha_v=alpha_v if k == 2 else None)[0]


def _chassis_column(k: int) -> int:
    return 1 if k == 2 else 0


def _f_icr(alpha_v, P) -> np.ndarray:
    """f_ICR (8) without the range check of :func:`ident.kinematics.f_icr` (an RK4 stage may pass
    arctan(l/b) by a rounding error; the C code evaluates the same formula)."""
    s, c, g = math.sin(alpha_v), math.cos(alpha_v), P._g
    return np.array([math.atan2(g.l * s, g.l * c - g.b * s), math.atan2(g.l * s, g.l * c + g.b * s)])


def _derivative(k, y, u, P):
    alpha = _f_icr(y[ALPHA_V], P) if k == 2 else y[ALPHA:ALPHA + 2]
    nk = kinematics.N_GENERALIZED[k]
    q = np.zeros((1, 9))
    q[0, 3:5] = alpha
    sd = y[SDOT:SDOT + nk][None]
    av = y[ALPHA_V] if k == 2 else None
    sdd = dynamics.forward_dynamics(k, q, sd, u[None], P.p, P._g, P.i_G, P.eps, alpha_v=av)[0]
    qd = _H(k, alpha, av, P) @ sd[0]
    c, s = math.cos(y[GAMMA]), math.sin(y[GAMMA])
    dy = np.zeros(K)
    dy[X], dy[Y], dy[GAMMA] = c * qd[0] - s * qd[1], s * qd[0] + c * qd[1], qd[2]
    dy[ALPHA:ALPHA + 2] = qd[3:5]
    dy[ALPHA_V] = sd[0, 0] if k == 2 else 0.0
    dy[BETA:BETA + 4] = qd[5:9]
    dy[SDOT:SDOT + nk] = sdd
    return dy


def _set_alpha(y, target, P):
    H1 = _H(1, y[ALPHA:ALPHA + 2], None, P)
    y[BETA:BETA + 4] += H1[5:9] @ (np.asarray(target) - y[ALPHA:ALPHA + 2])
    y[ALPHA:ALPHA + 2] = target


def _chassis_force(k, alpha, alpha_v, u, P):
    h = _H(k, alpha, alpha_v, P)[5:9, _chassis_column(k)]
    return P.i_G * float(h @ u), P.p[_J["d_cw"]] * float(np.sum(np.abs(h))), float(np.max(np.abs(h)))


def _configuration(kc, alpha, P):
    if kc == 2:
        av = float(kinematics.alpha_v_from_alpha(alpha, P._g)[0])
        return kinematics.f_icr(av, P._g)[0], av
    return kinematics.mode_alpha(kc, P._g), 0.0


def _engage(y, kc, cfg, av, P):
    alpha_dot = y[SDOT:SDOT + 2].copy()
    _set_alpha(y, cfg, P)
    if kc == 2:
        f = _H(2, cfg, av, P)[3:5, 0]
        y[ALPHA_V] = av
        y[SDOT] = float(f @ alpha_dot) / float(f @ f)
    else:
        y[ALPHA_V] = 0.0
        y[SDOT] = 0.0
    y[SDOT + 1] = 0.0


def _try_engage(y, u, P) -> int:
    alpha = y[ALPHA:ALPHA + 2].copy()
    kc = configuration_mode(alpha, P)
    if kc == 1:
        return 1
    cfg, av = _configuration(kc, alpha, P)
    tau, F, _ = _chassis_force(kc, cfg, av, u, P)
    if not abs(tau) > F:
        return 1
    if kc == 3:
        H1b = _H(1, cfg, None, P)[5:9]
        for j, d_c in enumerate((P.p[_J["d_cl"]], P.p[_J["d_cr"]])):
            tau_s = P.i_G * float(H1b[:, j] @ u)
            F_s = d_c + P.p[_J["d_cw"]] * float(np.sum(np.abs(H1b[:, j])))
            if math.copysign(1.0, cfg[j]) * tau_s < -F_s:
                return 1
    _engage(y, kc, cfg, av, P)
    return kc


def _rest_due(k, y, u, P, v_start) -> bool:
    alpha = y[ALPHA:ALPHA + 2].copy()
    tau, F, hmax = _chassis_force(k, alpha, y[ALPHA_V] if k == 2 else 0.0, u, P)
    v = y[SDOT + _chassis_column(k)]
    slow = hmax * abs(v) < P.omega_rest or v * v_start < 0.0
    return slow and abs(tau) <= F


def _come_to_rest(k, y, P) -> int:
    if k == 2:
        f = _H(2, y[ALPHA:ALPHA + 2], y[ALPHA_V], P)[3:5, 0]
        y[SDOT:SDOT + 2] = f * y[SDOT]
    else:
        y[SDOT:SDOT + 2] = 0.0
    y[ALPHA_V] = 0.0
    return 1


def _transition(k, y, u, P, v_start) -> int:
    """The mode after the transition due at y (applied to y in place): engaging from rest, coming to rest."""
    if k == 1:
        return _try_engage(y, u, P)
    return _come_to_rest(k, y, P) if _rest_due(k, y, u, P, v_start) else k


def _stops(k, y, P, start) -> bool:
    """Apply the stops to y in place; whether a stop was reached that ``start`` was not at."""
    reached = False
    if k == 1:
        target = y[ALPHA:ALPHA + 2].copy()
        hit = np.abs(target) > P.steering_limit
        if np.any(hit):
            for j in np.flatnonzero(hit):
                target[j] = math.copysign(P.steering_limit, target[j])
                if y[SDOT + j] * target[j] > 0:
                    y[SDOT + j] = 0.0
                reached = reached or abs(start[ALPHA + j]) < P.steering_limit
            _set_alpha(y, target, P)
    elif k == 2:
        av_max = kinematics.alpha_v_max(P._g)
        if abs(y[ALPHA_V]) > av_max:
            reached = abs(start[ALPHA_V]) < av_max
            y[ALPHA_V] = math.copysign(av_max, y[ALPHA_V])
            if y[SDOT] * y[ALPHA_V] > 0:
                y[SDOT] = 0.0
        y[ALPHA:ALPHA + 2] = _f_icr(y[ALPHA_V], P)
    return reached


def _advance(k, y, u, P, theta):
    """(y advanced by theta in mode k with the stops applied, whether an event lies within theta)."""
    k1 = _derivative(k, y, u, P)
    k2 = _derivative(k, y + 0.5 * theta * k1, u, P)
    k3 = _derivative(k, y + 0.5 * theta * k2, u, P)
    k4 = _derivative(k, y + theta * k3, u, P)
    out = y + theta / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    event = _stops(k, out, P, y)
    return out, _transition(k, out.copy(), u, P, y[SDOT + _chassis_column(k)]) != k or event


MAX_EVENTS = 8
EVENT_RESOLUTION = 2.0 ** -50


def _substep(k, y, u, P, dt):
    """One sub-step (module docstring, 'Events'); returns (k, y)."""
    k = _transition(k, y, u, P, y[SDOT + _chassis_column(k)])
    rest, e = dt, 0
    while rest > 0.0:
        v_start = y[SDOT + _chassis_column(k)]
        nxt, event = _advance(k, y, u, P, rest)
        if not event or e >= MAX_EVENTS:
            return _transition(k, nxt, u, P, v_start), nxt
        lo, hi = 0.0, rest
        while hi - lo > EVENT_RESOLUTION * rest:
            mid = lo + 0.5 * (hi - lo)
            if _advance(k, y, u, P, mid)[1]:
                hi = mid
            else:
                lo = mid
        y = _advance(k, y, u, P, hi)[0]
        k = _transition(k, y, u, P, v_start)
        rest -= hi
        e += 1
    return k, y


def step(state, u, P: PlantParameters, h: float) -> np.ndarray:
    """Advance ``state`` (13,) by the communication step h > 0 s under motor torques u (4,) N m (motor
    side, held constant); returns the new state (module docstring). Raises ValueError for h <= 0 or
    non-finite torques."""
    u = np.asarray(u, dtype=float)
    if u.shape != (4,) or not np.all(np.isfinite(u)):
        raise ValueError(f"u must be 4 finite motor torques, got {u!r}")
    if not (h > 0 and math.isfinite(h)):
        raise ValueError(f"h must be > 0 and finite, got {h!r}")
    y = np.array(state[:K], dtype=float)
    k = int(state[K])
    n = max(1, math.ceil(h / P.substep() - 1e-9))
    for _ in range(n):
        k, y = _substep(k, y, u, P, h / n)
    return np.append(y, float(k))


def outputs(state, P: PlantParameters) -> dict[str, float | int | np.ndarray]:
    """The FMU's outputs of ``state``: pose (3,), velocity (3,) chassis frame, alpha, alpha_dot (2,),
    motor_position, motor_velocity (4,) motor side, k, k_configuration."""
    k = int(state[K])
    alpha = np.asarray(state[ALPHA:ALPHA + 2], dtype=float)
    nk = kinematics.N_GENERALIZED[k]
    qd = _H(k, alpha, state[ALPHA_V] if k == 2 else None, P) @ np.asarray(state[SDOT:SDOT + nk])
    return {"pose": np.array(state[X:X + 3]), "velocity": qd[:3], "alpha": alpha, "alpha_dot": qd[3:5],
            "motor_position": P.i_G * np.asarray(state[BETA:BETA + 4]), "motor_velocity": P.i_G * qd[5:9],
            "k": k, "k_configuration": configuration_mode(alpha, P)}


__all__ = ["N_STATE", "DEFAULTS", "PlantParameters", "initial_state", "configuration_mode", "step", "outputs"]
