"""The library of named physical hypotheses: unmodelled effects as nested extensions of the paper's
model.

Each hypothesis adds columns Φ_e to a channel so that the residual of the base model is explained as
``r ≈ Θ̂₁ δp + Φ_e θ_e`` (θ_e = 0 is the paper's model). Columns are built from what the vehicle puts
on the bus (recorded torques, encoder and steering-sensor angles, odometry) and the base model's
parameters — never from the emulator. Non-linear parameters (a delay, a Stribeck velocity) are
profiled over a grid; everything else enters linearly.

Sign convention: the residual is τ̂ − H_kᵀΘ̂p (measured generalized input minus the model's need), so a
resisting load that the model lacks gives a positive column.

Hypotheses (``Hypothesis.name`` equals the effect name the emulator's effects file uses):

=========================  ==============================================  =====================
name                       columns                                         magnitude reported
=========================  ==============================================  =====================
payload                    Θ̂_{m_ch}, Θ̂_{C_ch}, centre-of-mass offset       Δm [kg]
incline                    m_ch·g along world x, y in the chassis frame   angle [rad]
stribeck (wheels/steering) d_c·exp(−(v/v_s)²)·s(v), v_s profiled; s the   breakaway ratio − 1
                           direction of sliding, or of the motion ending a
                           stick
rolling_resistance         (m_ch g r / 4)·tanh(β̇_i/ε) per wheel           c_rr [-]
actuator_delay             H_kᵀB(u(t) − u(t − T_d)), T_d profiled           T_d [s]
torque_constant_error      −H_kᵀB e_j u_j for one drive j                  factor − 1 [-]
wheel_radius               (kinematic) predicted rolling angle; (torque)    r_nominal/r − 1 [-]
                           −(steering-joint terms) − 2·(Θ̂_{m_ch} m_ch +
                           Θ̂_{C_ch} C_ch): odometry's scale
backlash                   (kinematic, rolling) ½·sign(u_i)                 gap [rad, wheel side]
steering_compliance        (kinematic) linkage torque T; (torque) scrub    1/stiffness [rad/(N m)]
                           drag μN·|δ| of the toed rear wheels, δ = T/k
                           through the held joints' stiction play d_c/2;
                           the rotation's drag: s_rot/k, 0 ≤ s_rot ≤ 1.5
tire_slip                  (rolling) lateral slip of a rigid chassis whose  1/C_α [rad/N]
                           side forces need slip angles F/C_α
heavy_steering_units       exact point masses at the wheel centres          m_w [kg]
=========================  ==============================================  =====================
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from qomni.ident import filtering, kinematics
from qomni.ident.regressor_rows import model_alpha
from qomni.conventions import EPSILON as EPS_SIGN, FRONT_SIGN, GRAVITY, SIDE_INDEX, SIDE_SIGN

from .channels import ChannelData



@dataclass(frozen=True)
class Magnitude:
    """A hypothesis' physical size: value, 95 % interval, unit and what it is."""

    value: float
    ci: tuple[float, float]
    unit: str
    quantity: str


@dataclass(frozen=True)
class Hypothesis:
    """One named unmodelled effect.

    Attributes:
        name: effect name (``payload``, ``incline`` …).
        variant: which instance (``"drive fl"``, ``"joints=wheels"``) or ``""``.
        parameters: names of the linear coefficients θ.
        columns: ``(channel, nonlinear) -> (n, len(parameters))`` or None when the hypothesis does not
            act on that channel.
        grid: values of the profiled non-linear parameter (``(None,)`` if none).
        magnitude: ``(θ, cov θ, nonlinear, data sheet) -> Magnitude``.
        physical: ``θ -> bool``: whether the fitted sign is physically possible.
        absorbed_by: base parameters the columns are (nearly) collinear with, by construction.
        relevant: smallest size of practical relevance; a smaller effect is not reported as
            significant however well the data determine it.
        size: ``θ -> float``, the size ``relevant`` bounds (default |θ₀|, the first coefficient).
    """

    name: str
    variant: str
    parameters: tuple[str, ...]
    columns: Callable[[ChannelData, object], np.ndarray | None]
    grid: tuple = (None,)
    magnitude: Callable = None
    physical: Callable[[np.ndarray], bool] = lambda theta: True
    absorbed_by: tuple[str, ...] = ()
    nonlinear_unit: str = ""
    relevant: float = 0.0
    size: Callable[[np.ndarray], float] = lambda theta: abs(float(theta[0]))

    @property
    def label(self) -> str:
        return f"{self.name} ({self.variant})" if self.variant else self.name


