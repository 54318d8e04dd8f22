"""The campaign's motion controller: executes a step's trajectory through the four wheel torques only.

Per cycle it
1. estimates the state from what the bus gives: α from the steering sensors, α̇ by a filtered
   differentiator, β̇ from the drives' velocity, chassis velocities by odometry (3), and the step's
   chassis coordinate (x_ch or γ_ch) by integrating them — no ground-truth pose;
2. takes the feed-forward motor torques of the paper's law (21) with nominal parameters, which depend on
   the step time only and are evaluated for every cycle of the step when the controller is built;
3. adds PD feedback on the steering angles (holding or tracking them through differential wheel torques,
   H_1ᵀB) and on the step's chassis coordinate (H_kᵀB of its column), allocated to the four motors by
   the pseudoinverse of the stacked input rows (fixed in modes 1, 3, 4; in mode 2 a function of the
   measured steering counts, cached);
4. clips to the drives' torque limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from typing import Callable

import numpy as np

from . import dynamics, kinematics, odometry
from .control_design import DifferentiatorFilter, LowPassFilter, design_pd, design_pid
from qomni.datasheet import DataSheet
from .excitation import ExcitationStep
from .json_values import json_number

CHASSIS_COORDINATE = {2: "x_ch", 3: "y_ch", 4: "gamma_ch"}


#: Steering errors within this many sensor LSBs are not integrated (no wind-up on the quantization), so a
#: held steering may rest up to this far off its reference.
INTEGRAL_DEADBAND_LSB = 1.5


@dataclass(frozen=True)
class ControllerSettings:
    """Loop bandwidths (rad/s) and damping; the velocity-estimate filter cutoff (rad/s)."""

    steering_bandwidth: float = 45.0
    steering_integral_ratio: float = 0.25  # integral pole / bandwidth; removes the Coulomb deadband
    chassis_bandwidth: float = 6.0
    damping: float = 0.9
    derivative_cutoff: float = 150.0
    # Low-pass on the chassis rate (from the drives' velocities) the chassis loop damps with: a gear
    # backlash lets the motor rotors rattle in the gap at ≈ 100 Hz, and the loop's gain on the whole
    # vehicle's inertia turns that rattle into a torque limit cycle; 10 × the chassis bandwidth costs
    # 6° of its 69° phase margin.
    chassis_rate_cutoff: float = 60.0
    torque_margin: float = 0.95  # fraction of max_torque the controller may command
    # The steering loop keeps this phase margin (deg) with the dead time the probe measures
    # (DeadTimeProbe); the default bandwidth has 36° without dead time, so an undelayed vehicle keeps it.
    min_phase_margin: float = 30.0
    # Measure the actuator dead time first and lower the steering bandwidth to it (DeadTimeProbe). Off by
    # default: a suite draw recorded with it named more false effects, among them one on a clean vehicle
    # (docs/effects.md); without it an actuator delay above about 6 ms drives the steering into a limit
    # cycle at the torque limit, which ``probe_on_limit_cycle`` catches.
    probe: bool = False
    max_dead_time: float = 0.03  # s, the dead time the gains are designed for when the probe sees none
    # Whether the probe's reading sets the steering bandwidth. A run that must repeat another's campaign
    # exactly (the digital twin's reference run) probes too but keeps the bandwidth the other run recorded.
    probe_retunes: bool = True
    # Where the steering loop falls into a limit cycle at the torque limit in the campaign's first steps
    # (an actuator delay the default gains cannot take), stop, probe the dead time and start the campaign
    # again at the bandwidth it gives (ident.campaign.Campaign). A vehicle that never reaches the limit
    # records exactly what it records without this.
    probe_on_limit_cycle: bool = True

    def __post_init__(self) -> None:
        """Refuse settings no campaign controller can run with (a run's metadata.json edited, or from
        another tool).

        Raises: ValueError naming the key: a switch that is not true or false; another setting that is not
        a finite number, or not > 0 (the dead time the gains are designed for may be 0); a torque margin
        above 1 or a phase margin of 90° or more."""
        for f in fields(self):
            where, value = f"controller.{f.name}", getattr(self, f.name)
            if f.type in ("bool", bool):
                if not isinstance(value, bool):
                    raise ValueError(f"{where} must be true or false, got {value!r}")
                continue
            value = json_number(value, where)
            object.__setattr__(self, f.name, value)
            if value < 0 or (value == 0 and f.name != "max_dead_time"):
                raise ValueError(f"{where} must be {'>= 0' if f.name == 'max_dead_time' else '> 0'}, "
                                 f"got {value!r}")
        if self.torque_margin > 1:
            raise ValueError(f"controller.torque_margin must be <= 1 (a fraction of max_torque), "
                             f"got {self.torque_margin!r}")
        if self.min_phase_margin >= 90:
            raise ValueError(f"controller.min_phase_margin must be < 90 deg, got {self.min_phase_margin!r}")


@dataclass
class ControllerState:
    """The controller's estimate after the last measurement (SI, see docs/conventions.md)."""

    alpha: np.ndarray
    alpha_dot: np.ndarray
    beta_dot: np.ndarray
    velocity: np.ndarray  # chassis-frame ẋ, ẏ, γ̇
    s_chassis: float  # the step's chassis coordinate by odometry


