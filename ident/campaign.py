"""The four-step identification campaign of the paper (section 6.2) plus the lane-change validation run,
executed through a vehicle link (the CANopen client, or anything with the same ``exchange``/``stop``).

Order: steer left, steer right, straight, rotation (the paper's order: straight before rotation so the
direction of the straight motion is known), then the lane change in mode 2 that the fit never sees, then
two arcs in mode 2 at held steering angles, one to each side (for the gap diagnosis; the fit never sees
them either). The
wheels are aligned at rest between steps (mode 1). Everything is recorded cycle by cycle into the run
directory; if anything fails the wheels get torque 0, the drives are disabled, and what was recorded so
far stays on disk.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Callable

import numpy as np

from qomni.vehicle_interface import VehicleInterface

from . import excitation, kinematics
from .controller import ControllerSettings, StepController, quintic_alignment, step_cycles
from .probe import DeadTimeProbe
from qomni.datasheet import DataSheet
from .excitation import ExcitationStep
from .json_values import json_number
from .min_cond_design import trajectory_pair_condition
from .recording import SignalWriter
from .regressor import VELOCITY_THRESHOLD
from .rundir import METADATA, RUN_FORMAT, SIGNALS, write_json

IDENTIFICATION_STEPS = ("steer_left", "steer_right", "straight", "rotation")
VALIDATION_STEP = "lane_change"
#: Mode 2 at a held α_v, yawing the chassis about a point beside it, to the left and to the right
#: (``excitation.arc_excitation``): the diagnosis' view of a yaw inertia that depends on the steering
#: angles. Neither fitted nor validated.
ARC_STEPS = ("arc_left", "arc_right")


#: rad: a steering angle this close to the stops aborts the campaign.
STOP_MARGIN = 0.03

#: Step name of the rows recorded while the steering loop was in a limit cycle, and of the recovery from it.
LIMIT_CYCLE_STEP = "limit_cycle"
#: A limit cycle: in this many seconds (a sliding window) some drive was commanded at the torque limit in at
#: least LIMIT_CYCLE_SHARE of the cycles. A loop that tracks the campaign's trajectories stays inside its
#: margin: on the full-campaign suite's vehicles without an actuator delay (effects over their realistic
#: ranges, the prototype, the heavy platform) no cycle reached the limit in any step; with a 16 ms delay
#: 73 % of the first 0.5 s rest did, and 68–98 % of every later step.
LIMIT_CYCLE_WINDOW = 0.25
LIMIT_CYCLE_SHARE = 0.5
#: s of zero torque after a limit cycle is detected (the steering coasts to rest on its friction), then s
#: of a quintic back to α = 0 at the bandwidth designed for ``max_dead_time``.
COAST = 0.5
RECOVER = 1.5


#: The min_cond design keeps the planned cond(Θ̂₁ᵀΘ̂₁) this share below ``CampaignSettings.cond_target``:
#: the measured figure adds tracking error, noise and the zero-phase filter (docs/identification.md).
PLANNED_COND_MARGIN = 0.03
#: The chassis steps' cond cap is searched to this resolution.
CAP_RESOLUTION = 0.05


class CampaignAborted(RuntimeError):
    """The campaign stopped early; the run directory keeps what was recorded until then."""


class PlanPrefixError(ValueError):
    """The segments a campaign was asked to drive up to are not the start of its plan."""


class _LimitCycle(Exception):
    """The steering loop is in a limit cycle at the torque limit (during ``segment``, at ``time``)."""

    def __init__(self, segment: str, time: float, share: float, measurement):
        super().__init__(segment)
        self.segment, self.time, self.share, self.measurement = segment, time, share, measurement


@dataclass(frozen=True)
class CampaignSettings:
    """Durations (s) and limits (SI) of the campaign's movements; ``seed`` designs the excitation."""

    steer_duration: float = 12.0
    straight_duration: float = 14.0
    rotation_duration: float = 14.0
    lane_change_duration: float = 12.0
    align_duration: float = 2.0
    rest_duration: float = 0.5
    alpha_max: float = 0.6
    alpha_dot_max: float = 2.5
    alpha_ddot_max: float = 10.0
    x_max: float = 1.2
    x_dot_max: float = 0.8
    x_ddot_max: float = 1.0
    gamma_max: float = 1.0
    gamma_dot_max: float = 0.8
    # The rotation's yaw acceleration bound. At 3.0 rad/s² its drives peak at 1.8 of their 6 N m (1.3 at
    # 1.5): the C_ch rows stand further out of the ideal vehicle's residual (1.2 N m RMS in the rotation),
    # and a steering-unit mass of 8 kg per wheel (+0.5 % yaw inertia) becomes visible (docs/diagnosis.md).
    gamma_ddot_max: float = 3.0
    lane_distance: float = 4.5
    # A double lane change (out and back) 0.25 m wide over the same way steers at up to 0.9 rad/s and
    # keeps |α̇_v| above the steering's stiction threshold for about 40 % of the manoeuvre, so the
    # validation tests the steering dynamics (paper Fig. 6); a single 1 m lane change never leaves
    # stiction. Wider changes steer harder and raise the x_ch error of the prototype's model
    # (docs/identification.md, Validation).
    lane_width: float = 0.25
    lane_changes: int = 2
    # Each arc's length (0: none), the inner steering units' angle (rad; 0.32 rad inside the stops at
    # π/2, and no closer to tighter stops: arc_inner_angle) and the path acceleration bound (m/s²); their
    # yaw keeps the rotation's limits. The tighter the turn, the more the steering units' yaw inertia
    # differs from mode 4's per newton of drive (docs/diagnosis.md, Where: the arcs).
    arc_duration: float = 10.0
    arc_inner_alpha: float = 1.25
    arc_x_ddot_max: float = 1.6
    # The identification steps' design criterion (excitation.CRITERIA). "richness" is the random-start
    # design of ``n_harmonics`` harmonics over ``steer_period`` / ``chassis_period``, with ``seed``;
    # "min_cond" minimises each viscous/Coulomb pair's condition number, the pairs that bound cond(Θ̂₁ᵀΘ̂₁),
    # with ``min_cond_harmonics`` harmonics of a base period it chooses itself, and gives the chassis steps
    # the most acceleration that keeps the planned stack within ``cond_target``: cond 4.7 instead of 18.7
    # and better steering parameters, but the twin-reference diagnosis names heavy steering units at the
    # low end of their range less often (docs/identification.md, "Optimised excitation"). The arcs
    # always use the richness design.
    excitation: str = "richness"
    min_cond_harmonics: int = 16
    # With "min_cond": the chassis steps' harmonics (their bursts need more than the steering's sawtooth)
    # and the bound their design keeps the planned cond(Θ̂₁ᵀΘ̂₁) below (less PLANNED_COND_MARGIN).
    min_cond_chassis_harmonics: int = 32
    cond_target: float = 5.0
    n_harmonics: int = 5
    steer_period: float = 4.0  # s, base period of the steering excitation (repeated over the step)
    chassis_period: float = 5.0  # s, base period of the straight and rotation excitation
    seed: int = 0

    def __post_init__(self) -> None:
        """Refuse a setting no campaign can drive (a run's metadata.json edited or from another tool).

        Raises: ValueError naming the key: not a number (a string, a boolean), not finite, an integer
        setting with a fraction, a duration, limit or period ≤ 0 (the arcs' duration and the rest and
        alignment times may be 0), fewer than one lane change or harmonic, a cond target ≤ 1, an excitation
        criterion not in ``excitation.CRITERIA``."""
        may_be_zero = {"arc_duration", "align_duration", "rest_duration", "seed"}
        at_least_one = {"lane_changes", "n_harmonics", "min_cond_harmonics", "min_cond_chassis_harmonics"}
        if self.excitation not in excitation.CRITERIA:
            raise ValueError(f"settings.excitation must be one of {excitation.CRITERIA}, "
                             f"got {self.excitation!r}")
        for f in fields(self):
            if f.name == "excitation":
                continue
            where = f"settings.{f.name}"
            value = json_number(getattr(self, f.name), where)
            if f.type in ("int", int):
                if value != int(value):
                    raise ValueError(f"{where} must be an integer, got {value!r}")
                value = int(value)
            object.__setattr__(self, f.name, value)
            if f.name in at_least_one and value < 1:
                raise ValueError(f"{where} must be >= 1, got {value!r}")
            if f.name in may_be_zero and value < 0:
                raise ValueError(f"{where} must be >= 0, got {value!r}")
            if f.name not in may_be_zero | at_least_one and not value > 0:
                raise ValueError(f"{where} must be > 0, got {value!r}")
            if f.name == "cond_target" and not value > 1:
                raise ValueError(f"{where} must be > 1 (a condition number), got {value!r}")

    @classmethod
    def quick(cls, **overrides) -> "CampaignSettings":
        """A short campaign (≈ 46 s emulated) for tests and smoke runs."""
        short = dict(steer_duration=5.0, straight_duration=6.0, rotation_duration=6.0,
                     lane_change_duration=8.0, align_duration=1.5, rest_duration=0.3,
                     alpha_dot_max=1.5, alpha_ddot_max=6.0, lane_distance=3.0, lane_width=0.1,
                     n_harmonics=4, arc_duration=4.0)
        short.update(overrides)
        return cls(**short)