def plausible(h: Hypothesis, theta: np.ndarray) -> bool:
    """Physically possible and of practically relevant size."""
    return bool(h.physical(theta)) and (h.relevant == 0 or h.size(theta) >= h.relevant)


# --- helpers ---------------------------------------------------------------------------------------
def _project(ch: ChannelData, Q: np.ndarray, smooth: bool = False) -> np.ndarray:
    """Generalized force Q (N, 9) of the step → the channel's rows H_k[:, :, j]ᵀQ; ``smooth``: low-pass
    at ω_g first (parallel filtering of non-smooth columns, as ``ident.identify`` does)."""
    ctx = ch.context
    if smooth:
        Q = filtering.zero_phase_lowpass(Q, ctx.st.cycle_time, ctx.st.omega_g)
    return ch.rows(np.einsum("ni,ni->n", ctx.H[:, :, ch.index], Q))


def _torque_only(fn):
    def wrapped(ch: ChannelData, nonlinear):
        return fn(ch, nonlinear) if ch.kind == "torque" else None
    return wrapped


def _kinematic_only(fn):
    def wrapped(ch: ChannelData, nonlinear):
        return fn(ch, nonlinear) if ch.kind == "kinematic" else None
    return wrapped


def _rolling_only(fn):
    def wrapped(ch: ChannelData, nonlinear):
        return fn(ch, nonlinear) if ch.kind == "rolling" else None
    return wrapped


def _rolling(ch: ChannelData, violation: np.ndarray) -> np.ndarray:
    """(N, 8) constraint-violation rates (m/s) of the step → the rolling channel's rows (n,)."""
    return ch.rows(ch.context.rolling.integrate(violation)[:, ch.index])


def _tyre_torque(ctx) -> np.ndarray:
    """(N, 4) wheel-side torque the drives pass on to the tyres, N m: i_G·u less the model's wheel
    friction d_cw·tanh(β̇/ε) + d_vw·β̇."""
    p, beta_d = ctx.p, ctx.st.qd[:, 5:9]
    return ctx.sheet.drive.i_G * ctx.st.motor_torque - p[9] * np.tanh(beta_d / EPS_SIGN) - p[8] * beta_d


def _ci(value: float, std: float, scale: float = 1.0) -> tuple[float, float]:
    return (scale * (value - 1.96 * std), scale * (value + 1.96 * std))


def _linear_magnitude(index: int, unit: str, quantity: str, scale: float = 1.0):
    def magnitude(theta, cov, nonlinear, sheet):
        v, s = float(theta[index]), float(math.sqrt(max(cov[index, index], 0.0)))
        return Magnitude(scale * v, _ci(v, s, scale), unit, quantity)
    return magnitude


def _input_torque(ch: ChannelData) -> np.ndarray:
    """(N, 9) B u with the step's filtered, aligned motor torques (N m wheel side on the β rows)."""
    st = ch.context.st
    Bu = np.zeros((len(st.time), 9))
    Bu[:, 5:9] = ch.context.sheet.drive.i_G * st.motor_torque
    return Bu


# --- payload ---------------------------------------------------------------------------------------
@_torque_only
def _payload_columns(ch: ChannelData, _):
    st = ch.context.st
    v, a = st.qd[:, :3], st.qdd[:, :3]
    w, wd = v[:, 2], a[:, 2]
    # Generalized chassis force of a mass with centre (x_c, y_c) in the chassis frame, per unit
    # first moment s = m·(x_c, y_c), beyond the model's diag(m, m, C) (Newton-Euler, body frame).
    Qx = np.zeros((len(w), 9))
    Qx[:, 0], Qx[:, 1], Qx[:, 2] = -w**2, wd, a[:, 1] + w * v[:, 0]
    Qy = np.zeros((len(w), 9))
    Qy[:, 0], Qy[:, 1], Qy[:, 2] = -wd, -w**2, -(a[:, 0] - w * v[:, 1])
    mass, inertia = ch.base[:, 6], ch.base[:, 7]
    return np.column_stack([mass, inertia, _project(ch, Qx), _project(ch, Qy)])


PAYLOAD = Hypothesis(
    "payload", "", ("delta_m", "delta_C", "m_x_c", "m_y_c"), _payload_columns,
    magnitude=_linear_magnitude(0, "kg", "added mass"),
    physical=lambda t: t[0] > 0 and t[1] > -1e-9,
    absorbed_by=("m_ch", "C_ch"))


