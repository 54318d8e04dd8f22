"""The residual channels of a recorded campaign under a given model.

Three kinds of channel, one per (campaign step, quantity), and the lifted run's:

* **torque** channels — the generalized torque of the step's excited coordinate: measured
  ``τ̂ = H_kᵀBu`` minus the model ``H_kᵀΘ̂p`` of the paper's (19), filtered exactly as for
  identification (``ident.identify``). Rows in stiction (|ṡ| below ``ident.identify.VELOCITY_THRESHOLD``)
  are kept for the regime breakdown but not fitted: static friction is indeterminate there.
* **rolling** channels — in the rotation step (mode 4) the chassis twist is fixed by the steering
  angles, and the eight rolling constraints (1) of the four wheels (lateral and longitudinal) hold three
  unknowns only. The measured ``A(α)q̇`` projected onto the five redundant directions (the left null space
  of ``A_ch`` at the mode's nominal angles) and integrated over time is zero up to constants for rolling
  without slip; tyre slip and backlash break it. Channel ``rotation/rolling_<j>``, j = 1…5, in m.
* **kinematic** channels — in the steering steps (mode 1, chassis at rest) every wheel of the steered
  side rolls on a circle of radius a about its steering axis, so its encoder angle and the steering
  sensor are tied by the rolling constraint (1): ``β_i − β_i(t₀) = (H₁)_{β_i}(α − α(t₀))``. The model
  predicts a residual of zero up to a constant; wheel radius, backlash and coupling compliance break it.
* the **lifted** channel — the lifted vehicle's single-axis run, a torque channel of the four wheels'
  rows (:func:`lifted_channel`), held out and never fitted.

Rows where a drive is at its torque limit (and ``TRACTION_MARGIN`` around them) are not fitted in any
channel: a wheel driven that hard may spin or skid, and then neither the rolling constraint nor the
model's generalized forces hold. A kinematic channel's constant of integration is free per stretch
between such rows, since a wheel that slid has lost its reference.

A channel carries everything a hypothesis needs to build its columns (``ChannelData.context``), so the
hypotheses in :mod:`diagnosis.hypotheses` never re-read the run directory.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from qomni.ident import filtering, kinematics, odometry
from qomni.ident.controller import INTEGRAL_DEADBAND_LSB
from qomni.ident.campaign import ARC_STEPS, IDENTIFICATION_STEPS, VALIDATION_STEP
from qomni.datasheet import DataSheet
from qomni.ident.result import IdentificationResult
from qomni.ident.regressor_rows import (EXCITED, MODE_COORDINATES, VELOCITY_THRESHOLD, StepSignals,
                                        generalized_signals, lifted_blocks, model_alpha, step_blocks)
from qomni.ident.single_axis import VELOCITY_THRESHOLD as LIFTED_VELOCITY_THRESHOLD
from qomni.ident.recording import Signals
from qomni.ident.symbolic import WHEELS

#: Steps with rolling channels (constant mode angles: a fixed basis of redundant constraints).
#: The campaign steps whose channels the diagnosis reads, where recorded.
DIAGNOSED_STEPS = (*IDENTIFICATION_STEPS, VALIDATION_STEP, *ARC_STEPS)
ROLLING_STEPS = ("rotation",)
#: Coordinates of the lane change (validation step) that become torque channels.
LANE_CHANGE_COORDINATES = ("x_ch",)
#: The lane change's steering coordinate: the one step whose steering turns while the wheels roll at
#: speed, so that a low-speed friction peak there is the steering joints' (``hypotheses.stribeck``).
LANE_CHANGE_STEERING = ("alpha_v",)
#: Coordinates of the arcs that become torque channels: their steering is held (below the stiction
#: threshold throughout), so only the path coordinate carries a torque.
ARC_COORDINATES = ("x_ch",)
#: Rows cut at both ends of every step: zero-phase filter edge effects (``filtering.padlen``).
EDGE_ROWS = 60
#: A drive at this fraction of its ``max_torque`` is at its traction limit; rows within
#: TRACTION_MARGIN s of it are not fitted (the filter's smear and the wheel's spin-down).
TRACTION_LIMIT = 0.9
TRACTION_MARGIN = 0.1


@dataclass
class StepContext:
    """Signals of one step shared by all its channels (arrays (N, …), SI).

    Attributes:
        st: filtered generalized signals (``ident.identify.StepSignals``).
        sheet: the data sheet (geometry, i_G).
        pose: (N, 3) odometry world pose x [m], y [m], γ [rad], integrated over the whole run.
        H: (N, 9, n_k) H_k(α) of the step's mode.
        alpha_dot_encoder: (N, 2) α̇ from the wheel encoders (mode 1 only, else the sensor's), rad/s
            at the Coulomb cutoff — far finer than the 14-bit steering sensor.
        keep: (N,) bool, rows away from the filter's edges.
        p: (11,) the diagnosed model's parameters, order (18).
        traction_limited: (N,) bool, rows at or near a drive's torque limit (not fitted).
        rolling: the step's redundant rolling constraints (``ROLLING_STEPS`` only, else None).
        lifted: the lifted vehicle's run (:func:`lifted_channel`): no ground contact, the chassis at rest.
    """

    st: StepSignals
    sheet: DataSheet
    p: np.ndarray
    pose: np.ndarray
    H: np.ndarray
    alpha_dot_encoder: np.ndarray
    keep: np.ndarray
    traction_limited: np.ndarray
    rolling: "RollingConstraints | None" = None
    lifted: bool = False

    @property
    def k(self) -> int:
        return self.st.k

    @property
    def step(self) -> str:
        return self.st.step


@dataclass(frozen=True)
class RollingConstraints:
    """The rolling constraints (1) of one step with constant mode angles, reduced to their redundant part.

    Attributes:
        A: (N, 8, 9) ``A(α)`` at the measured steering angles (rows 0–3 lateral, 4–7 longitudinal, wheel
            order fl, rl, fr, rr).
        A_ch_nominal: (8, 3) ``A_ch`` at the mode's nominal angles.
        basis: (8, 5) orthonormal basis of its left null space: combinations of the constraints that no
            chassis twist can satisfy or violate.
        cycle_time: s.
    """

    A: np.ndarray
    A_ch_nominal: np.ndarray
    basis: np.ndarray
    cycle_time: float

    def integrate(self, violation: np.ndarray) -> np.ndarray:
        """(N, 8) constraint violation rates, m/s (what ``A q̇`` would be) → (N, 5) their redundant part
        integrated over the step, m."""
        return np.cumsum(violation @ self.basis, axis=0) * self.cycle_time


def rolling_constraints(st: StepSignals, sheet: DataSheet) -> RollingConstraints:
    """The step's :class:`RollingConstraints` (mode 3 or 4)."""
    nominal = kinematics.constraint_matrix(kinematics.mode_alpha(st.k, sheet.geometry)[None, :],
                                           sheet.geometry)[0, :, :3]
    u, _, _ = np.linalg.svd(nominal)
    return RollingConstraints(kinematics.constraint_matrix(st.q[:, 3:5], sheet.geometry), nominal,
                              u[:, 3:], st.cycle_time)


@dataclass(eq=False)
class ChannelData:
    """One residual channel. Compared and hashed by identity: its columns are cached per channel object
    (:func:`.problem.cached_columns`, a hypothesis' own per-channel memo).

    Attributes:
        name: ``"<step>/<coordinate>"`` (torque), ``"<step>/kinematic_<wheel>"`` or
            ``"<step>/rolling_<j>"``.
        kind: ``"torque"``, ``"kinematic"`` or ``"rolling"``.
        unit: unit of ``y`` and of the residual (``N m``, ``N``, ``rad`` wheel side or ``m``).
        index: column j of H_k (torque), wheel index i (kinematic) or redundant direction j (rolling).
        y: (n,) measured quantity: τ̂ − Θ̂₂p₂ (torque), the rolling-constraint residual (kinematic) or
            the integrated redundant constraint (rolling).
        base: (n, 10) regressor Θ̂₁ (torque) or (n, 0) (kinematic, rolling).
        model: (n,) the given model's prediction Θ̂₁p̂₁ (torque) or 0 (kinematic, rolling).
        velocity: (n,) generalized velocity of the row (rad/s or m/s).
        acceleration: (n,) generalized acceleration.
        fitted: (n,) bool, rows used for fitting (moving and away from the edges).
        context: the step's :class:`StepContext`; rows are ``context.keep``-selected.
        nuisance: (n, m) columns with free coefficients per channel that belong to no effect
            (kinematic: the constant of integration and the chassis' creep seen by the held side's
            two wheels; rolling: the constant of integration; torque: none).
        paired: (n,) the residual a paired reference run (the same campaign on the model's twin,
            :mod:`.paired`) leaves at the same instants, subtracted from this channel's residual; None
            where the channel is not paired.
    """

    name: str
    kind: str
    unit: str
    index: int
    y: np.ndarray
    base: np.ndarray
    model: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    fitted: np.ndarray
    context: StepContext = field(repr=False)
    nuisance: np.ndarray = field(repr=False, default=None)
    paired: np.ndarray | None = field(repr=False, default=None)

    def __post_init__(self):
        if self.nuisance is None:
            self.nuisance = np.zeros((len(self.y), 0))

    @property
    def residual(self) -> np.ndarray:
        """(n,) y − model: what the given model leaves unexplained; of a paired channel, beyond what it
        leaves at the same instants of the paired reference run (y − model − paired)."""
        if self.paired is not None:
            return self.y - self.model - self.paired
        return self.y - self.model

    @property
    def time(self) -> np.ndarray:
        return self.context.st.time[self.context.keep]

    @property
    def step(self) -> str:
        return self.context.step

    def rows(self, full: np.ndarray) -> np.ndarray:
        """The channel's rows of a step-length (N, …) array."""
        return np.asarray(full)[self.context.keep]

    @property
    def held_out_only(self) -> bool:
        """Whether the diagnosis never fits the channel's rows and only holds them out (the lifted run's:
        it reaches the fits only as the measured wheel friction, :class:`.problem.MeasuredBase`)."""
        return self.context.lifted


def _alpha_dot_from_encoders(st: StepSignals, sheet: DataSheet) -> np.ndarray:
    """Mode 1: α̇ per side by least squares over the side's two wheels, β̇_i = (H₁)_{β_i} α̇."""
    if st.k != 1:
        return st.qd_coulomb[:, 3:5]
    H1 = kinematics.H(1, st.q[:, 3:5], sheet.geometry)[:, 5:9, :]  # (N, 4, 2)
    beta_d = st.qd_coulomb[:, 5:9]
    num = np.einsum("nik,ni->nk", H1, beta_d)
    den = np.einsum("nik,nik->nk", H1, H1)
    return num / den


def step_context(sig: Signals, sheet: DataSheet, p: np.ndarray, pose: np.ndarray) -> StepContext:
    """Filtered signals, H_k and pose of one step."""
    st = generalized_signals(sig, sheet)
    alpha = model_alpha(st, sheet.geometry)
    alpha_v = kinematics.alpha_v_from_alpha(alpha, sheet.geometry) if st.k == 2 else None
    H = kinematics.H(st.k, alpha, sheet.geometry, alpha_v=alpha_v)
    keep = np.zeros(len(st.time), dtype=bool)
    keep[EDGE_ROWS:len(keep) - EDGE_ROWS] = True
    rolling = rolling_constraints(st, sheet) if st.step in ROLLING_STEPS else None
    return StepContext(st, sheet, np.asarray(p, dtype=float), pose, H, _alpha_dot_from_encoders(st, sheet),
                       keep, traction_limited(sig.motor_torque, sheet), rolling)


def traction_limited(motor_torque: np.ndarray, sheet: DataSheet) -> np.ndarray:
    """(N,) bool: rows within ``TRACTION_MARGIN`` of any drive at ``TRACTION_LIMIT``·max_torque.

    Args:
        motor_torque: (N, 4) measured motor torques, N m motor side.
    """
    at_limit = np.any(np.abs(motor_torque) >= TRACTION_LIMIT * sheet.drive.max_torque, axis=1)
    if not at_limit.any():
        return at_limit
    rows = max(int(round(TRACTION_MARGIN / sheet.drive.cycle_time)), 1)
    return ndimage.binary_dilation(at_limit, np.ones(2 * rows + 1, dtype=bool))


def _segments(free: np.ndarray) -> np.ndarray:
    """(n, m) indicator columns of the m stretches of ``free`` rows between limited rows (at least
    one column)."""
    label, m = ndimage.label(free)
    out = np.zeros((len(free), max(m, 1)))
    out[free, label[free] - 1] = 1.0
    if not m:
        out[:, 0] = 1.0
    return out


def _torque_channels(ctx: StepContext, coordinates, model: IdentificationResult) -> list[ChannelData]:
    out = []
    p = model.p
    names = MODE_COORDINATES[ctx.k]
    for block in step_blocks(ctx.st, ctx.sheet, coordinates):
        coord = str(np.atleast_1d(block.channel)[0]).split("/")[1]
        j = names.index(coord)
        keep = ctx.keep
        theta = block.Theta[keep]
        y = block.tau[keep] - theta[:, 10] * p[10]
        velocity = block.velocity[keep]
        sdd = np.einsum("ni,ni->n", ctx.H[:, :, j], ctx.st.qdd)[keep] / np.maximum(
            np.einsum("ni,ni->n", ctx.H[:, :, j], ctx.H[:, :, j])[keep], 1e-12)
        threshold = VELOCITY_THRESHOLD.get(coord, VELOCITY_THRESHOLD["*"])
        unit = "N" if coord in ("x_ch", "y_ch") else "N m"
        out.append(ChannelData(f"{ctx.step}/{coord}", "torque", unit, j, y, theta[:, :10],
                               theta[:, :10] @ p[:10], velocity, sdd,
                               (np.abs(velocity) > threshold) & ~ctx.traction_limited[keep], ctx))
    return out


def _kinematic_channels(ctx: StepContext, side: int) -> list[ChannelData]:
    """Rolling-constraint residuals of the steered side's two wheels (mode 1)."""
    st, keep = ctx.st, ctx.keep
    alpha, beta = st.q[:, 3:5], st.q[:, 5:9]
    H1 = ctx.H[:, 5:9, :]
    out = []
    for i in range(4):
        if abs(H1[0, i, side]) < 1e-12:
            continue
        predicted = H1[:, i, side] * (alpha[:, side] - alpha[0, side])
        y = (beta[:, i] - beta[0, i] - predicted)[keep]
        velocity = st.qd[:, 3 + side][keep]
        held = [k for k in range(4) if abs(H1[0, k, side]) < 1e-12]
        creep = (beta[:, held] - beta[0, held])[keep]
        free = ~ctx.traction_limited[keep]
        out.append(ChannelData(f"{ctx.step}/kinematic_{WHEELS[i]}", "kinematic", "rad", i, y,
                               np.zeros((len(y), 0)), np.zeros(len(y)), velocity,
                               st.qdd[:, 3 + side][keep], free, ctx,
                               np.column_stack([_segments(free), creep])))
    return out


def _rolling_channels(ctx: StepContext) -> list[ChannelData]:
    """Integrated redundant rolling constraints of a step in ``ROLLING_STEPS``."""
    st, keep, rc = ctx.st, ctx.keep, ctx.rolling
    measured = np.einsum("nij,nj->ni", rc.A[:, :, 3:], st.qd[:, 3:])  # chassis twist left out
    y = rc.integrate(measured)[keep]
    # the mode's one generalized coordinate (y_ch or γ_ch): ṡ and, since the selection is linear, s̈
    velocity = kinematics.sdot_from_qdot(ctx.k, st.q[:, 3:5], st.qd, ctx.sheet.geometry)[keep, 0]
    acceleration = kinematics.sdot_from_qdot(ctx.k, st.q[:, 3:5], st.qdd, ctx.sheet.geometry)[keep, 0]
    free = ~ctx.traction_limited[keep]
    misaligned = _misalignment_sliding(ctx)[keep]
    return [ChannelData(f"{ctx.step}/rolling_{m + 1}", "rolling", "m", m, y[:, m], np.zeros((len(y), 0)),
                        np.zeros(len(y)), velocity, acceleration, free, ctx,
                        np.hstack([_segments(free), misaligned[:, m, :]]))
            for m in range(y.shape[1])]


#: rad: the steering-angle step of the finite difference in :func:`_misalignment_sliding`.
MISALIGNMENT_STEP = 1e-4
#: Steering sensor LSBs (2π/2¹⁴ rad each) by which a side's median angle must miss the mode's angle for
#: the step's rolling channels to get that side's misalignment column, and for the Stribeck placement's
#: static reading of the steering joints (:func:`qomni.diagnosis.hypotheses.stribeck.steering_held_off`):
#: the campaign controller's integral deadband (``ident.controller.INTEGRAL_DEADBAND_LSB``, 1.5: a held
#: steering may rest that far off by design) plus half an LSB, the rounding of the sensor's reading:
#: 2.0 LSB ≈ 0.77 mrad. On full campaigns at the default steering bandwidth every vehicle without
#: steering-joint stiction and every twin held both sides within 1.4 LSB (54 vehicles); steering-joint
#: Stribeck friction up to 66 LSB; a 20 ms actuator delay, at the bandwidth lowered for it, 17 LSB.
MISALIGNMENT_LSB = INTEGRAL_DEADBAND_LSB + 0.5


def steering_offset(ctx: StepContext) -> np.ndarray:
    """(2,) rad: the median measured steering angle (left, right) over the step's kept rows minus the
    mode's angle; meaningful in the steps whose mode holds the steering at fixed angles
    (``ROLLING_STEPS``)."""
    return np.median(ctx.st.q[ctx.keep, 3:5], axis=0) - kinematics.mode_alpha(ctx.st.k, ctx.sheet.geometry)


def held_off_sides(ctx: StepContext) -> list[int]:
    """The sides (0 left, 1 right) whose steering the step holds ``MISALIGNMENT_LSB`` sensor LSBs or more
    off the mode's angle (:func:`steering_offset`)."""
    offset = steering_offset(ctx)
    bar = MISALIGNMENT_LSB * ctx.sheet.drive.steering_lsb
    return [side for side in range(2) if abs(offset[side]) >= bar]


def _misalignment_sliding(ctx: StepContext) -> np.ndarray:
    """(N, 5, m) the redundant constraints' integrated violation, m, per radian by which the steering of
    a side turns the wheels off the chassis twist's rolling directions, for each side (left, right) whose
    measured angle misses the mode's by ``MISALIGNMENT_LSB`` or more: m = 0, 1 or 2.

    Wheels held a few mrad off the mode's angles (e.g. by steering stiction short of the target) share
    no instantaneous centre of rotation: as the chassis turns they slide sideways at their speed times
    the offset, whatever their tyres. That sliding is a nuisance of the step, not an effect of the
    vehicle, and how it splits among the wheels depends on their friction: its coefficients are free per
    channel. Where the sensor shows no offset it is left out, since a tyre's slip angle under a steady
    side force looks the same."""
    st, g, rc = ctx.st, ctx.sheet.geometry, ctx.rolling
    sides = held_off_sides(ctx)
    out = np.empty((len(st.time), rc.basis.shape[1], len(sides)))
    for column, side in enumerate(sides):
        turned = st.q[:, 3:5].copy()
        turned[:, side] += MISALIGNMENT_STEP
        dA = (kinematics.constraint_matrix(turned, g)[:, :, :3] - rc.A[:, :, :3]) / MISALIGNMENT_STEP
        out[:, :, column] = rc.integrate(np.einsum("nij,nj->ni", dA, st.qd[:, :3]))
    return out


#: The lifted run's channel is ``"lifted/beta"``: its step.
LIFTED_STEP = "lifted"


def lifted_channel(signals: Signals, sheet: DataSheet, model: IdentificationResult) -> ChannelData:
    """The lifted run's torque channel ``"lifted/beta"`` (N m, wheel side): every wheel's
    i_G u_i − B_w β̈_i − (d_vw β̇_i + d_cw tanh(β̇_i/ε)) under ``model``, the four wheels' rows stacked
    (``lifted_blocks``), each wheel's rows its own stretch of the channel (the filter's edges cut per
    wheel), so that the channel holds one row per wheel and instant and the held-out windows take the
    four wheels together. Its context is lifted (:attr:`StepContext.lifted`): H selects the row's wheel,
    the chassis is at rest, and hypotheses that need ground contact give it no columns
    (:attr:`qomni.diagnosis.hypotheses.base.Hypothesis.lifted`).

    The rows are held out, never fitted (:attr:`ChannelData.held_out_only`): a model identified on the
    vehicle on its wheels holds in d_vw, d_cw whatever resists the wheels' rolling, and the lifted wheels
    show what the joints alone resist; the fits know the lifted run only as its measured friction
    (:class:`.problem.MeasuredBase`).

    Args:
        signals: the lifted run's tracking rows (``qomni.ident.single_axis.tracking_rows``), torque lag
            applied.
        sheet: the data sheet; model: the diagnosed model (p (11,), B_w as used)."""
    st = generalized_signals(signals, sheet, lifted=True)
    blocks = lifted_blocks(st, sheet)
    n, wheels = len(st.time), len(blocks)
    stacked = StepSignals(LIFTED_STEP, 0, np.tile(st.time, wheels),
                          *(np.tile(a, (wheels, 1))
                            for a in (st.q, st.qd, st.qdd, st.motor_torque, st.qd_coulomb)),
                          st.cycle_time, st.omega_g)
    H = np.zeros((wheels * n, 9, 1))
    keep = np.zeros(wheels * n, dtype=bool)
    for i in range(wheels):
        H[i * n:(i + 1) * n, 5 + i, 0] = 1.0
        keep[i * n + EDGE_ROWS:(i + 1) * n - EDGE_ROWS] = True
    limited = np.tile(traction_limited(signals.motor_torque, sheet), wheels)
    p = np.asarray(model.p, dtype=float)
    ctx = StepContext(stacked, sheet, p, np.zeros((wheels * n, 3)), H, stacked.qd_coulomb[:, 3:5], keep,
                      limited, None, lifted=True)
    theta = np.vstack([b.Theta for b in blocks])[keep]
    y = np.concatenate([b.tau for b in blocks])[keep] - theta[:, 10] * p[10]
    velocity = np.concatenate([b.velocity for b in blocks])[keep]
    acceleration = np.concatenate([st.qdd[:, 5 + i] for i in range(wheels)])[keep]
    fitted = (np.abs(velocity) > LIFTED_VELOCITY_THRESHOLD) & ~limited[keep]
    return ChannelData(f"{LIFTED_STEP}/beta", "torque", "N m", 0, y, theta[:, :10], theta[:, :10] @ p[:10],
                       velocity, acceleration, fitted, ctx)


def run_pose(signals: Signals, sheet: DataSheet) -> np.ndarray:
    """(N, 3) odometry pose over the whole recording (paper (3)), from filtered α and β."""
    ts = sheet.drive.cycle_time
    alpha = filtering.zero_phase_lowpass(signals.alpha, ts)
    beta = signals.motor_position / sheet.drive.i_G
    pose, _ = odometry.odometry(signals.time, alpha, beta, sheet.geometry)
    return pose


def channels(signals: Signals, sheet: DataSheet, model: IdentificationResult,
             steps=None, lane_change=LANE_CHANGE_COORDINATES) -> list[ChannelData]:
    """Every residual channel of the recording under ``model``.

    Args:
        signals: the run's recorded signals.
        sheet: its data sheet.
        model: the model to diagnose (identified on this run or another).
        steps: step names to use (default: the four identification steps, the lane change and the arcs,
            each where recorded).
        lane_change: the lane change's coordinates that become torque channels.
    Returns:
        Torque channels of every step, kinematic channels of the steering steps and rolling channels
        of ``ROLLING_STEPS``.
    """
    pose = run_pose(signals, sheet)
    recorded = signals.steps()
    wanted = steps or [s for s in DIAGNOSED_STEPS if s in recorded]
    out: list[ChannelData] = []
    for step in wanted:
        mask = signals.step == step
        ctx = step_context(signals.select(mask), sheet, model.p, pose[mask])
        coordinates = EXCITED.get(step) or (ARC_COORDINATES if step in ARC_STEPS else lane_change)
        out += _torque_channels(ctx, coordinates, model)
        if ctx.k == 1:
            side = MODE_COORDINATES[1].index(coordinates[0])
            out += _kinematic_channels(ctx, side)
        if ctx.rolling is not None:
            out += _rolling_channels(ctx)
    return out
