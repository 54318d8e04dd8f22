"""The contract every hypothesis plug-in fills (:class:`Hypothesis`, :class:`Magnitude`) and the helpers
that turn a generalized force or a constraint violation into a channel's columns."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from qomni.conventions import EPSILON as EPS_SIGN
from qomni.ident import filtering

from ..channels import ChannelData


#: :attr:`Hypothesis.lifted`: the effect needs ground contact or a moving chassis (rolling resistance, a
#: tyre's slip, an incline, a payload): absent on lifted wheels.
LIFTED_ABSENT = "absent"
#: :attr:`Hypothesis.lifted`: the effect acts through the drives or the wheel joints, and its columns give
#: the lifted rows (a delay, a torque constant, wheel-joint friction).
LIFTED_MODELLED = "modelled"
#: :attr:`Hypothesis.lifted`: the effect acts on lifted wheels, but its columns are built for the
#: vehicle on its wheels (a backlash's transients through the mode's dynamics).
LIFTED_UNMODELLED = "unmodelled"


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
        grid: values of the profiled non-linear parameter (``(None,)`` if none; a tuple per point where
            it profiles several, :attr:`profiled`).
        magnitude: ``(θ, cov θ, nonlinear, data sheet) -> Magnitude``.
        physical: ``θ -> bool``: whether the fitted sign is physically possible.
        absorbed_by: base parameters the columns are (nearly) collinear with, by construction.
        free_base: the hypothesis tested in this one's place where the base parameters are free (a
            model identified on the diagnosed data, :func:`qomni.diagnosis.hypotheses.library`): the
            coefficients whose columns are base columns (``absorbed_by``) are then the base's, their
            fitted values are set by the solver's minimum norm, not by the data, and the hypothesis
            keeps only the rest. None: tested as it is.
        relevant: smallest size of practical relevance; a smaller effect is not reported as
            significant however well the data determine it.
        size: ``θ -> float``, the size ``relevant`` bounds (default |θ₀|, the first coefficient).
        folds_into: the paper's parameters that can carry the effect once identified:
            ``{parameter of p₁: (coefficient θ name, scale(p (11,), r [m]) -> float)}``; the effect then
            needs no term of its own in a forward simulation (p[parameter] += θ·scale).
        resolve: a rule between this hypothesis' variants, ``(candidates, rows: RuleRows) -> None``, run
            once on the ranked candidates; it may change their ``significant`` flags and notes (e.g.
            which joints low-speed friction is placed in). Variants of one effect share the rule.
        lifted: how the effect acts on the lifted vehicle's wheels (the diagnosis' lifted channel,
            :func:`qomni.diagnosis.channels.lifted_channel`): :data:`LIFTED_ABSENT` it needs ground
            contact or a moving chassis, and the channel gets no columns; :data:`LIFTED_MODELLED` it acts
            through the drives or the wheel joints and ``columns`` gives its lifted rows (the generalized
            force on the wheel coordinates, as on the ground); :data:`LIFTED_UNMODELLED` it acts there but
            its columns do not describe it, and held-out comparisons leave the channel out.
    """

    name: str
    variant: str
    parameters: tuple[str, ...]
    columns: Callable[[ChannelData, object], np.ndarray | None]
    grid: tuple = (None,)
    magnitude: Callable = None
    physical: Callable[[np.ndarray], bool] = lambda theta: True
    absorbed_by: tuple[str, ...] = ()
    free_base: "Hypothesis | None" = None
    nonlinear_unit: str = ""
    relevant: float = 0.0
    size: Callable[[np.ndarray], float] = lambda theta: abs(float(theta[0]))
    folds_into: Mapping[str, tuple[str, Callable[[np.ndarray, float], float]]] = field(default_factory=dict)
    resolve: Callable | None = None
    lifted: str = LIFTED_ABSENT

    @property
    def label(self) -> str:
        return f"{self.name} ({self.variant})" if self.variant else self.name

    @property
    def profiled(self) -> int:
        """How many non-linear parameters the grid profiles: 0 without one, else the length of a grid
        point (a tuple per point where it profiles several, e.g. the backlash's crossing time and width)."""
        if self.grid == (None,):
            return 0
        return len(self.grid[0]) if isinstance(self.grid[0], tuple) else 1


