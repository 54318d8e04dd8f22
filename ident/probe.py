"""The dead-time probe: short steering pulses at rest that measure how long the wheels' torque takes
to act, so the campaign's steering loop is tuned to the vehicle's actuators before the campaign moves.

An actuator delay (current loop, PWM, the drive's set-point pipeline) takes phase out of every loop at
ω·τ: a 20 ms delay turns the default 45 rad/s steering loop into a limit cycle at the torque limit. The
delay cannot be read from the bus (torque actual, 0x6077, reports the set-point at once); it shows only
in the motion. So the probe, at rest in mode 1 (chassis still), for each of two pulse amplitudes a and
2a (``AMPLITUDES``):

1. commands both steering angles open loop with the nominal feed-forward (21) of a bang-bang
   acceleration ±amplitude for ``pulse`` s each (Coulomb friction compensated as if sliding);
2. fits Δα(t) = c·½·max(t − τ, 0)² to the mean steering angle over the accelerating half, τ on whole
   cycles (the loop's resolution), c by least squares;
3. brings the steering back to where it started with gains designed for ``max_dead_time``.

Those gains do not pull the steering out of its static friction: each return ends up to 0.08 rad short.
After both pulses the probe therefore settles the steering at α = 0, where the campaign starts, in
``SETTLE`` s (a quintic from where it stands) with the steering bandwidth just chosen (or the one the
caller names): the campaign's first step then starts at rest where it was planned to, as without a probe.

Low-speed friction rounds the onset like a dead time, and more so the weaker the pulse: its breakaway
peak holds the joint until the torque's surplus has overcome it; a dead time reads the same at both.
Friction only adds to the onset, so the stronger pulse's reading is taken: it holds the least friction,
and a pure delay reads the same. (Extrapolating the two readings to an infinitely
strong pulse, τ = 2τ(2a) − τ(a), read 2 ms for an 18 ms delay under Stribeck friction in both joints,
38 and 20 ms at the two pulses, and that campaign ran at the torque limit.) The campaign gets the
steering bandwidth that keeps ``min_phase_margin`` with τ
(:func:`qomni.ident.control_design.delay_robust_bandwidth`); docs/effects.md has the readings.

A steering that does not respond to either pulse (friction above the pulse's torque, no vehicle motion)
gives no τ; the campaign then keeps the gains designed for ``max_dead_time``: slower tracking, never a
limit cycle.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from . import dynamics
from .control_design import delay_robust_bandwidth
from .controller import ControllerSettings, StepController, quintic_alignment, step_cycles
from qomni.datasheet import DataSheet

#: Response the fit needs at the end of the accelerating half, in steering-sensor LSB: below it the
#: steering has not moved (stiction, no vehicle) and no dead time is read.
MIN_RESPONSE_LSB = 20
#: Samples the fit keeps after the latest dead time it tries (the curvature needs a few).
MIN_FIT_CYCLES = 10
#: Pulse amplitudes as multiples of the probe's ``acceleration``: the weaker first (gentle: a ±40 rad/s²
#: pulse left the ideal vehicle looking inclined to the diagnosis), then twice that.
AMPLITUDES = (1.0, 2.0)
#: s, the final settle from where the returns left the steering to α = 0.
SETTLE = 1.0


@dataclass(frozen=True)
class ProbeResult:
    """What the probe measured and chose.

    Attributes:
        dead_time: s, τ read by the strongest pulse that moved the steering (None: no response to fit).
        acceleration: rad/s², the fitted c of the weaker pulse (the acceleration it really gave).
        response: rad, mean |Δα| at the end of the weaker pulse's accelerating half.
        fit_rms: rad, RMS of the weaker pulse's fit residual.
        steering_bandwidth: rad/s, the campaign's steering bandwidth from here on.
        pulses: per pulse, ``{"amplitude": rad/s², "dead_time": s or None, "acceleration": c, "response",
            "fit_rms"}``.
    """

    dead_time: float | None
    acceleration: float
    response: float
    fit_rms: float
    steering_bandwidth: float
    pulses: tuple = ()


def fit_dead_time(delta_alpha: np.ndarray, cycle_time: float, max_cycles: int) -> tuple[int, float, float]:
    """Fit Δα_k = c·½·max(k·T_s − n·T_s, 0)² (k = 1 … N) over n = 0 … ``max_cycles``.

    Args:
        delta_alpha: (N,) rad, the angle moved since the pulse began, one sample per cycle.
    Returns:
        (n, c [rad/s²], residual RMS [rad]) of the best n.
    """
    t = cycle_time * np.arange(1, len(delta_alpha) + 1)
    best = None
    for n in range(max_cycles + 1):
        basis = 0.5 * np.maximum(t - n * cycle_time, 0.0) ** 2
        c = float(basis @ delta_alpha / (basis @ basis))
        rms = float(np.sqrt(np.mean((delta_alpha - c * basis) ** 2)))
        if best is None or rms < best[2]:
            best = (n, c, rms)
    return best


class DeadTimeProbe:
    """The probe's movements, planned before any vehicle is connected (nothing slow between SYNCs).

    Args:
        sheet: the data sheet (nominal parameters for the feed-forward, geometry, drive).
        settings: the campaign controller's settings (bandwidth, phase margin, ``max_dead_time``).
        acceleration: rad/s² of the weaker pulse (``AMPLITUDES`` scale it); pulse: s of each half;
        settle: s to return and rest after each pulse.
    """

    def __init__(self, sheet: DataSheet, settings: ControllerSettings | None = None, acceleration: float = 10.0,
                 pulse: float = 0.1, settle: float = 0.8):
        self.sheet, self.settings = sheet, settings or ControllerSettings()
        d, s = sheet.drive, self.settings
        self.cycles = int(round(pulse / d.cycle_time))
        self.safe_bandwidth = self._bandwidth(s.max_dead_time)
        self.amplitudes = tuple(acceleration * k for k in AMPLITUDES)
        self._u, self._return = [], []
        q = np.zeros((2, 9))
        sd = np.ones((2, 2))                                 # sliding forwards: Coulomb compensated
        for a in self.amplitudes:
            sdd = np.array([[a] * 2, [-a] * 2])
            self._u.append(dynamics.feedforward(1, q, sd, sdd, sheet.nominal.p, sheet.geometry, d.i_G))  # (2, 4)
            moved = np.full(2, a * pulse**2)                  # where a bang-bang of ±a for T each ends
            back = quintic_alignment(moved, np.zeros(2), settle, name="probe")
            self._return.append(StepController(back, sheet, replace(s, steering_bandwidth=self.safe_bandwidth)))
        self._settle_cycles = step_cycles(SETTLE, d.cycle_time)

    @property
    def total_cycles(self) -> int:
        return sum(2 * self.cycles + back.cycles for back in self._return) + self._settle_cycles

    def _bandwidth(self, dead_time: float) -> float:
        s, d = self.settings, self.sheet.drive
        return delay_robust_bandwidth(s.steering_bandwidth, s.damping, d.cycle_time, s.steering_integral_ratio,
                                      s.derivative_cutoff, dead_time, s.min_phase_margin)

    def run(self, vehicle, measurement, on_cycle: Callable | None = None, settle_bandwidth: float | None = None):
        """Run the probe on ``vehicle`` (a ``VehicleInterface``) from ``measurement`` (the last one).

        Args:
            on_cycle: called with (measurement, command) after every exchange (the recording).
            settle_bandwidth: rad/s of the final settle at α = 0; default the bandwidth the probe chose (a
                run repeating another's campaign passes the one that run used).
        Returns:
            (:class:`ProbeResult`, the last measurement).
        """
        moved_by_pulse = []
        for u_pulse, back in zip(self._u, self._return):
            start = np.asarray(measurement.alpha, dtype=float)
            moved = []
            for j in range(2 * self.cycles):
                u = u_pulse[0] if j < self.cycles else u_pulse[1]
                measurement = vehicle.exchange(u)
                if j < self.cycles:
                    moved.append(np.mean(np.asarray(measurement.alpha) - start))
                if on_cycle:
                    on_cycle(measurement, u)
            measurement = back.follow(vehicle, measurement, on_cycle)
            moved_by_pulse.append(np.array(moved))
        result = self.evaluate(moved_by_pulse)
        # built after the pulses (its start is where they left the steering), while it stands still
        to_start = quintic_alignment(np.asarray(measurement.alpha, dtype=float), np.zeros(2), SETTLE, name="probe")
        bandwidth = settle_bandwidth or result.steering_bandwidth
        settle = StepController(to_start, self.sheet, replace(self.settings, steering_bandwidth=bandwidth))
        return result, settle.follow(vehicle, measurement, on_cycle)

    def _reading(self, moved: np.ndarray, amplitude: float) -> dict:
        """One pulse's fit: its dead time (None: no response to fit), c, response and residual."""
        d = self.sheet.drive
        response = float(abs(moved[-1])) if len(moved) else 0.0
        n, c, rms = fit_dead_time(moved, d.cycle_time, max(self.cycles - MIN_FIT_CYCLES, 0))
        responded = response >= MIN_RESPONSE_LSB * d.steering_lsb and c > 0
        return {"amplitude": amplitude, "dead_time": n * d.cycle_time if responded else None,
                "acceleration": c, "response": response, "fit_rms": rms}

    def evaluate(self, moved_by_pulse) -> ProbeResult:
        """The probe's result from the mean steering angle moved over each pulse's accelerating half:
        a sequence of (N,) rad, one per amplitude (the weaker first)."""
        readings = [self._reading(np.asarray(m, dtype=float), a) for m, a in zip(moved_by_pulse, self.amplitudes)]
        weak = readings[0]
        # the strongest pulse that moved the steering: the least friction in its onset
        dead_time = next((r["dead_time"] for r in reversed(readings) if r["dead_time"] is not None), None)
        bandwidth = self.safe_bandwidth if dead_time is None else self._bandwidth(dead_time)
        return ProbeResult(dead_time, weak["acceleration"], weak["response"], weak["fit_rms"], bandwidth,
                           tuple(readings))
