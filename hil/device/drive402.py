"""CiA 402 wheel drive node: power state machine, cyclic synchronous torque (CST, 0x6060 = 10) and
cyclic synchronous velocity (CSV, 0x6060 = 9) modes; profile position, profile velocity, homing and
cyclic synchronous position are :mod:`.drive_modes` (dispatched by 0x6061 from :meth:`Drive402.latch_torque`),
and the node is an LSS slave (:mod:`.lss`). The drive stores its EDS in 0x1021 (CiA 301 "store EDS") and
keeps up to 4 kB of commissioning notes in the user data DOMAIN 0x2020.

Source: CiA 402-2 (IEC 61800-7-201) §6 "device control" (state machine, controlword 0x6040 command
coding, statusword 0x6041 state coding, abort connection option 0x6007, quick stop option 0x605A) and
the mode objects: CST 0x6071 target torque, CSV 0x60FF target velocity (increments/s) with the velocity
control parameter set 0x60F9; common 0x6072 max torque, 0x6076 motor rated torque, 0x6077 torque actual
value, 0x6087 torque slope (per mille/s), 0x6064 position actual and 0x606C velocity actual.
Units: docs/conventions.md.

Timing (see ``qomni.hil.device.server``): at each SYNC the drive applies the RPDOs received since the last SYNC
(controlword first takes effect here) and latches its torque for the coming cycle, in OPERATION
ENABLED only (else 0):

* CST: ``clip(0x6071, ±0x6072)``;
* CSV: ``clip(K_p·(0x60FF − v) + I, ±0x6072)`` with ``v`` the velocity actual 0x606C sampled at the
  previous SYNC, ``K_p`` = 0x60F9:1 [per mille of 0x6076 per 1000 increments/s] and the integral ``I``
  accumulating ``K_p·e·T/T_i`` per cycle (``T_i`` = 0x60F9:2 [ms], 0 = no integral; anti-windup by
  clamping ``I`` to ±0x6072); T = 0x1006.

Quick stop (command, or 0x6007 = 3): the torque ramps from its last value to 0 at the torque slope
0x6087; 0x605A = 1…4: then SWITCH ON DISABLED (transition 12); 5…8: stay in QUICK STOP ACTIVE
(transition 16 possible); 0: disable drive function at once. The ramp advances per SYNC, so on SYNC
loss the quick stop drops the torque at once.

Over-torque: if |torque actual 0x6077| (the plant's measurement) exceeds max torque 0x6072 for longer
than 0x2000 [ms] while the drive applies torque, the drive faults with error code 0x8311 (excess
torque), sends EMCY 0x8311 and stops the torque (FAULT REACTION ACTIVE → FAULT).
"""
from __future__ import annotations

import enum
import logging
from pathlib import Path

from canopen import objectdictionary as od

from canopen.sdo import SdoAbortedError

from ..cia import (ABORT_LENGTH_HIGH, ABORT_VALUE_RANGE, CW_FAULT_RESET, EMCY_COMMUNICATION, EMCY_EXCESS_TORQUE, MODE_CSV,
                   MODE_CST, SW_FOLLOWS_COMMAND, SW_INTERNAL_LIMIT, SW_QUICK_STOP, SW_REMOTE,
                   SW_VOLTAGE_ENABLED)
from .drive_modes import HOMING_METHODS, SUPPORTED_MODES, DriveModes
from .lss import LssSlave
from .node301 import Node301

logger = logging.getLogger(__name__)

#: Bytes the user data object 0x2020 (DOMAIN, commissioning notes) holds.
USER_DATA_SIZE = 4096

# Statusword bits (CiA 402 §6, object 0x6041) beyond the state coding.

# 0x6007 abort connection option codes.
ABORT_NO_ACTION, ABORT_FAULT, ABORT_DISABLE_VOLTAGE, ABORT_QUICK_STOP = 0, 1, 2, 3
# 0x605A quick stop option codes that end in SWITCH ON DISABLED after the ramp (others stay).
_QUICK_STOP_THEN_DISABLE = (1, 2, 3, 4)


class PowerState(enum.Enum):
    """CiA 402 power states; the value is the state coding in statusword bits 0…3, 5, 6."""

    NOT_READY_TO_SWITCH_ON = 0x0000
    SWITCH_ON_DISABLED = 0x0040
    READY_TO_SWITCH_ON = 0x0021
    SWITCHED_ON = 0x0023
    OPERATION_ENABLED = 0x0027
    QUICK_STOP_ACTIVE = 0x0007
    FAULT_REACTION_ACTIVE = 0x000F
    FAULT = 0x0008

    @property
    def label(self) -> str:
        """Name as written in CiA 402 and canopen's ``BaseNode402.state`` ('OPERATION ENABLED')."""
        return self.name.replace("_", " ")


