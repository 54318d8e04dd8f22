"""CiA 402 wheel drive node: power state machine and cyclic synchronous torque mode (CST, 0x6060 = 10).

Source: CiA 402-2 (IEC 61800-7-201) §6 "device control" (state machine, controlword 0x6040 command
coding, statusword 0x6041 state coding, abort connection option 0x6007) and the CST mode objects
0x6071 target torque, 0x6072 max torque, 0x6076 motor rated torque, 0x6077 torque actual value,
plus 0x6064 position actual and 0x606C velocity actual. Units: docs/conventions.md.

Timing (lock-step, see ``hil.server``): at each SYNC the drive applies the RPDOs received since the last
SYNC (controlword first takes effect here), latches the target torque, and the torque it applies
from this instant is ``clip(0x6071, ±0x6072)`` in OPERATION ENABLED with mode 10, else 0.
"""
from __future__ import annotations

import enum
import logging

from canopen.sdo import SdoAbortedError

from .node301 import ABORT_VALUE_RANGE, EMCY_COMMUNICATION, Node301

logger = logging.getLogger(__name__)

MODE_NONE = 0
MODE_CST = 10                                  # cyclic synchronous torque
SUPPORTED_MODES = (MODE_NONE, MODE_CST)

# Statusword bits (CiA 402 §6, object 0x6041) beyond the state coding.
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5                         # 1 = quick stop NOT active
SW_REMOTE = 1 << 9
SW_INTERNAL_LIMIT = 1 << 11                    # target torque clipped by 0x6072
SW_FOLLOWS_COMMAND = 1 << 12                   # CST: drive follows the command value
CW_FAULT_RESET = 1 << 7

# 0x6007 abort connection option codes.
ABORT_NO_ACTION, ABORT_FAULT, ABORT_DISABLE_VOLTAGE, ABORT_QUICK_STOP = 0, 1, 2, 3


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
    (S.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION): S.OPERATION_ENABLED,      # 16
}


def _int16(x: int) -> int:
    return -32768 if x < -32768 else 32767 if x > 32767 else x


class Drive402(Node301):
    """A CiA 402 servo drive supporting only cyclic synchronous torque mode.

    Args:
        node_id, eds, lock, sync_timeout: see :class:`hil.node301.Node301`.
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
        super().__init__(node_id, eds, lock=lock, sync_timeout=sync_timeout)
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

        Applied = clip(0x6071, ±0x6072) in OPERATION ENABLED with mode display 10, else 0.
        Call with :attr:`lock` held, after :meth:`sync_receive`.
        """
        values = self.values
        if self.state is S.OPERATION_ENABLED and values[(0x6061, 0)] == MODE_CST:
            target, limit = values[(0x6071, 0)], values[(0x6072, 0)]
            torque = -limit if target < -limit else limit if target > limit else target
            limited = torque != target
        else:
            torque, limited = 0, False
        self.applied_torque = torque
        if limited != self._limited:
            self._limited = limited
            self._update_statusword()
        return torque

    def set_actuals(self, position: int, velocity: int, torque: float) -> None:
        """SYNC phase 2: the measured values the TPDOs will carry.

        Args:
            position: motor encoder increments, any int (wrapped to INTEGER32 like the drive's counter).
            velocity: increments/s (saturated to INTEGER32).
            torque: N m motor side, torque actual; sent as per mille of 0x6076 (rounded, INTEGER16).
        """
        values = self.values
        values[(0x6064, 0)] = ((position + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        values[(0x606C, 0)] = max(-0x80000000, min(0x7FFFFFFF, velocity))
        values[(0x6077, 0)] = _int16(round(torque * 1e6 / values[(0x6076, 0)]))

    # ------------------------------------------------------------ hooks
    def validate_write(self, index, subindex, value):
        if index == 0x6060 and value not in SUPPORTED_MODES:
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == 0x6007 and value not in (0, 1, 2, 3):
            raise SdoAbortedError(ABORT_VALUE_RANGE)
        if index == 0x6076 and value <= 0:
            raise SdoAbortedError(ABORT_VALUE_RANGE)

    def on_write(self, index, subindex, value):
        if index == 0x6040:
            self._controlword(value)
        elif index == 0x6060:
            self.values[(0x6061, 0)] = value
            self._update_statusword()

    def on_reset_application(self):
        self.state = S.NOT_READY_TO_SWITCH_ON          # transition 0, self test
        self.applied_torque = 0
        self._last_controlword = self.values[(0x6040, 0)]
        self._limited = False
        self.values[(0x6061, 0)] = self.values[(0x6060, 0)]
        self.values[(0x603F, 0)] = 0
        self._set_state(S.SWITCH_ON_DISABLED)          # transition 1, automatic

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
        if new is not None:
            self._set_state(new)

    def _abort_connection(self, error_code: int) -> None:
        """Reaction to a connection loss per 0x6007 (only while voltage is enabled)."""
        if self.state not in _VOLTAGE_ON or self.state is S.FAULT_REACTION_ACTIVE:
            return
        option = self.values[(0x6007, 0)]
        if option == ABORT_FAULT:
            self.values[(0x603F, 0)] = error_code
            self._set_state(S.FAULT_REACTION_ACTIVE)                       # 13
            self._set_state(S.FAULT)                                       # 14: torque off, done
        elif option == ABORT_DISABLE_VOLTAGE:
            self._set_state(S.SWITCH_ON_DISABLED)
        elif option == ABORT_QUICK_STOP:
            self._set_state(S.QUICK_STOP_ACTIVE if self.state is S.OPERATION_ENABLED
                            else S.SWITCH_ON_DISABLED)
        logger.warning("%s (node %d): connection lost, 0x6007 = %d → %s",
                       self.name, self.id, option, self.state.label)

    def _set_state(self, state: PowerState) -> None:
        if state is not self.state:
            logger.debug("%s (node %d): %s → %s", self.name, self.id, self.state.label, state.label)
            self.state = state
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
            if self.values[(0x6061, 0)] == MODE_CST:
                word |= SW_FOLLOWS_COMMAND
            if self._limited:
                word |= SW_INTERNAL_LIMIT
        self.values[(0x6041, 0)] = word
