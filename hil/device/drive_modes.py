"""CiA 402 position, profile and homing modes of the emulated drive: controllers acting on the physics
through the motor torque.

Source: CiA 402-2 (IEC 61800-7-201) §6: profile position (PP, 0x6060 = 1), profile velocity (PV, 3),
homing (HM, 6), cyclic synchronous position (CSP, 8); controlword bits 4 (new set-point / homing start),
5 (change set immediately), 6 (relative), 8 (halt); the mode-specific statusword bits 10, 12, 13.
Units: positions in motor encoder increments (inc), velocities inc/s, accelerations inc/s², torques per
mille of 0x6076 (docs/conventions.md); the full object list and gains are in docs/drive_modes.md.

Every mode ends in the drive's velocity loop (0x60F9 PI, the law of CSV in ``drive402``), whose output is
the torque the plant integrates: nothing is mirrored, the motion comes from the physics. Position modes
run a position loop in front of it (cascade)::

    v_cmd = k_ff · v_demand + K_v · (x_demand − x)        K_v = 0x2010:1 [0.001/s], k_ff = 0x2010:2 [‰]
    torque = velocity loop(v_cmd) + J_ff · a_demand       J_ff = 0x2010:3 [10⁻⁶ kg m², motor side]

with ``x`` = position actual 0x6064 and the loop's measurements taken at the previous SYNC, ``a_demand``
the demand's acceleration converted to rad/s² with 0x608F and the torque to ‰ of 0x6076. J_ff = 0 (the
default: the drive does not know its load) leaves the acceleration to the velocity loop's integral,
which then overshoots the profile velocity by a few per cent; a commissioned drive sets its inertia.

* CSP: ``x_demand`` = target position 0x607A as received at this SYNC, ``v_demand`` its difference to
  the previous SYNC's over the cycle time 0x1006. Following error 0x60F4 = x_demand − x; statusword bit 13
  while |0x60F4| > following error window 0x6065 for longer than 0x6066 [ms] (0x6065 = 0xFFFFFFFF: off).
* PP: a trapezoidal profile from the demand's state to the set-point with profile velocity 0x6081,
  acceleration 0x6083 and deceleration 0x6084. Handshake: a rising bit 4 takes 0x607A (relative to the
  last set-point if bit 6) and sets statusword bit 12 (set-point acknowledge) until bit 4 falls; with
  bit 5 the new set-point replaces the running one, else it waits for the running one to finish (one
  buffered set-point). Bit 10 (target reached) when the profile has ended and |x − target| ≤ position
  window 0x6067 for 0x6068 [ms]; halt (bit 8) decelerates to rest with 0x6084 and resumes when cleared.
* PV: the velocity demand ramps to target velocity 0x60FF with 0x6083 (speeding up) / 0x6084 (slowing
  down); halt ramps to 0. Bit 10 when the ramp has ended and |0x606C − 0x60FF| ≤ velocity window 0x606D,
  bit 12 when |0x606C| ≤ velocity threshold 0x606F.
* HM: rising bit 4 starts the method 0x6098. 35 and 37: the current position is the home position.
  34 / 33: move in positive / negative direction at 0x6099:2 (speed during search for zero) with
  homing acceleration 0x609A until the motor encoder's index pulse (one per motor revolution,
  0x608F:1 / 0x608F:2 increments), which is the home position; the drive then returns to it. At the home
  position the position actual value becomes the home offset 0x607C (the drive shifts 0x6064).
  Statusword bits 13/12/10: 0/0/1 not started or interrupted (halt), 0/0/0 in progress, 0/1/0 home found
  and returning, 0/1/1 completed, 1/0/1 error (0x6099:2 or 0x609A is 0).
"""
from __future__ import annotations

import math

from ..cia import (MODE_CSP, MODE_CST, MODE_CSV, MODE_HOMING, MODE_NONE, MODE_PP, MODE_PV,
                   SW_FOLLOWING_ERROR, SW_SETPOINT_ACK, SW_TARGET_REACHED)

#: The modes of operation the drive accepts in 0x6060; 0x6502 says the same (tests check both).
SUPPORTED_MODES = (MODE_NONE, MODE_PP, MODE_PV, MODE_HOMING, MODE_CSP, MODE_CSV, MODE_CST)
#: Homing methods (0x6098) of this drive: index pulse negative/positive, current position.
HOMING_METHODS = (33, 34, 35, 37)