# --- incline ---------------------------------------------------------------------------------------
@_torque_only
def _incline_columns(ch: ChannelData, _):
    ctx = ch.context
    gamma = ctx.pose[:, 2]
    m_g = ctx.p[6] * GRAVITY
    Qx = np.zeros((len(gamma), 9))
    Qy = np.zeros((len(gamma), 9))
    # World x and y unit vectors in the chassis frame (the downhill force's direction is fitted).
    Qx[:, 0], Qx[:, 1] = np.cos(gamma), -np.sin(gamma)
    Qy[:, 0], Qy[:, 1] = np.sin(gamma), np.cos(gamma)
    return m_g * np.column_stack([_project(ch, Qx), _project(ch, Qy)])


def _incline_magnitude(theta, cov, nonlinear, sheet):
    s = float(np.hypot(theta[0], theta[1]))
    grad = np.array(theta[:2]) / max(s, 1e-12)
    std = float(np.sqrt(max(grad @ cov[:2, :2] @ grad, 0.0)))
    lo, hi = min(max(s - 1.96 * std, 0.0), 1.0), min(s + 1.96 * std, 1.0)
    return Magnitude(math.asin(min(s, 1.0)), (math.asin(lo), math.asin(hi)), "rad", "floor inclination")


#: sin of 1 mrad (0.06°): a slope within an ordinary industrial floor's flatness tolerance (1–3 mm per m)
#: is no incline to report, however well a long campaign determines it.
INCLINE = Hypothesis("incline", "", ("sin_x", "sin_y"), _incline_columns, magnitude=_incline_magnitude,
                     relevant=math.sin(1e-3), size=lambda t: float(np.hypot(t[0], t[1])))


# --- Stribeck ----------------------------------------------------------------------------------------
#: rad/s, joint side: below this speed a joint is taken as sticking. Its friction then holds against the
#: motion that breaks it loose, so its direction is that motion's, which tanh(v/ε) of the filtered speed
#: (≈ 0 there) does not give: the stick-slip transients at every reversal are where a friction peak
#: shows most, and the filter spreads them into the moving rows next to the stuck ones.
STICK_VELOCITY = 0.01


def _friction_direction(v: np.ndarray) -> np.ndarray:
    """(N, m) direction friction acts in, within ±1: tanh(v/ε) where a joint slides, and where it sticks
    the sign of the motion that ends the stick (the motion before it if none follows)."""
    v = np.asarray(v, dtype=float)
    out = np.tanh(v / EPS_SIGN)
    rows = np.arange(len(v))
    for j in range(v.shape[1]):
        sliding = np.abs(v[:, j]) > STICK_VELOCITY
        if not sliding.any():
            continue
        slide_rows = rows[sliding]
        # the first sliding row after each stuck one, or the last sliding row when none follows
        after = np.minimum(np.searchsorted(slide_rows, rows[~sliding]), len(slide_rows) - 1)
        out[~sliding, j] = np.sign(v[slide_rows[after], j])
    return out


def _stribeck(v, v_s):
    return np.exp(-(v / v_s) ** 2) * _friction_direction(v)


STRIBECK_VELOCITIES = (0.02, 0.05, 0.1, 0.2, 0.4)  # rad/s, joint side


@_torque_only
def _stribeck_wheel_columns(ch: ChannelData, v_s):
    st = ch.context.st
    Q = np.zeros((len(st.time), 9))
    Q[:, 5:9] = ch.context.p[9] * _stribeck(st.qd_coulomb[:, 5:9], v_s)
    return _project(ch, Q, smooth=True)[:, None]


@_torque_only
def _stribeck_steering_columns(ch: ChannelData, v_s):
    ctx = ch.context
    peak = _stribeck(ctx.alpha_dot_encoder, v_s)
    Q = np.zeros((len(ctx.st.time), 9))
    Q[:, 3] = ctx.p[2] * peak[:, 0]
    Q[:, 4] = ctx.p[5] * peak[:, 1]
    return _project(ch, Q, smooth=True)[:, None]


STRIBECK_WHEELS = Hypothesis(
    "stribeck", "joints=wheels", ("breakaway_excess",), _stribeck_wheel_columns, STRIBECK_VELOCITIES,
    magnitude=_linear_magnitude(0, "-", "breakaway/Coulomb − 1 (wheel joints)"),
    physical=lambda t: t[0] > 0, nonlinear_unit="rad/s (Stribeck velocity)")