def step_cycles(duration: float, cycle_time: float) -> int:
    """Cycles a step of ``duration`` s takes at t = j·T_s, j = 0 … cycles − 1 (its end included)."""
    return int(math.floor(duration / cycle_time + 1e-9)) + 1


class StepController:
    """Tracks one ``ExcitationStep`` (modes 1, 2, 4; mode 2 with or without α_v).

    Args:
        step: the step; its trajectories start at t = 0.
        sheet: the vehicle data sheet (geometry, drive, nominal parameters for feed-forward).
        settings: loop settings.

    Call ``command(t, measurement)`` once per cycle; it returns the motor torques (4,) [N m, motor
    side] to send for the next cycle.
    """

    def __init__(self, step: ExcitationStep, sheet: DataSheet,
                 settings: ControllerSettings | None = None):
        self.step = step
        self.sheet = sheet
        self.settings = s = settings or ControllerSettings()
        g, d, n = sheet.geometry, sheet.drive, sheet.nominal
        self.k = step.mode
        self.p_nominal = n.p
        self._chassis_gains = design_pd(s.chassis_bandwidth, s.damping, d.cycle_time)
        self._dalpha = DifferentiatorFilter(s.derivative_cutoff, d.cycle_time, 2)
        self._rate = LowPassFilter(s.chassis_rate_cutoff, d.cycle_time, 1)
        ar2 = (g.a / g.r) ** 2
        self._steer_inertia = np.array([n.C_l, n.C_r]) + 2 * n.B_w * ar2
        self._hold_rows = d.i_G * kinematics.H(1, np.zeros((1, 2)), g)[0][5:9, :].T  # (2, 4) H_1ᵀB
        self._hold_inverse = np.linalg.pinv(self._hold_rows)
        self._s_chassis = 0.0
        self._steer_integral = np.zeros(2)
        self.retune(s.steering_bandwidth)
        self._integral_deadband = INTEGRAL_DEADBAND_LSB * d.steering_lsb
        self._u_max = s.torque_margin * d.max_torque
        self.state: ControllerState | None = None
        self._chassis_terms_at = lru_cache(maxsize=4096)(self._chassis_terms_uncached)
        # odometry (3) at the measured α: steering sensor counts, few distinct values per step
        self._velocity_map_at = lru_cache(maxsize=4096)(
            lambda alpha_l, alpha_r: odometry.chassis_velocity_map(np.array([alpha_l, alpha_r]), sheet.geometry))
        self._fixed_chassis_terms = self._chassis_terms_uncached(0.0, 0.0) if self.k in (3, 4) else None
        self._plan = self._planned(np.arange(self.cycles) * d.cycle_time)
        self._warm_up()

    @property
    def cycles(self) -> int:
        """Cycles the step takes (:func:`step_cycles`)."""
        return step_cycles(self.step.duration, self.sheet.drive.cycle_time)

    def follow(self, vehicle, measurement, on_cycle: Callable | None = None):
        """Run the whole step on ``vehicle`` (a ``VehicleInterface``) from ``measurement`` (the last one):
        one command and exchange per cycle, ``on_cycle(measurement, command)`` after each. Returns the last
        measurement."""
        ts = self.sheet.drive.cycle_time
        for j in range(self.cycles):
            u = self.command(j * ts, measurement)
            measurement = vehicle.exchange(u)
            if on_cycle:
                on_cycle(measurement, u)
        return measurement

    def retune(self, steering_bandwidth: float) -> None:
        """Set the steering loop's bandwidth (rad/s): its PID gains (:func:`design_pid`) and the
        integral's anti-windup limit (at most 1.5 × the nominal steering Coulomb friction)."""
        s, d, n = self.settings, self.sheet.drive, self.sheet.nominal
        self.settings = replace(s, steering_bandwidth=steering_bandwidth)
        self._steer_gains = design_pid(steering_bandwidth, s.damping, d.cycle_time, s.steering_integral_ratio)
        self._integral_limit = 1.5 * np.array([n.d_cl, n.d_cr]) / (self._steer_inertia * self._steer_gains.ki)

    def _warm_up(self) -> None:
        """Evaluate the command path once: the model compiles on first use (≈ 0.1–0.3 s), which must
        not happen between two SYNCs."""
        a_ref, ad_ref, chassis, _ = self._reference_row(0.0)
        if chassis is not None:
            self._chassis_terms(a_ref)
        odometry.chassis_velocity(a_ref[None], ad_ref[None], np.zeros((1, 4)), self.sheet.geometry)

    # -- references -------------------------------------------------------------------------
    def _references(self, t: np.ndarray):
        """The references at the times t (N,), from one evaluation of the step's trajectories: α, α̇, α̈
        (N, 2) each, the chassis coordinate's (q, q̇, q̈) (N,) each or None, and α_v's (q, q̇, q̈) or None."""
        ref = self.step.evaluate(t)
        av = None
        if "alpha_v" in self.step.trajectories:
            av = ref["alpha_v"]
            h = 1e-4
            n = len(t)
            a = kinematics.f_icr(np.concatenate([av[0] - h, av[0], av[0] + h]), self.sheet.geometry)
            a_minus, a_mid, a_plus = a[:n], a[n:2 * n], a[2 * n:]
            da = (a_plus - a_minus) / (2 * h)
            dda = (a_plus - 2 * a_mid + a_minus) / h**2
            alpha = (a_mid, da * av[1][:, None], dda * av[1][:, None] ** 2 + da * av[2][:, None])
        else:
            alpha = tuple(np.stack([ref[c][i] for c in ("alpha_l", "alpha_r")], axis=1) for i in range(3))
        name = CHASSIS_COORDINATE.get(self.k)
        chassis = None
        if name is not None and name in self.step.trajectories:
            chassis = ref[name]
        return (*alpha, chassis, av)

    def _planned(self, t: np.ndarray) -> dict:
        """References and feed-forward at the times t (N,), computed at once: the feed-forward depends on
        the references only, so the cycle needs none of the model's evaluation."""
        a_ref, ad_ref, add_ref, chassis, av = self._references(t)
        return {"t": t, "alpha": a_ref, "alpha_dot": ad_ref, "chassis": chassis,
                "u_ff": self._feedforward(a_ref, ad_ref, add_ref, chassis, av)}

    def _reference_row(self, t: float):
        """(α, α̇ (2,), chassis (q, q̇) or None, u_ff (4,)) at step time t: the plan's row when t is on the
        cycle grid, else evaluated for t alone."""
        plan = self._plan
        j = int(round(t / self.sheet.drive.cycle_time))
        if not (0 <= j < len(plan["t"]) and plan["t"][j] == t):
            plan, j = self._planned(np.array([float(t)])), 0
        chassis = None if plan["chassis"] is None else (plan["chassis"][0][j], plan["chassis"][1][j])
        return plan["alpha"][j], plan["alpha_dot"][j], chassis, plan["u_ff"][j]

    def _chassis_rate(self, velocity: np.ndarray) -> float:
        """The step's chassis coordinate rate from the chassis-frame velocities (3,)."""
        return {2: velocity[0], 3: velocity[1], 4: velocity[2]}.get(self.k, 0.0)

    # -- one cycle ----------------------------------------------------------------------------
    def estimate(self, measurement) -> ControllerState:
        """Update the state estimate from one measurement (the client's ``Measurement``)."""
        d = self.sheet.drive
        alpha = np.asarray(measurement.alpha, dtype=float)
        alpha_dot = self._dalpha.update(alpha)
        beta_dot = np.asarray(measurement.motor_velocity, dtype=float) / d.i_G
        rates = np.concatenate([alpha_dot, beta_dot])
        velocity = self._velocity_map_at(float(alpha[0]), float(alpha[1])) @ rates
        if self.state is not None:
            self._s_chassis += self._chassis_rate(velocity) * d.cycle_time
        self.state = ControllerState(alpha, alpha_dot, beta_dot, velocity, self._s_chassis)
        return self.state

    def command(self, t: float, measurement) -> np.ndarray:
        """Motor torques (4,) [N m, motor side] for the cycle after ``measurement``, at step time t."""
        st = self.estimate(measurement)
        d = self.sheet.drive
        a_ref, ad_ref, chassis, u_ff = self._reference_row(t)
        sg, cg = self._steer_gains, self._chassis_gains
        error = a_ref - st.alpha
        integrate = np.where(np.abs(error) > self._integral_deadband, error, 0.0)
        limit = self._integral_limit
        self._steer_integral = np.minimum(np.maximum(self._steer_integral + integrate * d.cycle_time, -limit),
                                          limit)
        q_steer = self._steer_inertia * (sg.kp * error + sg.kd * (ad_ref - st.alpha_dot)
                                         + sg.ki * self._steer_integral)
        if chassis is None:
            u_fb = self._hold_inverse @ q_steer
        else:
            inertia, inverse = self._chassis_terms(st.alpha)
            rate = float(self._rate.update(self._chassis_rate(st.velocity))[0])
            q_ch = inertia * (cg.kp * (chassis[0] - st.s_chassis) + cg.kd * (chassis[1] - rate))
            u_fb = inverse @ np.array([q_steer[0], q_steer[1], q_ch])
        return np.minimum(np.maximum(u_ff + u_fb, -self._u_max), self._u_max)

    def _feedforward(self, a_ref, ad_ref, add_ref, chassis, av) -> np.ndarray:
        """Feed-forward motor torques (N, 4) [N m, motor side] of (21) along the references (N samples)."""
        k, n = self.k, len(a_ref)
        q = np.zeros((n, 9))
        q[:, 3:5] = a_ref
        if k == 1:
            sd, sdd = ad_ref, add_ref
        elif k == 2:
            av_d, av_dd = (av[1], av[2]) if av is not None else (np.zeros(n), np.zeros(n))
            sd = np.stack([av_d, chassis[1]], axis=1)
            sdd = np.stack([av_dd, chassis[2]], axis=1)
        else:
            sd, sdd = chassis[1][:, None], chassis[2][:, None]
        return np.asarray(dynamics.feedforward(k, q, sd, sdd, self.p_nominal, self.sheet.geometry,
                                               self.sheet.drive.i_G))

    def _alpha_v(self, alpha: np.ndarray) -> float:
        """The virtual steering angle (rad) the measured α (2,) imply in mode 2 (0 in the other modes). α
        off the mode-2 configuration (a steering unit sticking or lagging, as the outer one entering an
        arc at 1.25 rad inner angle) can imply one beyond the mode's range ±arctan(l/b): the chassis loop
        then takes its column at the nearest admissible one, the range's end."""
        if self.k != 2:
            return 0.0
        g = self.sheet.geometry
        limit = kinematics.alpha_v_max(g)
        return float(np.clip(kinematics.alpha_v_from_alpha(alpha[None], g)[0], -limit, limit))

    def _chassis_column(self, alpha: np.ndarray) -> np.ndarray:
        """The column of H_k belonging to the chassis coordinate, (9,)."""
        g = self.sheet.geometry
        if self.k == 2:
            av = np.array([self._alpha_v(alpha)])
            return kinematics.H(2, kinematics.f_icr(av, g), g, alpha_v=av)[0][:, 1]
        return kinematics.H(self.k, kinematics.mode_alpha(self.k, g)[None], g)[0][:, 0]

    def _chassis_terms(self, alpha: np.ndarray) -> tuple[float, np.ndarray]:
        """The chassis loop's nominal inertia h ᵀ M h and the allocation (4, 3), the pseudoinverse of the
        stacked input rows (H_1ᵀB of the steering, H_kᵀB of the chassis column h), at the measured α.
        Modes 3 and 4 hold one configuration, so both are fixed; in mode 2 they depend on α through α_v,
        and the measured α are steering sensor counts, few distinct values recurring cycle after cycle."""
        if self.k != 2:
            return self._fixed_chassis_terms
        return self._chassis_terms_at(float(alpha[0]), float(alpha[1]))

    def _chassis_terms_uncached(self, alpha_l: float, alpha_r: float) -> tuple[float, np.ndarray]:
        h = self._chassis_column(np.array([alpha_l, alpha_r]))
        inverse = np.linalg.pinv(np.vstack([self._hold_rows, self.sheet.drive.i_G * h[5:9][None]]))
        inverse.flags.writeable = False
        return self._chassis_inertia(h), inverse

    def _chassis_inertia(self, h: np.ndarray) -> float:
        """Nominal generalized inertia h ᵀ M h of the chassis column h (9,) of H_k."""
        n = self.sheet.nominal
        return float(n.m_ch * (h[0] ** 2 + h[1] ** 2) + (n.C_ch + n.C_l + n.C_r) * h[2] ** 2
                     + n.B_w * np.sum(h[5:9] ** 2))


def quintic_alignment(alpha_from, alpha_to, duration: float, name: str = "align") -> ExcitationStep:
    """Mode-1 wheel alignment at rest: α moves from ``alpha_from`` to ``alpha_to`` (2,) [rad] on a
    quintic (rest to rest) in ``duration`` s; the chassis stays where it is."""
    from .fourier import AnalyticTrajectory

    def make(a0: float, a1: float):
        def f(tau):
            s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
            ds = 30 * tau**2 - 60 * tau**3 + 30 * tau**4
            dds = 60 * tau - 180 * tau**2 + 120 * tau**3
            return a0 + (a1 - a0) * s, (a1 - a0) * ds, (a1 - a0) * dds
        return AnalyticTrajectory(duration, f)

    return ExcitationStep(name, 1, {"alpha_l": make(alpha_from[0], alpha_to[0]),
                                       "alpha_r": make(alpha_from[1], alpha_to[1])})