CW_NEW_SETPOINT, CW_CHANGE_IMMEDIATELY, CW_RELATIVE, CW_HALT = 1 << 4, 1 << 5, 1 << 6, 1 << 8
SW_HOMING_ATTAINED, SW_HOMING_ERROR = SW_SETPOINT_ACK, SW_FOLLOWING_ERROR   # bits 12, 13 in HM
FOLLOWING_ERROR_OFF = 0xFFFFFFFF


def profile_step(x: float, v: float, target: float, v_max: float, acc: float, dec: float,
                 dt: float) -> tuple[float, float, bool]:
    """One cycle of a trapezoidal point-to-point profile; returns (x, v, finished).

    The velocity is the largest that still stops at ``target`` with deceleration ``dec`` (discrete-time
    braking curve), limited to ``v_max`` and changed by at most ``acc`` (speeding up) or ``dec``
    (slowing down) per second. Units: any length unit, s. ``v_max``, ``acc``, ``dec`` > 0.
    """
    rem = target - x
    if abs(rem) <= 0.5 and abs(v) <= dec * dt:
        return target, 0.0, True
    s = 1.0 if rem > 0 else -1.0
    h = dec * dt / 2
    v_des = s * min(v_max, -h + math.sqrt(h * h + 2 * dec * abs(rem)))
    speeding_up = v * v_des > 0 and abs(v_des) > abs(v) or v == 0
    step = (acc if speeding_up else dec) * dt
    v_new = v + max(-step, min(step, v_des - v))
    x_new = x + (v + v_new) / 2 * dt
    if (target - x_new) * s <= 0 and abs(v_new) <= 2 * dec * dt:
        return target, 0.0, True
    return x_new, v_new, False


def ramp(v: float, target: float, acc: float, dec: float, dt: float) -> float:
    """Velocity ramp one cycle toward ``target``: ``acc`` while |v| grows, ``dec`` while it shrinks."""
    speeding_up = v * target >= 0 and abs(target) > abs(v)
    step = (acc if speeding_up else dec) * dt
    return v + max(-step, min(step, target - v))