#: What a run that does not record a setting drove: one lane change, no arcs, the richness design.
RECORDED_BEFORE = {"lane_changes": 1, "arc_duration": 0.0, "excitation": "richness"}


def recorded_settings(recorded: dict) -> CampaignSettings:
    """The settings a run drove, from its ``metadata.json`` ``settings``: a setting it does not record takes
    :data:`RECORDED_BEFORE`'s value where it has one, else the default (the other settings added since
    default to what runs drove before them).

    Raises: TypeError for a setting the campaign does not know, ValueError for one it refuses."""
    return CampaignSettings(**{**RECORDED_BEFORE, **recorded})


#: rad: how far inside the steering stops the arcs' inner units stand at most (the prototype's 1.25 rad
#: inside its stops at π/2); a vehicle with tighter stops drives wider arcs.
ARC_STOP_CLEARANCE = math.pi / 2 - 1.25


def arc_inner_angle(settings: CampaignSettings, geometry) -> float:
    """The arcs' inner steering angle (rad): ``settings.arc_inner_alpha``, or :data:`ARC_STOP_CLEARANCE`
    inside the steering stops where those are tighter."""
    return min(settings.arc_inner_alpha, geometry.steering_limit - ARC_STOP_CLEARANCE)


def plan(sheet: DataSheet, settings: CampaignSettings) -> list[ExcitationStep]:
    """The four identification steps, the lane change and (``arc_duration`` > 0) the two arcs, designed
    from ``settings``.

    Raises:
        ValueError: a step's limits cannot be met, the rotation's steering angles lie within
            :data:`STOP_MARGIN` of the steering stops, or the stops leave the arcs no room
            (:func:`arc_inner_angle`).
    """
    g, s = sheet.geometry, settings
    alpha4 = float(kinematics.mode_alpha(4, g)[1])   # the rotation's steering angles, ±
    if not alpha4 < g.steering_limit - STOP_MARGIN:
        raise ValueError(f"the rotation (mode 4) holds the steering units at ±{alpha4:.4g} rad (atan(l/b)), "
                         f"within {STOP_MARGIN} rad of the steering stops ({g.steering_limit:.4g} rad)")
    arc_inner_alpha = arc_inner_angle(s, g)
    if s.arc_duration > 0 and not arc_inner_alpha > 0:
        raise ValueError(f"the arcs' inner units have no room inside the steering stops "
                         f"({g.steering_limit:.4g} rad, less than {ARC_STOP_CLEARANCE:.3g} rad)")
    common = dict(n_harmonics=s.n_harmonics)

    def designed(coordinate: str, duration: float, period: float, cond_cap: float | None = None) -> dict:
        """The design keywords of one excited coordinate."""
        if s.excitation == "min_cond":
            if cond_cap is None:
                return dict(criterion="min_cond", threshold=VELOCITY_THRESHOLD[coordinate],
                            n_harmonics=s.min_cond_harmonics)
            return dict(criterion="min_cond", threshold=VELOCITY_THRESHOLD[coordinate],
                        n_harmonics=s.min_cond_chassis_harmonics, cond_cap=cond_cap)
        # A long step is several repetitions of a short base period: a single slow period would keep
        # |α̇| nearly constant within the position limits, which makes d_v and d_c collinear.
        return dict(periods=_periods(duration, period), **common)

    steer = dict(duration=s.steer_duration, alpha_max=s.alpha_max, alpha_dot_max=s.alpha_dot_max,
                 alpha_ddot_max=s.alpha_ddot_max, **designed("alpha_l", s.steer_duration, s.steer_period))
    steering = [excitation.steer_left_excitation(seed=s.seed + 1, **steer),
                excitation.steer_right_excitation(seed=s.seed + 2, **steer)]

    def chassis(cap: float | None) -> list[ExcitationStep]:
        return [excitation.straight_excitation(duration=s.straight_duration, x_max=s.x_max,
                                               x_dot_max=s.x_dot_max, x_ddot_max=s.x_ddot_max,
                                               seed=s.seed + 3,
                                               **designed("x_ch", s.straight_duration, s.chassis_period, cap)),
                excitation.rotation_excitation(l=g.l, b=g.b, duration=s.rotation_duration,
                                               gamma_max=s.gamma_max, gamma_dot_max=s.gamma_dot_max,
                                               gamma_ddot_max=s.gamma_ddot_max,
                                               seed=s.seed + 4,
                                               **designed("gamma_ch", s.rotation_duration, s.chassis_period,
                                                          cap))]

    if s.excitation == "min_cond":
        identification = steering + _capped_chassis(steering, chassis, sheet, s.cond_target)
    else:
        identification = steering + chassis(None)
    steps = identification + [
        excitation.lane_change(l=g.l, duration=s.lane_change_duration, distance=s.lane_distance,
                               lane_width=s.lane_width, changes=s.lane_changes,
                               alpha_v_max=s.alpha_max, alpha_dot_max=s.alpha_dot_max,
                               alpha_ddot_max=s.alpha_ddot_max, x_dot_max=s.x_dot_max,
                               x_ddot_max=s.x_ddot_max, narrow_to_limits=True),
    ]
    if s.arc_duration > 0:
        steps += [excitation.arc_excitation(
            l=g.l, b=g.b, side=side, inner_alpha=arc_inner_alpha, duration=s.arc_duration,
            gamma_max=s.gamma_max,
            gamma_dot_max=s.gamma_dot_max, gamma_ddot_max=s.gamma_ddot_max, x_ddot_max=s.arc_x_ddot_max,
            periods=_periods(s.arc_duration, s.chassis_period), seed=s.seed + i, **common)
            for i, side in ((5, 1), (6, -1))]
    return steps