STRIBECK_STEERING = Hypothesis(
    "stribeck", "joints=steering", ("breakaway_excess",), _stribeck_steering_columns,
    STRIBECK_VELOCITIES, magnitude=_linear_magnitude(0, "-", "breakaway/Coulomb − 1 (steering joints)"),
    physical=lambda t: t[0] > 0, nonlinear_unit="rad/s (Stribeck velocity)")


# --- rolling resistance ------------------------------------------------------------------------------
@_torque_only
def _rolling_columns(ch: ChannelData, _):
    st, sheet = ch.context.st, ch.context.sheet
    load = ch.context.p[6] * GRAVITY / 4
    Q = np.zeros((len(st.time), 9))
    Q[:, 5:9] = load * sheet.geometry.r * np.tanh(st.qd_coulomb[:, 5:9] / EPS_SIGN)
    return _project(ch, Q, smooth=True)[:, None]


#: c_rr below 0.003 (a sixth of the wheel's own Coulomb friction as an equivalent c_rr) is within what
#: a small error of another effect (e.g. the wheel radius' lever on d_cw) shifts; tyres on floors have
#: 0.005–0.02.
ROLLING_RESISTANCE = Hypothesis(
    "rolling_resistance", "", ("c_rr",), _rolling_columns,
    magnitude=_linear_magnitude(0, "-", "rolling-resistance coefficient"),
    physical=lambda t: t[0] > 0, absorbed_by=("d_cw",), relevant=0.003)


# --- actuator delay ----------------------------------------------------------------------------------
DELAY_STEPS = tuple(range(1, 13))  # cycles of T_s


@_torque_only
def _delay_columns(ch: ChannelData, cycles):
    Bu = _input_torque(ch)
    delayed = np.vstack([np.repeat(Bu[:1], cycles, axis=0), Bu[:-cycles]])
    return _project(ch, Bu - delayed)[:, None]


