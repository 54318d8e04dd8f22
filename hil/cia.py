"""The CANopen object catalogue of the vehicle's network: every CiA 301/402/406 code the devices, the
client, the decoder and the DBC share, named once.

Object indices with their CiA names and device units, NMT commands and states, SDO abort codes, EMCY
codes, the CiA 402 controlword commands, statusword bits and modes of operation, and which objects the
master reads every cycle. Sources: CiA 301 (§7.2.4.3.17 SDO abort codes, §7.2.7.1 EMCY, §7.2.8 and
§7.3.2.2 NMT), CiA 402 (§6 objects, the state machine's controlword/statusword coding, 0x6060 modes),
CiA 406 (encoder objects). Units as fixed in docs/conventions.md ("CANopen mapping (hil)"); SI
conversion in :mod:`qomni.hil.units`. Standard library only.
"""
from __future__ import annotations

# --- objects: CiA 301 communication profile ----------------------------------------------------------
SYNC_COB_ID_OBJECT = 0x1005
COMMUNICATION_CYCLE_PERIOD = 0x1006         # µs
ERROR_REGISTER = 0x1001
PRE_DEFINED_ERROR_FIELD = 0x1003
CONSUMER_HEARTBEAT_TIME = 0x1016
SYNC_COUNTER_OVERFLOW = 0x1019       # 0: SYNC without data; 2…240: a 1-byte counter up to it
#: Largest synchronous counter overflow value 0x1019 (CiA 301 §7.5.2.20; 1 and 241…255 are reserved).
MAX_SYNC_COUNTER = 240

PRODUCER_HEARTBEAT_TIME = 0x1017

# --- objects: CiA 402 drive profile ------------------------------------------------------------------
ABORT_CONNECTION_OPTION = 0x6007
ERROR_CODE = 0x603F
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
QUICK_STOP_OPTION = 0x605A
MODES_OF_OPERATION = 0x6060
MODES_OF_OPERATION_DISPLAY = 0x6061
POSITION_ACTUAL = 0x6064                    # motor encoder increments
VELOCITY_ACTUAL = 0x606C                    # increments/s
TARGET_TORQUE = 0x6071                      # per mille of 0x6076
MAX_TORQUE = 0x6072                         # per mille of 0x6076
MOTOR_RATED_TORQUE = 0x6076                 # mN m, motor side
TORQUE_ACTUAL = 0x6077                      # per mille of 0x6076
TARGET_VELOCITY = 0x60FF                    # increments/s
SUPPORTED_DRIVE_MODES = 0x6502

# --- objects: CiA 406 encoder profile ----------------------------------------------------------------
MEASURING_UNITS_PER_REVOLUTION = 0x6001
POSITION_VALUE = 0x6004                     # measuring units

#: CiA 301/402/406 short names of the objects a PDO usually carries: (index, subindex) → name.
OBJECT_NAMES: dict[tuple[int, int], str] = {
    (ERROR_REGISTER, 0): "error_register",
    (ERROR_CODE, 0): "error_code",
    (CONTROLWORD, 0): "controlword",
    (STATUSWORD, 0): "statusword",
    (MODES_OF_OPERATION, 0): "modes_of_operation",
    (MODES_OF_OPERATION_DISPLAY, 0): "modes_of_operation_display",
    (0x6062, 0): "position_demand",
    (0x6063, 0): "position_actual_internal",
    (POSITION_ACTUAL, 0): "position_actual",
    (0x606B, 0): "velocity_demand",
    (VELOCITY_ACTUAL, 0): "velocity_actual",
    (TARGET_TORQUE, 0): "target_torque",
    (MAX_TORQUE, 0): "max_torque",
    (0x6074, 0): "torque_demand",
    (TORQUE_ACTUAL, 0): "torque_actual",
    (0x6078, 0): "current_actual",
    (0x607A, 0): "target_position",
    (0x6081, 0): "profile_velocity",
    (0x60F4, 0): "following_error_actual",
    (0x60B2, 0): "torque_offset",
    (TARGET_VELOCITY, 0): "target_velocity",
    (POSITION_VALUE, 0): "position_value",
    (0x6030, 1): "speed_value",
}
#: Device units of mapped objects (CiA 402 §6 as fixed in docs/conventions.md; CiA 406).
OBJECT_UNITS: dict[tuple[int, int], str] = {
    (TARGET_TORQUE, 0): "permille", (MAX_TORQUE, 0): "permille", (0x6074, 0): "permille",
    (TORQUE_ACTUAL, 0): "permille", (0x60B2, 0): "permille", (0x6078, 0): "permille",
    (0x6062, 0): "inc", (0x6063, 0): "inc", (POSITION_ACTUAL, 0): "inc", (0x607A, 0): "inc",
    (0x60F4, 0): "inc", (0x6081, 0): "inc/s",
    (0x606B, 0): "inc/s", (VELOCITY_ACTUAL, 0): "inc/s", (TARGET_VELOCITY, 0): "inc/s",
    (POSITION_VALUE, 0): "counts",
}

#: What the master reads from each drive's synchronous TPDOs every cycle: (index, subindex) → field.
MEASURED_DRIVE_OBJECTS: dict[tuple[int, int], str] = {
    (STATUSWORD, 0): "status", (POSITION_ACTUAL, 0): "position", (VELOCITY_ACTUAL, 0): "velocity",
    (TORQUE_ACTUAL, 0): "torque"}