class DriveModes:
    """The mode controllers of one :class:`~qomni.hil.device.drive402.Drive402`.

    The drive calls :meth:`torque` at each SYNC in OPERATION ENABLED for the modes in
    :data:`SUPPORTED_MODES` other than CST/CSV, :meth:`controlword` on each controlword write,
    :meth:`restart` when it enters OPERATION ENABLED or changes mode, and adds :attr:`offset` to the
    measured position. Attributes: ``offset`` [inc], 0x6064 minus the raw encoder count (set by homing).
    """

    def __init__(self, drive):
        self.drive = drive
        self.offset = 0
        self.bits = 0
        self.homing = "idle"          # idle | running | returning | done | error | interrupted
        self._controlword = 0
        self._raw_previous = 0
        self.restart()

    # ----------------------------------------------------------- events
    def restart(self) -> None:
        """Demand := the actual state (no jump on enable or mode change); set-points dropped."""
        values = self.drive.values
        self.x = self._x_sampled = float(values.get((0x6064, 0), 0))
        self.v = float(values.get((0x606C, 0), 0)) if values.get((0x6061, 0)) == MODE_PV else 0.0
        self.last_target = values.get((0x607A, 0), 0)
        self.setpoint = None          # PP: running set-point [inc]
        self.pending = None           # PP: buffered set-point
        self.profile_done = True
        self.ack = False
        self._in_window_s = 0.0
        self._error_s = 0.0
        if self.homing in ("running", "returning"):
            self.homing = "interrupted"

    def controlword(self, word: int) -> None:
        """Controlword edges of bit 4 (set-point / homing start)."""
        rising = word & CW_NEW_SETPOINT and not self._controlword & CW_NEW_SETPOINT
        self._controlword = word
        if not word & CW_NEW_SETPOINT:
            self.ack = False
        if not rising or self.drive.state.name != "OPERATION_ENABLED":
            self._refresh()
            return
        mode = self.drive.values[(0x6061, 0)]
        if mode == MODE_PP:
            self._new_setpoint(word)
        elif mode == MODE_HOMING:
            self._start_homing()
        self._refresh()

    def _new_setpoint(self, word: int) -> None:
        values = self.drive.values
        base = self.pending if self.pending is not None else self.setpoint
        target = values[(0x607A, 0)] + (base if word & CW_RELATIVE and base is not None else 0)
        self.ack = True
        if word & CW_CHANGE_IMMEDIATELY or self.profile_done:
            self.setpoint, self.pending, self.profile_done = target, None, False
            self._in_window_s = 0.0
        else:
            self.pending = target

    def _start_homing(self) -> None:
        values = self.drive.values
        method = values.get((0x6098, 0), 35)
        self.x = self._x_sampled = float(values[(0x6064, 0)])
        self.v = 0.0
        self._raw_previous = values[(0x6064, 0)] - self.offset
        if method in (35, 37):
            self._set_home(values[(0x6064, 0)] - self.offset)
            self.homing = "done"
        elif not values.get((0x6099, 2)) or not values.get((0x609A, 0)):
            self.homing = "error"
        else:
            self.homing = "running"

    def _set_home(self, raw_home: int) -> None:
        """The raw encoder count ``raw_home`` becomes position actual = home offset 0x607C."""
        new = self.drive.values.get((0x607C, 0), 0) - raw_home
        self.x += new - self.offset
        self._x_sampled += new - self.offset
        self.drive.values[(0x6064, 0)] += new - self.offset
        self.offset = new

    # ------------------------------------------------------------ cycle
    def torque(self, mode: int, limit: int) -> int:
        """This SYNC's torque demand [‰ of 0x6076] in ``mode`` (0 for a mode without controller)."""
        drive, values = self.drive, self.drive.values
        dt = drive._cycle_time()
        halt = bool(self._controlword & CW_HALT)
        v0 = self.v
        if mode == MODE_CSP:
            target = values[(0x607A, 0)]
            self.v = (target - self.last_target) / dt
            self.last_target, self.x = target, float(target)
        elif mode == MODE_PP:
            self._profile_position(halt, dt)
        elif mode == MODE_PV:
            goal = 0 if halt else values.get((0x60FF, 0), 0)
            self.v = ramp(v0, goal, values.get((0x6083, 0), 0), values.get((0x6084, 0), 0), dt)
            self.profile_done = self.v == goal
        elif mode == MODE_HOMING:
            self._homing(halt, dt)
        else:
            return 0
        if mode == MODE_PV:
            out = drive._velocity_control(limit, self.v)
        else:
            out = self._position_loop(self.v, limit)
        out += self._acceleration_feed_forward((self.v - v0) / dt)
        self._supervise(mode, dt)
        self._refresh()
        return out

    def _position_loop(self, v_demand: float, limit: int) -> int:
        """Position loop on the previous SYNC's demand and measurement, then the velocity loop."""
        values = self.drive.values
        error = self._x_sampled - values[(0x6064, 0)]
        self._x_sampled = self.x
        values[(0x6062, 0)] = int(round(self.x))
        values[(0x60F4, 0)] = max(-0x80000000, min(0x7FFFFFFF, int(round(error))))
        kv = values.get((0x2010, 1), 0) * 1e-3
        kff = values.get((0x2010, 2), 1000) * 1e-3
        return self.drive._velocity_control(limit, kff * v_demand + kv * error)

    def _acceleration_feed_forward(self, acceleration: float) -> float:
        """J_ff · a [‰ of 0x6076] for a demand acceleration in inc/s²."""
        values = self.drive.values
        inertia = values.get((0x2010, 3), 0) * 1e-6
        if not inertia:
            return 0.0
        per_rev = values.get((0x608F, 1), 65536) / max(1, values.get((0x608F, 2), 1))
        return inertia * acceleration * 2 * math.pi / per_rev / (values[(0x6076, 0)] * 1e-6)

    def _profile_position(self, halt: bool, dt: float) -> None:
        values = self.drive.values
        acc, dec = values.get((0x6083, 0), 0), values.get((0x6084, 0), 0)
        if halt:
            self.v = ramp(self.v, 0.0, acc, dec, dt)
            self.x += self.v * dt
            return
        if self.profile_done and self.pending is not None:
            self.setpoint, self.pending, self.profile_done = self.pending, None, False
        if self.setpoint is None or self.profile_done:
            return
        if not values.get((0x6081, 0)) or not acc or not dec:
            return                      # no profile parameters: the drive holds its position
        self.x, self.v, self.profile_done = profile_step(self.x, self.v, self.setpoint, values[(0x6081, 0)],
                                                         acc, dec, dt)

    def _homing(self, halt: bool, dt: float) -> None:
        values = self.drive.values
        acc = values.get((0x609A, 0), 0)
        if self.homing not in ("running", "returning"):
            return
        if halt:
            self.v = ramp(self.v, 0.0, acc, acc, dt)
            self.x += self.v * dt
            if self.v == 0:
                self.homing = "interrupted"
            return
        speed = values.get((0x6099, 2), 0)
        if self.homing == "running":
            sign = 1 if values.get((0x6098, 0)) == 34 else -1
            self.v = ramp(self.v, sign * speed, acc, acc, dt)
            self.x += self.v * dt
            index = self._index_crossed()
            if index is not None:
                self._set_home(index)
                self.homing = "returning"
            return
        self.x, self.v, finished = profile_step(self.x, self.v, values.get((0x607C, 0), 0), speed, acc, acc, dt)
        if finished and self._settled(dt):
            self.homing = "done"

    def _index_crossed(self) -> int | None:
        """Raw count of an index pulse passed since the previous SYNC, else None."""
        values = self.drive.values
        per_rev = max(1, values.get((0x608F, 1), 65536) // max(1, values.get((0x608F, 2), 1)))
        raw = values[(0x6064, 0)] - self.offset
        previous, self._raw_previous = self._raw_previous, raw
        a, b = previous // per_rev, raw // per_rev
        return per_rev * max(a, b) if a != b else None

    def _settled(self, dt: float) -> bool:
        """|x − x_demand| ≤ position window 0x6067 for 0x6068 ms (the timer advances per call)."""
        values = self.drive.values
        if abs(values[(0x6064, 0)] - self.x) <= values.get((0x6067, 0), 0):
            self._in_window_s += dt
        else:
            self._in_window_s = 0.0
        return self._in_window_s * 1e3 >= values.get((0x6068, 0), 0)

    def _supervise(self, mode: int, dt: float) -> None:
        values = self.drive.values
        if mode == MODE_PP and self.profile_done and self.setpoint is not None:
            self._settled(dt)
        window = values.get((0x6065, 0), FOLLOWING_ERROR_OFF)
        if mode in (MODE_CSP, MODE_PP) and window != FOLLOWING_ERROR_OFF and \
                abs(values.get((0x60F4, 0), 0)) > window:
            self._error_s += dt
        else:
            self._error_s = 0.0

    # ---------------------------------------------------------- status
    def status_bits(self) -> int:
        """Statusword bits 10, 12, 13 of the mode shown in 0x6061 (0 outside OPERATION ENABLED)."""
        drive, values = self.drive, self.drive.values
        if drive.state.name != "OPERATION_ENABLED":
            return 0
        mode = values[(0x6061, 0)]
        if mode == MODE_CSP:
            following = self._error_s * 1e3 > values.get((0x6066, 0), 0)
            return SW_SETPOINT_ACK | (SW_FOLLOWING_ERROR if following else 0)
        if mode == MODE_PP:
            reached = self.profile_done and self.pending is None and (
                self.setpoint is None or self._in_window_s * 1e3 >= values.get((0x6068, 0), 0))
            halted = self._controlword & CW_HALT and self.v == 0
            following = self._error_s * 1e3 > values.get((0x6066, 0), 0)
            return ((SW_TARGET_REACHED if reached or halted else 0) | (SW_SETPOINT_ACK if self.ack else 0)
                    | (SW_FOLLOWING_ERROR if following else 0))
        if mode == MODE_PV:
            velocity = values.get((0x606C, 0), 0)
            reached = self.profile_done and abs(velocity - self.v) <= values.get((0x606D, 0), 0)
            still = abs(velocity) <= values.get((0x606F, 0), 0)
            return (SW_TARGET_REACHED if reached else 0) | (SW_SETPOINT_ACK if still else 0)
        if mode == MODE_HOMING:
            return {"idle": SW_TARGET_REACHED, "interrupted": SW_TARGET_REACHED, "running": 0,
                    "returning": SW_HOMING_ATTAINED, "done": SW_HOMING_ATTAINED | SW_TARGET_REACHED,
                    "error": SW_HOMING_ERROR | SW_TARGET_REACHED}[self.homing]
        return 0

    def _refresh(self) -> None:
        bits = self.status_bits()
        if bits != self.bits:
            self.bits = bits
            self.drive._update_statusword()