def _capped_chassis(steering: list[ExcitationStep], chassis, sheet: DataSheet,
                    cond_target: float) -> list[ExcitationStep]:
    """The min_cond campaign's straight and rotation: designed for the most acceleration under a common
    pair cond cap, the largest cap (to :data:`CAP_RESOLUTION`, between the steering pair's cond and
    ``cond_target``) whose planned cond(Θ̂₁ᵀΘ̂₁) stays within (1 − :data:`PLANNED_COND_MARGIN`) ×
    ``cond_target``; the steering pair's cond where none does.

    The steering pairs bound the stack's cond from below (docs/identification.md, "Optimised
    excitation"); the chassis steps may spend the slack above them on acceleration. The stack is checked
    as a whole because the straight and the rotation share the wheels' pair (d_vw, d_cw): two steps each
    within the cap can give that pair a larger cond together."""
    from .planned_regressor import steps_condition   # it plans through this module

    (coordinate, trajectory), = steering[0].trajectories.items()
    low = round(trajectory_pair_condition(trajectory, VELOCITY_THRESHOLD[coordinate],
                                          sheet.drive.cycle_time), 2)
    bound = (1 - PLANNED_COND_MARGIN) * cond_target

    def within(cap: float) -> list[ExcitationStep] | None:
        steps = chassis(cap)
        return steps if steps_condition(steering + steps, sheet) <= bound else None

    best = within(low) if low < cond_target else None
    if best is None:
        return chassis(low)
    high = round(cond_target, 2)
    top = within(high)
    if top is not None:
        return top
    while high - low > CAP_RESOLUTION:
        middle = round((low + high) / 2, 2)
        steps = within(middle)
        if steps is None:
            high = middle
        else:
            low, best = middle, steps
    return best