def columns_on(h: Hypothesis, ch: ChannelData, nonlinear) -> np.ndarray | None:
    """``h.columns(ch, nonlinear)``, None on a lifted channel where the effect is not modelled there
    (:attr:`Hypothesis.lifted`): the one entry to a hypothesis' columns."""
    if ch.context.lifted and h.lifted != LIFTED_MODELLED:
        return None
    return h.columns(ch, nonlinear)


@dataclass(frozen=True)
class RuleRows:
    """What a hypothesis' ``resolve`` rule may fit on: the diagnosed run with every row a fit row
    (``all_rows``), the reference run's problem or None, the model, the correlation lag (rows) and the
    fit cache (:mod:`qomni.diagnosis.fit`); the diagnosed run's lifted-wheel measurement
    (:attr:`qomni.ident.rundir.LiftedMeasurement.wheels`) or None; and the lane change's steering channel
    (:data:`qomni.diagnosis.channels.LANE_CHANGE_STEERING`, not a fitted channel of the diagnosis) of the
    diagnosed run and of the reference run, every row a fit row and paired as the torque channels are, or
    None where the run has no lane change; the lifted wheels' breakaway excess (excess, σ)
    (:attr:`qomni.ident.rundir.LiftedMeasurement.breakaway`) or None; the significance level the round's
    candidates were tested at (None: the first round's, :data:`qomni.diagnosis.fit.ALPHA`; in forward
    selection :func:`qomni.diagnosis.fit.alpha_more`)."""

    all_rows: object
    reference: object | None
    model: object
    lag: int
    cache: dict
    lifted_wheels: dict | None = None
    steering: object | None = None
    steering_reference: object | None = None
    lifted_breakaway: tuple[float, float] | None = None
    level: float | None = None


def plausible(h: Hypothesis, theta: np.ndarray) -> bool:
    """Physically possible and of practically relevant size."""
    return bool(h.physical(theta)) and (h.relevant == 0 or h.size(theta) >= h.relevant)


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


#: z of a two-sided 95 % interval: every magnitude's interval is value ± Z_95·σ.
Z_95 = 1.96


def interval_95(value: float, std: float, scale: float = 1.0) -> tuple[float, float]:
    """The 95 % interval scale·(value ± Z_95·std) of a normal estimate, every magnitude's and coefficient's
    interval in ``gap.json``; value and std in the coefficient's unit, scale to the reported one."""
    return (scale * (value - Z_95 * std), scale * (value + Z_95 * std))


def _linear_magnitude(index: int, unit: str, quantity: str, scale: float = 1.0):
    def magnitude(theta, cov, nonlinear, sheet):
        v, s = float(theta[index]), float(math.sqrt(max(cov[index, index], 0.0)))
        return Magnitude(scale * v, interval_95(v, s, scale), unit, quantity)
    return magnitude


def _delayed(x: np.ndarray, rows: int) -> np.ndarray:
    """``x`` (N, …) delayed by ``rows`` ≥ 0 samples along its first axis, its first row held before the
    start."""
    if rows == 0:
        return x
    return np.concatenate([np.repeat(x[:1], rows, axis=0), x[:-rows]], axis=0)


def _input_torque(ch: ChannelData) -> np.ndarray:
    """(N, 9) B u with the step's filtered, aligned motor torques (N m wheel side on the β rows)."""
    st = ch.context.st
    Bu = np.zeros((len(st.time), 9))
    Bu[:, 5:9] = ch.context.sheet.drive.i_G * st.motor_torque
    return Bu
