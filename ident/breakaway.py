"""Breakaway test on the lifted vehicle: each wheel joint's static friction against its Coulomb friction.

With the chassis jacked up every wheel is a free axis. From rest, its drive's torque ramps slowly until the
wheel turns; the wheel-side torque at which it starts to turn is the joint's breakaway torque. Friction
with a low-speed peak (Stribeck friction) breaks away at its breakaway ratio times the Coulomb friction
d_cw that the lifted Fourier tracking measures at speed (rows with |β̇| ≥ 0.5 rad/s, where a peak of the
realistic range, Stribeck velocity ≤ 0.2 rad/s, has decayed to 0.2 % of itself); friction without one
breaks away at d_cw. The ratio − 1 is the wheel joints' breakaway excess, the magnitude of the gap
diagnosis' wheel-joint Stribeck hypothesis (docs/diagnosis.md), measured where neither the ground nor
the steering acts: the one measurement of the campaign in which only the wheel joints' friction resists.

Each wheel runs the ramps of :class:`BreakawayPlan` in turn, the four wheels at once (lifted, they do not
interact). The first ramp after a change of direction takes up the gear's play (a backlash lets the motor
turn through the gap at next to no torque) and is not counted (:func:`analyse_breakaway`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from qomni.conventions import WHEELS

from .recording import Signals

#: The single-axis recording's step name of the breakaway ramps.
STEP = "breakaway"
#: Wheel-side rotation (rad) beyond its ramp's start at which a wheel counts as turning in the analysis:
#: above the encoder's resolution (65536 increments per motor turn: 4·10⁻⁶ rad at the wheel) and the creep
#: of a stuck joint under a rising torque, far below the ramp's end (``BreakawayPlan.moved``).
ONSET = 5e-4
#: Rows at a ramp's start left out of its torque line: the torque actual of the first SYNCs may still
#: report the rest before it (a drive reporting one cycle late).
SETTLE = 2
#: Rows (20 ms) over which a wheel that turns less than ONSET stands still.
STILL = 10


@dataclass(frozen=True)
class BreakawayPlan:
    """The breakaway ramps of every wheel, wheel side of the gear.

    ``directions``: the sign of each ramp in order; ``start``, ``cap``: the ramp's first torque and the
    torque at which it ends without motion, as fractions of the data sheet's d_cw; ``rate``: N m/s;
    ``moved``: rad the wheel turns before the ramp ends (beyond the realistic backlash, 0.002–0.02 rad);
    ``rest``: s at zero torque before each ramp, the wheel at rest."""

    directions: tuple[int, ...] = (1, 1, 1, -1, -1, -1)
    start: float = 0.5
    rate: float = 5.0
    cap: float = 4.0
    moved: float = 0.05
    rest: float = 0.3

    def __post_init__(self) -> None:
        if not self.directions or any(d not in (-1, 1) for d in self.directions):
            raise ValueError(f"directions must be a non-empty sequence of ±1, got {self.directions!r}")
        for name in ("start", "rate", "cap", "moved", "rest"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if not self.cap > self.start:
            raise ValueError(f"cap ({self.cap}) must exceed start ({self.start})")

    def longest(self, d_cw: float) -> float:
        """Upper bound (s) of the test's duration when no wheel turns before its cap."""
        return len(self.directions) * (self.rest + 0.5 + (self.cap - self.start) * d_cw / self.rate)


@dataclass
class _WheelRamps:
    """One wheel's progress through the plan (:class:`BreakawayController`)."""

    index: int = 0            # the ramp under way or next
    ramping: bool = False
    since: float = 0.0        # s since the phase began
    beta0: float = 0.0        # rad, wheel position at the ramp's start


@dataclass
class BreakawayController:
    """The ramps of :class:`BreakawayPlan` as a cyclic torque law: :meth:`torque` gives the wheel-side
    torques (4,) [N m] for the wheel positions β (4,) [rad] and speeds β̇ (4,) [rad/s] of a cycle.

    ``d_cw``: the data sheet's Coulomb friction (N m, wheel side); ``cycle_time``: s."""

    plan: BreakawayPlan
    d_cw: float
    cycle_time: float
    wheels: list[_WheelRamps] = field(default_factory=lambda: [_WheelRamps() for _ in WHEELS])

    @property
    def done(self) -> bool:
        return all(w.index >= len(self.plan.directions) for w in self.wheels)

    def torque(self, beta: np.ndarray, beta_dot: np.ndarray) -> np.ndarray:
        p, out = self.plan, np.zeros(len(self.wheels))
        for j, w in enumerate(self.wheels):
            if w.index >= len(p.directions):
                continue
            w.since += self.cycle_time
            if not w.ramping:
                # at rest long enough and no longer turning: the next ramp starts from here
                if w.since >= p.rest and abs(beta_dot[j]) < 0.01:
                    w.ramping, w.since, w.beta0 = True, 0.0, float(beta[j])
                continue
            level = p.start * self.d_cw + p.rate * w.since
            if abs(beta[j] - w.beta0) > p.moved or level > p.cap * self.d_cw:
                w.ramping, w.since = False, 0.0
                w.index += 1
                continue
            out[j] = p.directions[w.index] * level
        return out