def _periods(duration: float, base_period: float) -> int:
    return max(1, round(duration / base_period))


def step_start_alpha(step: ExcitationStep) -> np.ndarray:
    """Steering angles (2,) [rad] the step starts from."""
    ref = step.evaluate(np.array([0.0]))
    if "alpha_l" in ref:
        return np.array([ref["alpha_l"][0][0], ref["alpha_r"][0][0]])
    return np.zeros(2)


def occupied_rectangle(steps: list[ExcitationStep], sheet: DataSheet) -> dict:
    """Space the campaign needs, section 6.2: (l + 2·max|x_ch|) × (√(l²+b²) + 2a), in m."""
    g = sheet.geometry
    straight = next(s for s in steps if s.name == "straight")
    length, width = excitation.occupied_rectangle(straight.trajectories["x_ch"], g.l, g.b, g.a)
    return {"length": float(length), "width": float(width), "unit": "m"}


class Campaign:
    """The planned campaign; ``run(vehicle)`` executes it and records into ``run_dir``.

    Planning (trajectory design) happens here, before any vehicle is connected: drives fault when their
    master stops sending SYNC, so nothing slow may happen between connecting and running.

    Args:
        sheet: the vehicle's data sheet (geometry, drive, nominal parameters).
        run_dir: output directory (created; must not already hold a signals file).
        settings: durations and limits.
        controller: loop settings.
        source: a description of where the data come from (bus spec), stored in the metadata.
        on_progress: called with (cycles done, cycles total, segment name) every cycle.
        until: the names of the planned segments to drive, the plan's first ones (rest, align and steps
            alike; default all): a digital twin repeating a run that stopped after them.

    Raises:
        PlanPrefixError: ``until`` is not the start of the plan.
        FileExistsError: ``run_dir`` already holds a recording.
    """

    def __init__(self, sheet: DataSheet, run_dir: str | Path,
                 settings: CampaignSettings | None = None,
                 controller: ControllerSettings | None = None, source: str = "",
                 on_progress: Callable[[int, int, str], None] | None = None,
                 until: tuple[str, ...] | None = None):
        self.sheet = sheet
        self.settings = settings or CampaignSettings()
        self.controller_settings = controller or ControllerSettings()
        self.run_dir = Path(run_dir)
        self.source = source
        self.on_progress = on_progress
        self.steps = plan(sheet, self.settings)
        from .planned_regressor import steps_condition   # imports this module's names: here, not on top
        #: cond(Θ̂₁ᵀΘ̂₁) along the planned trajectories, before the vehicle moves (docs/identification.md)
        self.planned_condition = steps_condition(self.steps, sheet)
        self.segments = self._segments()
        if until is not None:
            planned = tuple(seg.name for seg in self.segments[:len(until)])
            if planned != tuple(until):
                raise PlanPrefixError(f"segments {list(until)} are not the first of the plan's {list(planned)}")
            self.segments = self.segments[:len(until)]
        # built now: the first one compiles the model (≈ 0.3 s), far longer than a SYNC timeout
        self.controllers = [StepController(seg, sheet, self.controller_settings)
                            for seg in self.segments]
        self.probe = DeadTimeProbe(sheet, self.controller_settings) if self.controller_settings.probe else None
        self.run_dir.mkdir(parents=True, exist_ok=True)
        if (self.run_dir / SIGNALS).exists():
            raise FileExistsError(f"{self.run_dir / SIGNALS} exists; choose a new run directory")

    def _segments(self) -> list[ExcitationStep]:
        s = self.settings
        segments: list[ExcitationStep] = []
        alpha = np.zeros(2)
        for step in self.steps:
            start = step_start_alpha(step)
            if np.max(np.abs(start - alpha)) > 1e-6:
                segments.append(quintic_alignment(alpha, start, s.align_duration, name="align"))
            segments.append(quintic_alignment(start, start, s.rest_duration, name="rest"))
            segments.append(step)
            alpha = _step_end_alpha(step, self.sheet)
        segments.append(quintic_alignment(alpha, alpha, s.rest_duration, name="rest"))
        return segments

    @property
    def total_cycles(self) -> int:
        return sum(c.cycles for c in self.controllers) + (self.probe.total_cycles if self.probe else 0)

    def run(self, vehicle: VehicleInterface) -> dict:
        """Execute all segments on ``vehicle`` (connected, drives enabled); returns the metadata
        written to ``metadata.json``.

        A steering loop that falls into a limit cycle at the torque limit before the first identification
        step has ended (``ControllerSettings.probe_on_limit_cycle``) is stopped and the campaign starts again
        after the dead-time probe (then, if the probe's bandwidth cycles as well, at the bandwidth designed
        for ``max_dead_time``): :meth:`_recover`.

        Raises:
            CampaignAborted: a communication error, a steering angle near the stops, a third limit cycle,
                or an interrupt (KeyboardInterrupt); the vehicle is stopped and the recording kept.
        """
        self.vehicle = vehicle
        meta = self._metadata()
        meta["status"] = "running"
        self._write_metadata(meta)
        self._done = 0
        writer = SignalWriter(self.run_dir / SIGNALS)
        try:
            measurement = self.vehicle.exchange(np.zeros(4))
            if self.probe is not None:
                measurement = self._probe(measurement, writer, meta)
                self._done = self.probe.total_cycles
            recoveries = 0
            while True:
                try:
                    measurement = self._segments_run(measurement, writer, meta,
                                                     self.controller_settings.probe_on_limit_cycle)
                    break
                except _LimitCycle as cycle:
                    recoveries += 1
                    measurement = self._recover(cycle, writer, meta, recoveries)
            meta["status"] = "complete"
            meta["missed_samples"] = _missed(self.vehicle)
        except BaseException as exc:  # noqa: BLE001 - stop the wheels whatever happened
            meta["status"] = f"aborted: {type(exc).__name__}: {exc}"
            meta["missed_samples"] = _missed(self.vehicle)
            self._safe_stop()
            writer.close()
            self._write_metadata(meta)
            if isinstance(exc, CampaignAborted):
                raise
            raise CampaignAborted(meta["status"]) from exc
        self._safe_stop()
        writer.close()
        meta["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S")
        self._write_metadata(meta)
        return meta

    def _segments_run(self, measurement, writer: SignalWriter, meta: dict, watch: bool):
        """Every planned segment, from the first; returns the last measurement. With ``watch``, the
        segments up to the first identification step are held back in the recording until they end
        without a limit cycle (:data:`LIMIT_CYCLE_WINDOW`); one raises :class:`_LimitCycle`.

        Raises:
            CampaignAborted: a steering angle near the stops."""
        ts = self.sheet.drive.cycle_time
        limit = self.sheet.geometry.steering_limit - STOP_MARGIN
        total = self.total_cycles
        names = [seg.name for seg in self.segments]
        watched = names.index(IDENTIFICATION_STEPS[0]) + 1 if watch and IDENTIFICATION_STEPS[0] in names else 0
        window = max(1, int(round(LIMIT_CYCLE_WINDOW / ts)))
        at_limit = np.zeros(window, dtype=bool)            # a ring over the last ``window`` cycles
        n_at_limit = 0
        u_limit = self.controller_settings.torque_margin * self.sheet.drive.max_torque * (1 - 1e-9)
        held = []
        if watched:
            writer.hold()
        for i, (seg, ctrl) in enumerate(zip(self.segments, self.controllers)):
            start = measurement.time
            for j in range(ctrl.cycles):
                u = ctrl.command(j * ts, measurement)
                measurement = self.vehicle.exchange(u)
                writer.write(seg.name, seg.mode, measurement, u)
                if max(map(abs, measurement.alpha)) > limit:
                    raise CampaignAborted(
                        f"steering angle {np.round(measurement.alpha, 3)} rad near the stops "
                        f"during '{seg.name}'")
                if i < watched:
                    slot, now = self._done % window, bool(np.max(np.abs(u)) >= u_limit)
                    n_at_limit += int(now) - int(at_limit[slot])
                    at_limit[slot] = now
                    if n_at_limit >= LIMIT_CYCLE_SHARE * window:
                        raise _LimitCycle(seg.name, measurement.time, n_at_limit / window, measurement)
                self._done += 1
                if self.on_progress:
                    self.on_progress(self._done, total, seg.name)
            segment = {"name": seg.name, "k": seg.mode, "t_start": start, "t_end": measurement.time}
            if i < watched:
                held.append(segment)
                if i == watched - 1:
                    writer.release()
                    meta["segments"].extend(held)
            else:
                meta["segments"].append(segment)
            writer.flush()
            self._write_metadata(meta)
        return measurement

    def _recover(self, cycle: _LimitCycle, writer: SignalWriter, meta: dict, recoveries: int):
        """After a limit cycle: the held rows recorded as step :data:`LIMIT_CYCLE_STEP`, the wheels given
        zero torque for :data:`COAST` s and the steering brought back to α = 0 at the bandwidth designed for
        ``max_dead_time`` (both recorded under the same step), then the first time the dead-time probe
        (its bandwidth for every step, ``metadata.json`` ``probe``), the second time that safe bandwidth
        itself; every step's controller starts afresh. Returns the last measurement.

        Raises:
            CampaignAborted: a third limit cycle."""
        ts = self.sheet.drive.cycle_time
        writer.release(LIMIT_CYCLE_STEP)
        t_start = float(meta["segments"][-1]["t_end"]) if meta["segments"] else 0.0
        bandwidth = self.controllers[0].settings.steering_bandwidth
        meta.setdefault("limit_cycles", []).append({"segment": cycle.segment, "time": cycle.time,
                                                    "share_at_limit": cycle.share,
                                                    "steering_bandwidth": bandwidth})
        if recoveries > 2:
            raise CampaignAborted(f"steering loop in a limit cycle at the torque limit during "
                                  f"'{cycle.segment}' at {bandwidth:.3g} rad/s, the bandwidth designed for "
                                  f"a {self.controller_settings.max_dead_time * 1e3:.0f} ms dead time")
        measurement = cycle.measurement
        for _ in range(step_cycles(COAST, ts)):
            measurement = self.vehicle.exchange(np.zeros(4))
            writer.write(LIMIT_CYCLE_STEP, 1, measurement, np.zeros(4))
        # the probe's safe bandwidth brings the steering back; a campaign that has not probed yet probes next
        probe_now = self.probe is None
        if probe_now:
            self.probe = DeadTimeProbe(self.sheet, replace(self.controller_settings, probe=True))
        safe = replace(self.controller_settings, steering_bandwidth=self.probe.safe_bandwidth)
        back = quintic_alignment(np.asarray(measurement.alpha, dtype=float), np.zeros(2), RECOVER,
                                 name=LIMIT_CYCLE_STEP)
        measurement = StepController(back, self.sheet, safe).follow(
            self.vehicle, measurement, lambda m, u: writer.write(LIMIT_CYCLE_STEP, 1, m, u))
        writer.flush()
        meta["segments"].append({"name": LIMIT_CYCLE_STEP, "k": 1, "t_start": t_start,
                                 "t_end": measurement.time})
        # the steps run so far start afresh (their filters and integrals held the limit cycle)
        self.controllers = [StepController(seg, self.sheet, ctrl.settings) if ctrl.state is not None else ctrl
                            for seg, ctrl in zip(self.segments, self.controllers)]
        meta["controller"]["probe"] = True
        if probe_now:
            return self._probe(measurement, writer, meta)
        for ctrl in self.controllers:
            ctrl.retune(safe.steering_bandwidth)
        meta["controller"]["steering_bandwidth"] = safe.steering_bandwidth
        self._write_metadata(meta)
        return measurement

    def _probe(self, measurement, writer: SignalWriter, meta: dict):
        """The dead-time probe (qomni.ident.probe), recorded as step ``probe``; its steering bandwidth
        goes to every step's controller and its result to the metadata."""
        done = [0]

        def record(m, u):
            writer.write("probe", 1, m, u)
            done[0] += 1
            if self.on_progress:
                self.on_progress(done[0], self.total_cycles, "probe")

        start = measurement.time
        keep = None if self.controller_settings.probe_retunes else self.controller_settings.steering_bandwidth
        found, measurement = self.probe.run(self.vehicle, measurement, record, settle_bandwidth=keep)
        writer.flush()
        meta["segments"].append({"name": "probe", "k": 1, "t_start": start, "t_end": measurement.time})
        meta["probe"] = asdict(found)
        if self.controller_settings.probe_retunes:
            for ctrl in self.controllers:
                ctrl.retune(found.steering_bandwidth)
            meta["controller"]["steering_bandwidth"] = found.steering_bandwidth
        self._write_metadata(meta)
        return measurement

    def _safe_stop(self) -> None:
        try:
            self.vehicle.stop()
        except Exception:  # noqa: BLE001 - stopping must never mask the original failure
            pass

    def _metadata(self) -> dict:
        sheet = self.sheet
        return {
            "format": RUN_FORMAT,
            "vehicle": sheet.name,
            "source": self.source,
            "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "datasheet": {"geometry": asdict(sheet.geometry), "drive": asdict(sheet.drive),
                          "nominal": asdict(sheet.nominal)},
            "settings": asdict(self.settings),
            "controller": asdict(self.controller_settings),
            "occupied_rectangle": occupied_rectangle(self.steps, sheet),
            "planned_condition_number": (self.planned_condition if np.isfinite(self.planned_condition)
                                         else None),
            "identification_steps": list(IDENTIFICATION_STEPS),
            "validation_step": VALIDATION_STEP,
            "arc_steps": [step.name for step in self.steps if step.name in ARC_STEPS],
            "segments": [],
        }

    def _write_metadata(self, meta: dict) -> None:
        write_json(self.run_dir / METADATA, meta)


def _missed(vehicle) -> dict:
    """Samples the vehicle link held because their TPDO did not come: {"0x183": cycles, …} (a CAN client's
    ``missed``; empty for links without one)."""
    return {f"0x{cob:03X}": n for cob, n in sorted(getattr(vehicle, "missed", {}).items())}


def _step_end_alpha(step: ExcitationStep, sheet: DataSheet) -> np.ndarray:
    ref = step.evaluate(np.array([step.duration]))
    if "alpha_v" in step.trajectories:
        return kinematics.f_icr(ref["alpha_v"][0], sheet.geometry)[0]
    if "alpha_l" in ref:
        return np.array([ref["alpha_l"][0][0], ref["alpha_r"][0][0]])
    return np.zeros(2)