def _delay_magnitude(theta, cov, cycles, sheet):
    # u(t) − u(t − T) ≈ T·u̇: gain·T is the delay to first order, whatever grid point fits best.
    T = cycles * sheet.drive.cycle_time
    g, s = float(theta[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
    return Magnitude(g * T, _ci(g, s, T), "s", "delay commanded → applied torque")


ACTUATOR_DELAY = Hypothesis("actuator_delay", "", ("gain",), _delay_columns, DELAY_STEPS,
                            magnitude=_delay_magnitude, physical=lambda t: 0.3 < t[0] < 3.0,
                            nonlinear_unit="cycles")


# --- torque constant of one drive ------------------------------------------------------------------
def _torque_constant(j: int):
    @_torque_only
    def columns(ch: ChannelData, _):
        Bu = _input_torque(ch)
        Q = np.zeros_like(Bu)
        Q[:, 5 + j] = Bu[:, 5 + j]
        return -_project(ch, Q)[:, None]
    return columns


TORQUE_CONSTANT = tuple(
    Hypothesis("torque_constant_error", f"drive {w}", ("factor_minus_one",), _torque_constant(j),
               magnitude=_linear_magnitude(0, "-", f"torque-constant factor − 1 of drive {w}"))
    for j, w in enumerate(("fl", "rl", "fr", "rr")))


# --- kinematic hypotheses ----------------------------------------------------------------------------
def _radius_columns(ch: ChannelData, _):
    if ch.kind == "rolling":
        return None  # one radius error scales every wheel's rolling alike: a rigid twist, not redundant
    if ch.kind == "torque":
        # ε = r_nominal/r − 1. The encoders and the steering sensor measure the joint angles exactly;
        # the chassis motion odometry takes from the wheels with r_nominal is (1 + ε) times the true
        # one. Written in the measured coordinates, the true rows of (19) keep every wheel-joint term
        # (input, d_vw, d_cw, B_w) and read the steering joints' (C, d_v, d_c of both sides) through a
        # lever 1/(1 + ε) and the chassis inertia (m_ch, C_ch) through 1/(1 + ε)²: the residual is
        # −ε·(steering-joint terms) − 2ε·(chassis terms) to first order. (A lever 1 + ε on the input,
        # the column before, also scales the wheels' friction; a 4 % smaller wheel left 18 N of a
        # 39 N residual in straight driving under it, 1.2 N against a 1.3 N floor under this one.)
        terms = ch.base * ch.context.p[:10]
        return (-terms[:, :6].sum(axis=1) - 2.0 * terms[:, 6:8].sum(axis=1))[:, None]
    st, side = ch.context.st, SIDE_INDEX[ch.index]
    H1 = ch.context.H[:, 5 + ch.index, side]
    return ch.rows(H1 * (st.q[:, 3 + side] - st.q[0, 3 + side]))[:, None]


def _radius_magnitude(theta, cov, nonlinear, sheet):
    v, s = float(theta[0]), float(math.sqrt(max(cov[0, 0], 0.0)))
    r = sheet.geometry.r
    return Magnitude(r / (1 + v), (r / (1 + v + 1.96 * s), r / (1 + v - 1.96 * s)), "m",
                     "effective wheel radius")


#: 0.25 % of r (0.25 mm on the prototype): the soft contact alone flattens a wheel by about as much, and
#: two runs of the same vehicle differ by ~0.03 %; a real radius error of worn or other tyres is 1–5 %.
WHEEL_RADIUS = Hypothesis("wheel_radius", "", ("r_ratio_minus_one",), _radius_columns,
                          magnitude=_radius_magnitude, relevant=0.0025)

BACKLASH_TORQUE_SCALE = 0.05  # N m motor side: torque below which the gear floats in its gap


def _backlash_columns(ch: ChannelData, _):
    if ch.kind == "torque":
        return None
    st = ch.context.st
    if ch.kind == "kinematic":
        return ch.rows(0.5 * np.tanh(st.motor_torque[:, ch.index] / BACKLASH_TORQUE_SCALE))[:, None]
    # The encoder reads the motor, half the gap ahead of the wheel in the direction of the torque: the
    # longitudinal rows (−r β̇) see the rate of that lead.
    lead = 0.5 * np.tanh(st.motor_torque / BACKLASH_TORQUE_SCALE)
    violation = np.zeros((len(st.time), 8))
    violation[:, 4:] = -ch.context.sheet.geometry.r * np.gradient(lead, st.cycle_time, axis=0)
    return _rolling(ch, violation)[:, None]


#: 0.3 mrad (1 arcmin) at the gear output: what precision gearboxes are specified at; less is no backlash
#: of practical consequence (standard planetary gears have 3–6 mrad).
BACKLASH = Hypothesis("backlash", "", ("gap",), _backlash_columns,
                      magnitude=_linear_magnitude(0, "rad", "gear backlash (wheel side)"),
                      physical=lambda t: t[0] > 0, relevant=3e-4)


#: Tyre/floor friction coefficient the scrub of a toed wheel is taken at (dry rubber on concrete, the
#: low end of 0.8–1.0): the vehicle's data sheet has none.
SCRUB_FRICTION = 0.8


def _linkage_torque(H1: np.ndarray, wheel_torque: np.ndarray) -> np.ndarray:
    """(N, 2) torque each side's front/rear linkage carries, left then right, N m.

    A wheel torque w_i acts on its steering joint as (H₁)_{β_i}·w_i (virtual work, chassis at rest: a
    tyre force F at the offset a gives a·F). The linkage holds the two joints mirrored, so it carries
    half their difference — which makes them turn alike."""
    return np.column_stack([0.5 * (H1[:, 5 + f, s] * wheel_torque[:, f] - H1[:, 5 + r, s] * wheel_torque[:, r])
                            for s, (f, r) in enumerate(((0, 1), (2, 3)))])


def _compliance_kinematic(ch: ChannelData) -> np.ndarray:
    i = ch.index
    if FRONT_SIGN[i] > 0:
        return ch.rows(np.zeros(len(ch.context.st.time)))[:, None]
    ctx, side = ch.context, SIDE_INDEX[ch.index]
    # the rear joint deflects by the linkage torque / stiffness and its wheel rolls with it
    coupling = _linkage_torque(ctx.H, ctx.sheet.drive.i_G * ctx.st.motor_torque)[:, side]
    return ch.rows(ctx.H[:, 5 + i, side] * coupling * FRONT_SIGN[i])[:, None]


#: rad/s: a side's steering joints count as held (static friction engaged) below this filtered speed. A
#: held front unit still wanders with a soft linkage's deflection: up to 0.03 rad/s in straight driving and
#: rotation at 800 N m/rad (0.003 with a rigid one), far below the lane change's steering rates.
HELD_STEERING_SPEED = 0.05

#: Steps whose scrub drag gets a coefficient s_rot/k of its own. In the rotation the chassis turns about
#: its centre and the other wheels take up part of a rear wheel's toe: fitted with the true deflection
#: (an emulator run with the truth recorded, 800 N m/rad), its drag is 0.74 of the μN|δ| straight driving
#: and the lane change show (R² 0.89 against 0.92 and 0.98), where the toed wheel slides fully.
ROTATION_STEPS = ("rotation",)


def play(x: np.ndarray, width: np.ndarray) -> np.ndarray:
    """The play (backlash) operator: y follows x only where |x − y| exceeds ``width``, then at that
    distance; it starts at y = x[0]. (N,), (N,) → (N,), in x's unit; width 0 passes x through."""
    y = np.empty(len(x))
    current = float(x[0])
    for i, (v, w) in enumerate(zip(np.asarray(x, float), np.asarray(width, float))):
        current = min(max(current, v - w), v + w)
        y[i] = current
    return y


def _linkage_deflection(ctx) -> np.ndarray:
    """(N, 2) deflection k·δ of each side's linkage, left then right, N m (δ in rad per unit 1/k).

    Where the steering moves, the two joints' Coulomb friction acts mirrored and cancels in the linkage:
    k·δ = T, the torque :func:`_linkage_torque` of the tyres' longitudinal forces at the mode's angles.
    Where the side's steering is held, each joint's static friction takes up to d_c/2 of the torque
    before the linkage deflects further: k·δ follows T through a play of that width (d_cl, d_cr the
    model's)."""
    st, g, p = ctx.st, ctx.sheet.geometry, ctx.p
    H1 = kinematics.H(1, model_alpha(st, g), g)
    T = _linkage_torque(H1, _tyre_torque(ctx))
    out = np.empty_like(T)
    for side, d_c in ((0, p[2]), (1, p[5])):
        held = np.abs(st.qd[:, 3 + side]) <= HELD_STEERING_SPEED
        out[:, side] = play(T[:, side], np.where(held, abs(d_c) / 2, 0.0))
    return out


def _compliance_scrub(ch: ChannelData) -> np.ndarray:
    """Drag of the rear wheels toed by the linkage's deflection, as generalized force per unit 1/k.

    The linkage deflects by δ (:func:`_linkage_deflection`), which toes the rear wheel by δ away from
    the mirror of the measured front angle. A toed wheel slides sideways at |v|·δ under the lateral
    friction μN, and the component μN|δ| of that force along its travel is a drag."""
    ctx = ch.context
    st, g, p = ctx.st, ctx.sheet.geometry, ctx.p
    deflection = np.abs(_linkage_deflection(ctx))   # × 1/k, rad
    load = SCRUB_FRICTION * p[6] * GRAVITY / 4
    Q = np.zeros((len(st.time), 9))
    Q[:, [6, 8]] = load * g.r * deflection * np.tanh(st.qd_coulomb[:, [6, 8]] / EPS_SIGN)
    return _project(ch, Q, smooth=True)[:, None]


def _compliance_columns(ch: ChannelData, _):
    """Columns (1/k, s_rot/k): the rear wheels' rolling with the deflection (kinematic channels) and the
    scrub drag of driving straight and of the lane change carry 1/k; the rotation's scrub has its own
    coefficient (:data:`STEERING_COMPLIANCE`)."""
    if ch.kind == "kinematic":
        column = _compliance_kinematic(ch)
    elif ch.kind == "torque":
        column = _compliance_scrub(ch)
    else:
        return None
    zero = np.zeros_like(column)
    return np.hstack([zero, column] if ch.context.step in ROTATION_STEPS else [column, zero])


#: 1e-4 rad/(N m) (a linkage of 10 kN m/rad): the campaign's typical tyre forces (≈ 250 N, a·F ≈ 20 N m
#: on the linkage) then toe a rear wheel by < 2 mrad, within an ordinary wheel-alignment tolerance (±0.1°).
#: 1/k: the straight and lane-change drag and the kinematic channels; s_rot/k, 0 ≤ s_rot ≤ S_ROT_MAX:
#: the rotation's share of full sliding. More than full sliding is no scrub of this linkage; the bound
#: leaves room for the two deflection models' errors (fitted s_rot: 0.93–1.01 at 800 N m/rad on full
#: campaigns), not for the 4× 1/k of the drives fighting sticking steering joints.
S_ROT_MAX = 1.5
STEERING_COMPLIANCE = Hypothesis(
    "steering_compliance", "", ("compliance", "compliance_rotation"), _compliance_columns,
    magnitude=_linear_magnitude(0, "rad/(N m)", "front/rear coupling compliance 1/k "
                                f"(scrub taken at μ = {SCRUB_FRICTION})"),
    physical=lambda t: t[0] > 0 and 0 <= t[1] <= S_ROT_MAX * t[0], relevant=1e-4)


# --- tyre slip ---------------------------------------------------------------------------------------
#: m/s: rolling speed below which a wheel's slip velocity is taken at this floor (a tyre's relaxation
#: length makes the side force lag at standstill instead of growing without bound).
SLIP_SPEED_FLOOR = 0.02


@_rolling_only
def _slip_columns(ch: ChannelData, _):
    ctx = ch.context
    st, g, p = ctx.st, ctx.sheet.geometry, ctx.p
    A = ctx.rolling.A
    beta_d = st.qd[:, 5:9]
    # Longitudinal tyre forces from the drives and their generalized chassis force; what the chassis'
    # inertia needs beyond it the side forces must supply.
    f_long = _tyre_torque(ctx) / g.r
    drive = np.einsum("nij,ni->nj", A[:, 4:8, :3], f_long)
    v, acc = st.qd[:, :3], st.qdd[:, :3]
    inertia = np.column_stack([p[6] * (acc[:, 0] - v[:, 2] * v[:, 1]), p[6] * (acc[:, 1] + v[:, 2] * v[:, 0]),
                               p[7] * acc[:, 2]])
    required = inertia - drive
    # Side force F_i = −C_α s_i/|v_i| through the lateral slip velocity s_i of a rigid chassis,
    # s = E_latᵀδ: the slip twist δ solves E_lat D⁻¹ E_latᵀ δ = −C_α⁻¹·required (D = diag|v_i|).
    # At the mode's nominal angles: there the side forces of mode 4 (radial) have no moment, and pinv
    # leaves the yaw share of ``required`` (the torque channel's business) out instead of amplifying it.
    E = np.broadcast_to(ctx.rolling.A_ch_nominal[0:4].T, (len(st.time), 3, 4))
    d_inv = 1.0 / np.maximum(g.r * np.abs(beta_d), SLIP_SPEED_FLOOR)
    K = np.einsum("nik,nk,njk->nij", E, d_inv, E)
    delta = np.einsum("nij,nj->ni", np.linalg.pinv(K, rcond=1e-6), required)
    violation = np.zeros((len(st.time), 8))
    violation[:, :4] = -np.einsum("nik,ni->nk", E, delta)  # per unit 1/C_α
    return _rolling(ch, violation)[:, None]


#: 1/C_α below 2e-5 rad/N (C_α above 50 kN/rad, 1 mrad of slip angle per 50 N; stiffer than the
#: stiffest tyre of this class, 30 kN/rad) is rigid contact for the platform's speeds. The ideal emulator's
#: contact fits ~4e-6 rad/N; an 8 ms actuator delay's torque ripple makes the wheels creep like 1.1e-5.
TIRE_SLIP = Hypothesis("tire_slip", "", ("inverse_cornering_stiffness",), _slip_columns,
                       magnitude=_linear_magnitude(0, "rad/N", "1/C_α per wheel"),
                       physical=lambda t: t[0] > 0, relevant=2e-5)


# --- heavy steering units ------------------------------------------------------------------------------
@_torque_only
def _heavy_columns(ch: ChannelData, _):
    ctx = ch.context
    st, g = ctx.st, ctx.sheet.geometry
    n = len(st.time)
    v, acc = st.qd[:, :3], st.qdd[:, :3]
    w, wd = v[:, 2], acc[:, 2]
    alpha, alpha_d, alpha_dd = model_alpha(st, g), st.qd[:, 3:5], st.qdd[:, 3:5]
    if ctx.k in (3, 4):
        alpha_d = alpha_dd = np.zeros_like(alpha)
    Q = np.zeros((n, 9))
    lumped = np.zeros((n, 9))
    for i in range(4):
        s, sigma, side = SIDE_SIGN[i], FRONT_SIGN[i], SIDE_INDEX[i]
        P = np.array([sigma * g.l / 2, s * g.b / 2])
        phi, phid, phidd = sigma * alpha[:, side], sigma * alpha_d[:, side], sigma * alpha_dd[:, side]
        e = np.column_stack([-np.sin(phi), np.cos(phi)])
        de = np.column_stack([-np.cos(phi), -np.sin(phi)])  # d e / d phi
        c = P + s * g.a * e
        cd = s * g.a * de * phid[:, None]
        cdd = s * g.a * (de * phidd[:, None] - e * (phid**2)[:, None])
        # Inertial acceleration of the wheel centre, chassis-frame components.
        A = (acc[:, :2] + np.column_stack([-w * v[:, 1], w * v[:, 0]])
             + np.column_stack([-wd * c[:, 1], wd * c[:, 0]]) - (w**2)[:, None] * c
             + 2 * np.column_stack([-w * cd[:, 1], w * cd[:, 0]]) + cdd)
        Q[:, 0] += A[:, 0]
        Q[:, 1] += A[:, 1]
        Q[:, 2] += -c[:, 1] * A[:, 0] + c[:, 0] * A[:, 1]
        Q[:, 3 + side] += sigma * s * g.a * np.einsum("nj,nj->n", de, A)
        # What the lumped model already holds for this mass: m_ch, C_ch + C_side at α = 0, C_side.
        c0 = P + s * g.a * np.array([0.0, 1.0])
        lumped[:, 0] += acc[:, 0] - w * v[:, 1]
        lumped[:, 1] += acc[:, 1] + w * v[:, 0]
        lumped[:, 2] += float(c0 @ c0) * wd
        lumped[:, 3 + side] += g.a**2 * alpha_dd[:, side]
    return _project(ch, Q - lumped)[:, None]


HEAVY_STEERING_UNITS = Hypothesis(
    "heavy_steering_units", "", ("wheel_mass",), _heavy_columns,
    magnitude=_linear_magnitude(0, "kg", "mass per steering unit at the wheel centre"),
    physical=lambda t: t[0] > 0)


LIBRARY: tuple[Hypothesis, ...] = (
    PAYLOAD, INCLINE, STRIBECK_WHEELS, STRIBECK_STEERING, ROLLING_RESISTANCE, ACTUATOR_DELAY,
    *TORQUE_CONSTANT, WHEEL_RADIUS, BACKLASH, STEERING_COMPLIANCE, TIRE_SLIP, HEAVY_STEERING_UNITS,
)
"""Every hypothesis the diagnosis tests."""



# --- generic structure (not a named effect) -----------------------------------------------------------
def generic(channel: str) -> Hypothesis:
    """A black-box extension of one channel — residual on its own velocity, acceleration, friction sign,
    input delayed by 10 and 30 ms, (kinematic) the steering excursion and drive torque, (rolling) integrals
    of the speed and input — used to
    tell "unexplained structure remains" from noise when no named hypothesis is significant."""

    def columns(ch: ChannelData, _):
        if ch.name != channel:
            return None
        v, acc = ch.velocity, ch.acceleration
        if ch.kind == "torque":
            y = ch.y
            lagged = [np.concatenate([np.repeat(y[:1], n), y[:-n]]) - y for n in (5, 15)]
            return np.column_stack([v, acc, np.tanh(v / EPS_SIGN), v * np.abs(v), *lagged])
        if ch.kind == "rolling":
            # positions: the integrals of the speed's odd and even powers and the generalized input
            ts = ch.context.st.cycle_time
            u = ch.rows(ch.context.st.motor_torque.sum(axis=1))
            return np.cumsum(np.column_stack([v, np.abs(v), v * v * v, u]), axis=0) * ts
        u = ch.rows(ch.context.st.motor_torque[:, ch.index])
        alpha = ch.rows(ch.context.st.q[:, 3 + SIDE_INDEX[ch.index]])
        return np.column_stack([alpha - alpha[0], u, np.tanh(u / BACKLASH_TORQUE_SCALE), v])

    names = (("c_alpha", "c_u", "c_sign_u", "c_v") if "/kinematic_" in channel
             else ("c_v", "c_abs_v", "c_v3", "c_u") if "/rolling_" in channel
             else ("c_v", "c_a", "c_sign", "c_v2", "c_u5", "c_u15"))
    return Hypothesis("unexplained", channel, names, columns, magnitude=lambda theta, cov, nl, sheet: Magnitude(
                          float(np.linalg.norm(theta)), (0.0, 0.0), "-", "black-box coefficients"))


__all__ = ["Hypothesis", "Magnitude", "LIBRARY", "GRAVITY", "generic", "plausible"]