@dataclass
class BreakawayResult:
    """Per wheel, the counted ramps' breakaway torques (N m, wheel side, signed by direction) and ratios to
    the wheel's lifted d_cw; ``censored``: counted ramps without a reading (the cap reached without
    turning, or the wheel turning from the ramp's first rows).

    ``excess``/``excess_std``: the mean of breakaway/d_cw − 1 over every counted ramp of every wheel, and
    its standard error (the ramps' scatter / √n); ``ramps``: how many were counted."""

    torques: dict[str, list[float]]
    ratios: dict[str, list[float]]
    censored: dict[str, int]
    excess: float
    excess_std: float
    ramps: int

    def to_json_dict(self) -> dict:
        return {"wheels": {w: {"breakaway_torque": self.torques[w], "ratio_to_d_cw": self.ratios[w],
                               "censored": self.censored[w], "unit": "N m"} for w in self.torques},
                # fewer than two readings give no standard error: no measurement
                "excess": ({"value": self.excess, "std": self.excess_std, "unit": "-"} if self.ramps >= 2
                           else None),
                "ramps": self.ramps,
                "definition": "breakaway torque / lifted d_cw - 1, mean over the counted ramps "
                              "(the first ramp after each change of direction takes up the gear play)"}


def breakaway_torque(time: np.ndarray, beta: np.ndarray, torque: np.ndarray, B_w: float) -> float | None:
    """The wheel-side torque (N m) at which a ramp's wheel starts to turn; None where it never does.

    ``time`` (n,) s, ``beta`` (n,) rad and ``torque`` (n,) N m: one ramp's rows, torque the applied
    torque of each SYNC's cycle (docs/conventions.md); ``B_w``: the wheel's inertia (kg m²). The torque
    is read from a straight line fitted to the ramp's torque up to the first row more than :data:`ONSET`
    from where the wheel last stood still (:data:`STILL` rows within ONSET), which averages the torque
    actual's noise over the ramp instead of taking one sample of it. The wheel needs time to turn that
    far: once free, under Coulomb friction, the ramp's excess rate·s accelerates it by rate·s/B_w, so it
    turns rate·s³/(6 B_w) in s seconds and reaches ONSET s = (6 B_w ONSET/rate)^(1/3) after it broke away. The line is read that much earlier.
    A wheel whose friction falls once it slides (a Stribeck peak) turns faster than that, so its
    breakaway is read up to (6 B_w ONSET)^(1/3) rate^(2/3) low (0.21 N m, 5 % of d_cw, at the default plan
    on the prototype): the excess is never read high."""
    moved = np.nonzero(np.abs(beta - beta[0]) > ONSET)[0]
    if not len(moved):
        return None
    # the wheel at rest under the ramp: the last row it stood still for STILL rows before; a gear play
    # lets the motor, and its encoder, turn through the gap before the wheel takes the torque
    still = np.nonzero(np.abs(beta[STILL:] - beta[:-STILL]) < ONSET)[0]
    if not len(still):
        return None
    rest = int(still[-1])
    after = np.nonzero(np.abs(beta[rest:] - beta[rest]) > ONSET)[0]
    if not len(after) or rest + after[0] < SETTLE + 3:
        return None
    k = rest + int(after[0])
    slope, intercept = np.polyfit(time[SETTLE:k], torque[SETTLE:k], 1)
    delay = (6.0 * B_w * ONSET / abs(slope)) ** (1.0 / 3.0) if slope != 0 else 0.0
    return float(slope * (time[k] - delay) + intercept)


def analyse_breakaway(signals: Signals, i_G: float, d_cw: dict[str, float],
                      B_w: dict[str, float]) -> BreakawayResult | None:
    """The breakaway test's result from a single-axis recording; None where it has no breakaway rows.

    ``signals``: the recording (the rows of :data:`STEP` are used), torque actual already shifted to the
    applied torque's timing (:func:`qomni.ident.torque_timing.shift_torque`); ``i_G``: gear ratio;
    ``d_cw``, ``B_w``: each wheel's Coulomb friction (N m, wheel side) and inertia (kg m²) from the lifted
    Fourier fit.

    Raises: ValueError: a wheel without a counted ramp that turned or reached its cap, or a d_cw ≤ 0."""
    rows = signals.step == STEP
    if not rows.any():
        return None
    sig = signals.select(rows)
    torques, ratios, censored = {}, {}, {}
    for j, wheel in enumerate(WHEELS):
        if not d_cw[wheel] > 0:
            raise ValueError(f"wheel {wheel}: lifted d_cw must be > 0, got {d_cw[wheel]}")
        cmd = sig.motor_torque_cmd[:, j]
        torques[wheel], ratios[wheel], censored[wheel] = [], [], 0
        previous = 0.0
        for (ramp,) in ndimage.find_objects(ndimage.label(cmd != 0)[0]):
            a, b = ramp.start, ramp.stop
            direction = float(np.sign(cmd[a]))
            counted = direction == previous
            previous = direction
            if not counted:
                continue
            tau = breakaway_torque(sig.time[a:b], sig.motor_position[a:b, j] / i_G,
                                   i_G * sig.motor_torque[a:b, j], B_w[wheel])
            if tau is None:
                censored[wheel] += 1
                continue
            torques[wheel].append(tau)
            ratios[wheel].append(abs(tau) / d_cw[wheel])
        if not torques[wheel] and not censored[wheel]:
            raise ValueError(f"wheel {wheel}: no counted breakaway ramp in the recording")
    excess = [r - 1.0 for w in WHEELS for r in ratios[w]]
    n = len(excess)
    mean = float(np.mean(excess)) if n else math.nan
    std = float(np.std(excess, ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    return BreakawayResult(torques, ratios, censored, mean, std, n)