S = PowerState
_VOLTAGE_ON = {S.READY_TO_SWITCH_ON, S.SWITCHED_ON, S.OPERATION_ENABLED, S.QUICK_STOP_ACTIVE,
               S.FAULT_REACTION_ACTIVE}


class Command(enum.Enum):
    """Device control commands decoded from controlword bits 0…3 and 7 (CiA 402 §6)."""

    SHUTDOWN = "shutdown"                      # 0xxx x110
    SWITCH_ON = "switch on / disable operation"  # 0xxx 0111
    ENABLE_OPERATION = "enable operation"      # 0xxx 1111
    DISABLE_VOLTAGE = "disable voltage"        # 0xxx xx0x
    QUICK_STOP = "quick stop"                  # 0xxx x01x
    FAULT_RESET = "fault reset"                # bit 7 (rising edge acts)


def decode_controlword(controlword: int) -> Command:
    """Controlword (0x6040) → :class:`Command`."""
    if controlword & CW_FAULT_RESET:
        return Command.FAULT_RESET
    if not controlword & 0x02:
        return Command.DISABLE_VOLTAGE
    if not controlword & 0x04:
        return Command.QUICK_STOP
    if not controlword & 0x01:
        return Command.SHUTDOWN
    if not controlword & 0x08:
        return Command.SWITCH_ON
    return Command.ENABLE_OPERATION