#: What the master reads from each steering encoder's synchronous TPDO every cycle.
MEASURED_ENCODER_OBJECTS: dict[tuple[int, int], str] = {(POSITION_VALUE, 0): "counts"}

#: COB-ID bits of the PDO/EMCY communication objects (CiA 301 §7.5.2.35/36): 31 = not valid, 29 = 29-bit ID.
COB_ID_INVALID = 1 << 31
COB_ID_EXTENDED = 1 << 29

# --- NMT (CiA 301 §7.2.8, §7.3.2.2) ------------------------------------------------------------------
INITIALISING, STOPPED, OPERATIONAL, PRE_OPERATIONAL = 0, 4, 5, 127
NMT_START, NMT_STOP, NMT_PRE_OPERATIONAL, NMT_RESET_NODE, NMT_RESET_COMMUNICATION = 1, 2, 128, 129, 130
NMT_COMMAND_NAMES = {NMT_START: "start", NMT_STOP: "stop", NMT_PRE_OPERATIONAL: "enter pre-operational",
                     NMT_RESET_NODE: "reset node", NMT_RESET_COMMUNICATION: "reset communication"}
NMT_STATE_NAMES = {INITIALISING: "boot-up", STOPPED: "stopped", OPERATIONAL: "operational",
                   PRE_OPERATIONAL: "pre-operational"}

# --- SDO abort codes (CiA 301 §7.2.4.3.17) -----------------------------------------------------------
ABORT_COMMAND_SPECIFIER = 0x05040001
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_OBJECT_MISSING = 0x06020000
ABORT_CANNOT_MAP = 0x06040041          # object cannot be mapped to the PDO
ABORT_PDO_LENGTH = 0x06040042          # number and length of mapped objects exceed the PDO length
ABORT_LENGTH = 0x06070010
ABORT_LENGTH_HIGH = 0x06070012
ABORT_LENGTH_LOW = 0x06070013
ABORT_SUBINDEX_MISSING = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_DEVICE_STATE = 0x08000022      # not in the present device state
ABORT_NO_DATA = 0x08000024

# --- EMCY error codes (CiA 301 §7.2.7.1, CiA 402) and error register bits (0x1001) -------------------
EMCY_NO_ERROR = 0x0000
EMCY_COMMUNICATION = 0x8100
EMCY_HEARTBEAT = 0x8130              # life guard / heartbeat error
EMCY_BUS_OFF = 0x8140                # recovered from bus off
EMCY_PDO_LENGTH = 0x8210
EMCY_SYNC_LENGTH = 0x8240
EMCY_RPDO_TIMEOUT = 0x8250
EMCY_EXCESS_TORQUE = 0x8311          # CiA 402 "excess torque"
ERROR_REGISTER_GENERIC = 0x01
ERROR_REGISTER_COMMUNICATION = 0x10

# --- CiA 402: controlword commands, statusword, modes of operation --------------------------------------
CW_SHUTDOWN = 0x0006
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080
#: Statusword state coding: (statusword & SW_STATE_MASK) == SW_OPERATION_ENABLED in OPERATION ENABLED.
SW_STATE_MASK, SW_OPERATION_ENABLED = 0x6F, 0x27
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5                         # 1 = quick stop NOT active
SW_REMOTE = 1 << 9
SW_INTERNAL_LIMIT = 1 << 11                    # target torque clipped by 0x6072
SW_TARGET_REACHED = 1 << 10                    # PP/PV: target reached; HM: with 12/13 the homing status
SW_FOLLOWS_COMMAND = 1 << 12                   # CSP/CSV/CST: drive follows the command value
SW_SETPOINT_ACK = 1 << 12                      # PP: set-point acknowledge; PV: speed 0; HM: homing attained
SW_FOLLOWING_ERROR = 1 << 13                   # CSP/PP: following error; HM: homing error

MODE_NONE = 0
MODE_PP = 1                                    # profile position
MODE_PV = 3                                    # profile velocity
MODE_HOMING = 6
MODE_CSP = 8                                   # cyclic synchronous position
MODE_CSV = 9                                   # cyclic synchronous velocity
MODE_CST = 10                                  # cyclic synchronous torque
MODE_NAMES = {0: "no mode", 1: "profile position", 3: "profile velocity", 4: "profile torque", 6: "homing",
              7: "interpolated position", 8: "cyclic synchronous position",
              9: "cyclic synchronous velocity", 10: "cyclic synchronous torque"}


def supported_mode_bit(mode: int) -> int:
    """Bit of a mode of operation in 0x6502 (CiA 402: bits 0–9 for modes 1–10; CST is bit 9)."""
    if not 1 <= mode <= 10:
        raise ValueError(f"mode {mode} has no bit in 0x6502")
    return 1 << (mode - 1)


def valid_sync_counter(value: int) -> bool:
    """Whether ``value`` is a synchronous counter overflow value 0x1019 CiA 301 allows: 0 (no counter)
    or 2…:data:`MAX_SYNC_COUNTER`."""
    return value == 0 or 2 <= value <= MAX_SYNC_COUNTER
