"""Feedback design for the campaign controller, with python-control.

Each generalized coordinate the campaign closes a loop on (steering angles, x_ch, γ_ch, wheel angles on
the lifted vehicle) is treated, after feed-forward (21) with nominal parameters, as a double integrator
with its nominal generalized inertia. The PD gains place the poles of the zero-order-hold discretisation
at T_s; velocities that are not measured are estimated by a discretised filtered differentiator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import control
import numpy as np


@dataclass(frozen=True)
class PDGains:
    """u = inertia · (kp · e + kd · ė + ki · ∫e dt), e = reference − measurement.
    kp in 1/s², kd in 1/s, ki in 1/s³ (0 for a plain PD)."""

    kp: float
    kd: float
    ki: float = 0.0


def design_pd(bandwidth: float, damping: float, cycle_time: float) -> PDGains:
    """PD gains for a unit double integrator by pole placement of its ZOH discretisation.

    Args:
        bandwidth: natural frequency ω_n of the closed loop, rad/s.
        damping: damping ratio ζ (> 0).
        cycle_time: T_s, s.

    Raises:
        ValueError: ω_n·T_s too large for a sampled loop (> 0.5) or a non-positive argument.
    """
    if bandwidth <= 0 or damping <= 0 or cycle_time <= 0:
        raise ValueError("bandwidth, damping and cycle_time must be > 0")
    if bandwidth * cycle_time > 0.5:
        raise ValueError(f"bandwidth {bandwidth} rad/s is too high for T_s = {cycle_time} s")
    plant = control.c2d(control.ss([[0, 1], [0, 0]], [[0], [1]], np.eye(2), 0), cycle_time, "zoh")
    wd = bandwidth * math.sqrt(max(1 - damping**2, 0.0))
    s_poles = [complex(-damping * bandwidth, wd), complex(-damping * bandwidth, -wd)]
    if wd == 0:
        s_poles = [-bandwidth, -1.1 * bandwidth]
    z_poles = np.exp(np.array(s_poles) * cycle_time)
    k = np.asarray(control.place(plant.A, plant.B, z_poles)).ravel()
    return PDGains(kp=float(k[0]), kd=float(k[1]))


def design_pid(bandwidth: float, damping: float, cycle_time: float,
               integral_ratio: float = 0.25) -> PDGains:
    """PID gains for a unit double integrator: the PD poles of :func:`design_pd` plus a real pole at
    ``integral_ratio · bandwidth`` for the integral state, placed on the ZOH discretisation.

    The integral removes the Coulomb-friction deadband a PD leaves when holding a steering angle.

    Raises:
        ValueError: as :func:`design_pd`, or integral_ratio not in (0, 1].
    """
    if not 0 < integral_ratio <= 1:
        raise ValueError(f"integral_ratio must be in (0, 1], got {integral_ratio}")
    pd = design_pd(bandwidth, damping, cycle_time)  # validates the arguments
    # states (∫e, e, ė) of the error dynamics ë = −u: integrator, double integrator
    a = [[0, 1, 0], [0, 0, 1], [0, 0, 0]]
    plant = control.c2d(control.ss(a, [[0], [0], [1]], np.eye(3), 0), cycle_time, "zoh")
    wd = bandwidth * math.sqrt(max(1 - damping**2, 0.0))
    s_poles = [complex(-damping * bandwidth, wd), complex(-damping * bandwidth, -wd),
               -integral_ratio * bandwidth]
    if wd == 0:
        s_poles[:2] = [-bandwidth, -1.1 * bandwidth]
    k = np.asarray(control.place(plant.A, plant.B, np.exp(np.array(s_poles) * cycle_time))).ravel()
    del pd
    return PDGains(kp=float(k[1]), kd=float(k[2]), ki=float(k[0]))


class LowPassFilter:
    """Online first-order low-pass 1/(τs + 1), Tustin-discretised at T_s, for m channels (unit DC gain).

    Args:
        cutoff: 1/τ in rad/s. cycle_time: T_s in s. channels: number of independent signals m.
    """

    def __init__(self, cutoff: float, cycle_time: float, channels: int):
        sys = control.c2d(control.tf([1], [1 / cutoff, 1]), cycle_time, "tustin")
        num, den = (np.asarray(v, dtype=float).ravel() for v in control.tfdata(sys))
        self._b, self._a = num / den[0], den / den[0]
        self._x = None
        self._y = None

    def update(self, x) -> np.ndarray:
        """Feed the next sample x (m,); returns the filtered value (m,), starting at the first sample."""
        x = np.atleast_1d(np.asarray(x, dtype=float))
        if self._x is None:
            self._x, self._y = x.copy(), x.copy()
        y = self._b[0] * x + self._b[1] * self._x - self._a[1] * self._y
        self._x, self._y = x.copy(), y
        return y.copy()


class DifferentiatorFilter:
    """Online filtered derivative s/(τs + 1), Tustin-discretised at T_s, for m channels.

    Args:
        cutoff: 1/τ in rad/s.
        cycle_time: T_s in s.
        channels: number of independent signals m.
    """

    def __init__(self, cutoff: float, cycle_time: float, channels: int):
        sys = control.c2d(control.tf([1, 0], [1 / cutoff, 1]), cycle_time, "tustin")
        num, den = (np.asarray(v, dtype=float).ravel() for v in control.tfdata(sys))
        self._b = num / den[0]
        self._a = den / den[0]
        self._x = None
        self._y = np.zeros(channels)

    def update(self, x: np.ndarray) -> np.ndarray:
        """Feed the next sample x (m,); returns the derivative estimate (m,) in units of x per s."""
        x = np.asarray(x, dtype=float)
        if self._x is None:
            self._x = x.copy()
        y = self._b[0] * x + self._b[1] * self._x - self._a[1] * self._y
        self._x = x.copy()
        self._y = y
        return y.copy()


def steering_loop(gains: PDGains, cycle_time: float, derivative_cutoff: float, dead_time: float):
    """The open steering loop L(z) = C(z)·P(z)·z^(−n) of a unit double integrator under PID ``gains``.

    C(z) = kp + kd·D(z) + ki·T_s/(z − 1), D the Tustin filtered differentiator the controller estimates
    α̇ with; P the ZOH double integrator; n = ⌈dead_time / T_s⌉ cycles of dead time (an actuator delay,
    rounded up to whole cycles: the conservative side). A discrete python-control ``TransferFunction``.
    """
    ts = cycle_time
    plant = control.c2d(control.tf([1], [1, 0, 0]), ts, "zoh")
    diff = control.c2d(control.tf([1, 0], [1 / derivative_cutoff, 1]), ts, "tustin")
    integ = control.tf([ts, 0], [1, -1], ts)
    n = math.ceil(dead_time / ts - 1e-9)
    delay = control.tf([1], [1] + [0] * n, ts)
    return (gains.kp + gains.kd * diff + gains.ki * integ) * plant * delay


def phase_margin(loop, cycle_time: float) -> float:
    """Phase margin of a discrete open loop at its first 0 dB crossing, degrees.

    The frequency response is evaluated on a log grid up to Nyquist (python-control's
    ``frequency_response``) and the crossing interpolated; −inf when |L| never falls through 1 (no
    crossover: not a stabilising loop for a double integrator). The phase is followed continuously from
    the grid's low end, where the loop (an integrator times a double integrator) lies at −270°, so a dead
    time's lag is counted in full: a loop whose phase at crossover is −540° has a margin of −360°, not
    the 0° the angle modulo 360° would give.
    """
    omega = np.logspace(-1, math.log10(math.pi / cycle_time) - 1e-6, 4000)
    response = np.asarray(control.frequency_response(loop, omega).frdata).ravel()
    gain = np.abs(response)
    below = np.nonzero((gain[:-1] >= 1) & (gain[1:] < 1))[0]
    if not len(below):
        return -math.inf
    i = below[0]
    w = (math.log(gain[i]) / (math.log(gain[i]) - math.log(gain[i + 1])))
    phase = np.degrees(np.unwrap(np.angle(response[:i + 2])))
    phase -= 360.0 * math.floor((phase[0] + 360.0) / 360.0)       # the low end into [−360°, 0°): −270°
    return float((1 - w) * phase[i] + w * phase[i + 1] + 180.0)


def delay_robust_bandwidth(bandwidth: float, damping: float, cycle_time: float, integral_ratio: float,
                           derivative_cutoff: float, dead_time: float, min_phase_margin: float,
                           floor: float = 4.0) -> float:
    """The largest steering bandwidth ≤ ``bandwidth`` whose PID design (:func:`design_pid`) keeps the
    phase margin ≥ ``min_phase_margin`` (degrees) with ``dead_time`` s in the loop (:func:`steering_loop`).

    A dead time lowers the phase at crossover by ω_c·τ; a loop tuned for a stiff actuator then runs into a
    limit cycle at the torque limit. Bisection on the bandwidth (the margin falls as it rises), 0.1 rad/s.

    Returns:
        ``bandwidth`` itself when it meets the margin, else the bisected value (rad/s, ≥ ``floor``:
        below it the loop could no longer hold the steering against its friction, and ``floor`` is
        returned whatever its margin).
    """
    def margin(bw: float) -> float:
        gains = design_pid(bw, damping, cycle_time, integral_ratio)
        return phase_margin(steering_loop(gains, cycle_time, derivative_cutoff, dead_time), cycle_time)

    if margin(bandwidth) >= min_phase_margin:
        return bandwidth
    low, high = floor, bandwidth
    if margin(low) < min_phase_margin:
        return floor
    while high - low > 0.1:
        mid = 0.5 * (low + high)
        low, high = (mid, high) if margin(mid) >= min_phase_margin else (low, mid)
    return low