# (state, command) → new state; the comment is the CiA 402 transition number.
_TRANSITIONS = {
    (S.SWITCH_ON_DISABLED, Command.SHUTDOWN): S.READY_TO_SWITCH_ON,            # 2
    (S.READY_TO_SWITCH_ON, Command.SWITCH_ON): S.SWITCHED_ON,                  # 3
    (S.READY_TO_SWITCH_ON, Command.ENABLE_OPERATION): S.OPERATION_ENABLED,     # 3 + 4
    (S.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,     # 7
    (S.READY_TO_SWITCH_ON, Command.QUICK_STOP): S.SWITCH_ON_DISABLED,          # 7
    (S.SWITCHED_ON, Command.ENABLE_OPERATION): S.OPERATION_ENABLED,            # 4
    (S.SWITCHED_ON, Command.SHUTDOWN): S.READY_TO_SWITCH_ON,                   # 6
    (S.SWITCHED_ON, Command.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,            # 10
    (S.SWITCHED_ON, Command.QUICK_STOP): S.SWITCH_ON_DISABLED,                 # 10
    (S.OPERATION_ENABLED, Command.SWITCH_ON): S.SWITCHED_ON,                   # 5
    (S.OPERATION_ENABLED, Command.SHUTDOWN): S.READY_TO_SWITCH_ON,             # 8
    (S.OPERATION_ENABLED, Command.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,      # 9
    (S.OPERATION_ENABLED, Command.QUICK_STOP): S.QUICK_STOP_ACTIVE,            # 11
    (S.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE): S.SWITCH_ON_DISABLED,      # 12
    (S.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION): S.OPERATION_ENABLED,      # 16 (0x605A = 5…8)
}


def _int16(x: int) -> int:
    return -32768 if x < -32768 else 32767 if x > 32767 else x


class Drive402(LssSlave, Node301):
    """A CiA 402 servo drive: CST and CSV here, PP, PV, HM and CSP in :mod:`.drive_modes`; an LSS slave.

    Args:
        node_id, eds, lock, sync_timeout: see :class:`qomni.hil.device.node301.Node301`.
        name: label for logs (e.g. the wheel 'fl').
    Attributes:
        state: current :class:`PowerState`.
        applied_torque: per mille of rated torque, the torque applied since the last SYNC.
    """

    def __init__(self, node_id, eds, *, lock=None, sync_timeout=0.1, name: str = ""):
        self.state = S.NOT_READY_TO_SWITCH_ON
        self.applied_torque = 0
        self.name = name or f"drive{node_id}"
        self._last_controlword = 0
        self._limited = False
        self._integral = 0.0          # CSV integral part, per mille
        self._over_torque_s = 0.0     # how long |0x6077| > 0x6072 has lasted
        super().__init__(node_id, eds, lock=lock, sync_timeout=sync_timeout)
        self.modes = DriveModes(self)
        if 0x1021 in self.object_dictionary and not isinstance(eds, od.ObjectDictionary):
            self._defaults[(0x1021, 0)] = self.values[(0x1021, 0)] = Path(eds).read_bytes()   # Store EDS
        self.on_reset_application()

    # ------------------------------------------------------------ values
    @property
    def rated_torque(self) -> float:
        """N m motor side, from 0x6076 (mN m)."""
        return self.values[(0x6076, 0)] * 1e-3

    @property
    def applied_torque_nm(self) -> float:
        """N m motor side applied since the last SYNC (0 unless OPERATION ENABLED)."""
        return self.applied_torque * self.values[(0x6076, 0)] * 1e-6

    def latch_torque(self) -> int:
        """SYNC phase 2: latch the target torque; returns the applied torque in per mille of rated.

        OPERATION ENABLED: CST / CSV law of the module docstring; QUICK STOP ACTIVE: the ramp to 0;
        else 0. Call with :attr:`lock` held, after :meth:`sync_receive`.
        """
        values = self.values
        state = self.state
        limited = False
        if state is S.OPERATION_ENABLED:
            mode, limit = values[(0x6061, 0)], values[(0x6072, 0)]
            if mode == MODE_CST:
                target = values[(0x6071, 0)]
            elif mode == MODE_CSV:
                target = self._velocity_control(limit)
            else:
                target = self.modes.torque(mode, limit)
            torque = -limit if target < -limit else limit if target > limit else target
            limited = torque != target
        elif state is S.QUICK_STOP_ACTIVE:
            torque = self._quick_stop_ramp()
        else:
            torque = 0
        self.applied_torque = torque
        if limited != self._limited:
            self._limited = limited
            self._update_statusword()
        return torque

    def _cycle_time(self) -> float:
        return (self.values.get((0x1006, 0)) or 2000) * 1e-6

    def _velocity_control(self, limit: int, demand: float | None = None) -> int:
        """Velocity loop: PI on 0x606C (sampled at the previous SYNC) → per mille; demand [inc/s] is 0x60FF
        (CSV) unless given (the position and profile modes)."""
        values = self.values
        error = (values[(0x60FF, 0)] if demand is None else demand) - values[(0x606C, 0)]
        kp = values.get((0x60F9, 1), 0) * 1e-3                 # per mille per increment/s
        ti = values.get((0x60F9, 2), 0) * 1e-3                 # s
        proportional = kp * error
        if ti > 0:
            integral = self._integral + proportional * self._cycle_time() / ti
            self._integral = max(-limit, min(limit, integral))
        return int(round(proportional + self._integral))

    def _quick_stop_ramp(self) -> int:
        """QUICK STOP ACTIVE: torque toward 0 at 0x6087 per mille/s; at 0, 0x605A = 1…4 → SWITCH ON DISABLED."""
        step = max(1, int(self.values.get((0x6087, 0), 0) * self._cycle_time()))
        torque = self.applied_torque
        torque = 0 if abs(torque) <= step else torque - step if torque > 0 else torque + step
        if torque == 0 and self.values.get((0x605A, 0), 2) in _QUICK_STOP_THEN_DISABLE:
            self._set_state(S.SWITCH_ON_DISABLED)                             # 12, automatic
        return torque

    def set_actuals(self, position: int, velocity: int, torque: float) -> None:
        """SYNC phase 2: the measured values the TPDOs will carry.

        Args:
            position: motor encoder increments, any int (plus the homing offset, wrapped to INTEGER32
                like the drive's counter).
            velocity: increments/s (saturated to INTEGER32).
            torque: N m motor side, torque actual; sent as per mille of 0x6076 (rounded, INTEGER16).
        """
        values = self.values
        position += self.modes.offset                     # homing: 0x6064 = encoder count + offset
        values[(0x6064, 0)] = ((position + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        values[(0x606C, 0)] = max(-0x80000000, min(0x7FFFFFFF, velocity))
        actual = values[(0x6077, 0)] = _int16(round(torque * 1e6 / values[(0x6076, 0)]))
        if self.applied_torque and abs(actual) > values[(0x6072, 0)]:
            self._over_torque_s += self._cycle_time()
            if self._over_torque_s * 1e3 > values.get((0x2000, 0), 0):
                self._over_torque_s = 0.0
                self._fault(EMCY_EXCESS_TORQUE)
                self.emcy_send(EMCY_EXCESS_TORQUE)
        else:
            self._over_torque_s = 0.0

    # ------------------------------------------------------------ hooks
    def validate_write(self, index, subindex, value):
        if index == 0x6060 and value not in SUPPORTED_MODES:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == 0x605A and not 0 <= value <= 8:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == 0x6007 and value not in (0, 1, 2, 3):
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == 0x6076 and value <= 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == 0x6098 and value not in HOMING_METHODS:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == 0x2020 and len(value) > USER_DATA_SIZE:
            raise SdoAbortedError(ABORT_LENGTH_HIGH)

    def on_write(self, index, subindex, value):
        if index == 0x6040:
            self._controlword(value)
            self.modes.controlword(value)
        elif index == 0x6060:
            self.values[(0x6061, 0)] = value
            self._integral = 0.0
            self.modes.restart()
            self._update_statusword()

    def on_reset_application(self):
        self.state = S.NOT_READY_TO_SWITCH_ON          # transition 0, self test
        self.applied_torque = 0
        self._last_controlword = self.values[(0x6040, 0)]
        self._limited = False
        self._integral = 0.0
        self._over_torque_s = 0.0
        self.values[(0x6061, 0)] = self.values[(0x6060, 0)]
        self.values[(0x603F, 0)] = 0
        self.modes = DriveModes(self)                  # homing offset and set-points lost
        self._set_state(S.SWITCH_ON_DISABLED)          # transition 1, automatic

    def on_power_off(self):
        self.applied_torque = 0
        self._set_state(S.NOT_READY_TO_SWITCH_ON)

    def on_leave_operational(self):
        if self.state is S.OPERATION_ENABLED:
            self._abort_connection(EMCY_COMMUNICATION)

    def on_communication_lost(self, emcy_code):
        self._abort_connection(emcy_code)

    # ---------------------------------------------------- state machine
    def _controlword(self, controlword: int) -> None:
        command = decode_controlword(controlword)
        rising = controlword & CW_FAULT_RESET and not self._last_controlword & CW_FAULT_RESET
        self._last_controlword = controlword
        if command is Command.FAULT_RESET:
            if self.state is S.FAULT and rising:                           # 15
                self.values[(0x603F, 0)] = 0
                self._set_state(S.SWITCH_ON_DISABLED)
            return
        new = _TRANSITIONS.get((self.state, command))
        if new is S.OPERATION_ENABLED and self.state is S.QUICK_STOP_ACTIVE and \
                self.values.get((0x605A, 0), 2) in _QUICK_STOP_THEN_DISABLE:
            return                                   # 16 only with 0x605A = 5…8
        if new is S.QUICK_STOP_ACTIVE:
            self._enter_quick_stop()
        elif new is not None:
            self._set_state(new)

    def _enter_quick_stop(self) -> None:
        if self.values.get((0x605A, 0), 2) == 0:                        # disable drive function
            self._set_state(S.SWITCH_ON_DISABLED)
            return
        torque = self.applied_torque
        self._set_state(S.QUICK_STOP_ACTIVE)
        self.applied_torque = torque                                    # the ramp starts here

    def _abort_connection(self, error_code: int) -> None:
        """Reaction to a connection loss per 0x6007 (only while voltage is enabled)."""
        if self.state not in _VOLTAGE_ON or self.state is S.FAULT_REACTION_ACTIVE:
            return
        option = self.values[(0x6007, 0)]
        if option == ABORT_FAULT:
            self._fault(error_code)
        elif option == ABORT_DISABLE_VOLTAGE:
            self._set_state(S.SWITCH_ON_DISABLED)
        elif option == ABORT_QUICK_STOP:
            # without SYNC the ramp cannot run: the torque drops at once
            self._set_state(S.QUICK_STOP_ACTIVE if self.state is S.OPERATION_ENABLED
                            else S.SWITCH_ON_DISABLED)
        logger.warning("%s (node %d): connection lost, 0x6007 = %d → %s",
                       self.name, self.id, option, self.state.label)

    def _fault(self, error_code: int) -> None:
        """Transitions 13 + 14: error code 0x603F, torque off, FAULT."""
        if self.state in (S.FAULT, S.FAULT_REACTION_ACTIVE):
            return
        self.values[(0x603F, 0)] = error_code
        self._set_state(S.FAULT_REACTION_ACTIVE)                           # 13
        self._set_state(S.FAULT)                                           # 14: torque off, done

    def _set_state(self, state: PowerState) -> None:
        if state is not self.state:
            logger.debug("%s (node %d): %s → %s", self.name, self.id, self.state.label, state.label)
            self.state = state
            if state is S.OPERATION_ENABLED:
                self._integral = 0.0
                self.modes.restart()
        if state is not S.OPERATION_ENABLED:
            self.applied_torque = 0
        self._update_statusword()

    def _update_statusword(self) -> None:
        state = self.state
        word = state.value | SW_REMOTE
        if state in _VOLTAGE_ON:
            word |= SW_VOLTAGE_ENABLED
        if state is S.SWITCH_ON_DISABLED:
            word |= SW_QUICK_STOP
        if state is S.OPERATION_ENABLED:
            if self.values[(0x6061, 0)] in (MODE_CST, MODE_CSV):
                word |= SW_FOLLOWS_COMMAND
            if self._limited:
                word |= SW_INTERNAL_LIMIT
        self.modes.bits = bits = self.modes.status_bits()
        word |= bits
        self.values[(0x6041, 0)] = word
