"""The vibration-table drive's use of the CiA 402 object dictionary: the one description of it that the driver and
the emulator share (config/eds/vibration_table_servo.eds is the drive's own).

Objects by index, the drive's units, controlword commands and statusword bits (CiA 402 device
control), mode values, the EMCY code of a lost master and the SDO abort codes the drive answers
bad values with. Controlword and mode go by RPDO 1; statusword, mode display, velocity and
position come by TPDO 1 and 2; parameters and targets by confirmed SDO (drivers.servo.driver).
"""

from __future__ import annotations

from canopen.profiles.p402 import State402

# ---------------------------------------------------------------- objects (index, sub-index 0)

ERROR_REGISTER = 0x1001  # CiA 301
HEARTBEAT_CONSUMER = 0x1016  # sub 1: (node id << 16) | consumer time in ms
HEARTBEAT_PRODUCER = 0x1017  # ms
ABORT_CONNECTION_OPTION_CODE = 0x6007  # what the drive does when the master is lost
ERROR_CODE = 0x603F
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
QUICK_STOP_OPTION_CODE = 0x605A
MODES_OF_OPERATION = 0x6060
MODES_OF_OPERATION_DISPLAY = 0x6061
POSITION_ACTUAL = 0x6064  # 1/65536 rev
VELOCITY_ACTUAL = 0x606C  # 1e-6 rev/s
MAX_PROFILE_VELOCITY = 0x607F
PROFILE_ACCELERATION = 0x6083  # 1e-6 rev/s^2
PROFILE_DECELERATION = 0x6084
QUICK_STOP_DECELERATION = 0x6085
TARGET_VELOCITY = 0x60FF  # 1e-6 rev/s
SUPPORTED_DRIVE_MODES = 0x6502

TPDO_OBJECTS = (STATUSWORD, MODES_OF_OPERATION_DISPLAY, VELOCITY_ACTUAL, POSITION_ACTUAL)
RPDO_OBJECTS = (CONTROLWORD, MODES_OF_OPERATION)

# ---------------------------------------------------------------- units and values

VELOCITY_UNIT_HZ = 1e-6  # 0x606C, 0x60FF: 1e-6 rev/s of the crank, i.e. uHz of the table
ACCEL_UNIT_HZ_PER_S = 1e-6  # 0x6083, 0x6084, 0x6085: 1e-6 rev/s^2
POSITION_UNITS_PER_REV = 65536  # 0x6064
MODE_PROFILE_VELOCITY = 3  # 0x6060 / 0x6061
SUPPORTED_MODE_PV_BIT = 0x04  # 0x6502 bit 2
EMCY_HEARTBEAT_ERROR = 0x8130  # EMCY code: heartbeat of the master lost (life guard error)

# controlword commands (CiA 402 device control)
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080  # its rising edge resets a fault

# statusword
SW_FAULT = 0x0008
SW_REMOTE = 0x0200
SW_TARGET_REACHED = 0x0400
SOD = "SWITCH ON DISABLED"
RTSO = "READY TO SWITCH ON"
SO = "SWITCHED ON"
OE = "OPERATION ENABLED"
QSA = "QUICK STOP ACTIVE"
FAULT = "FAULT"
STATE_STATUSWORD = {SOD: 0x0040, RTSO: 0x0031, SO: 0x0033, OE: 0x0037, QSA: 0x0017, FAULT: 0x0008}  # state bits

# SDO abort codes (CiA 301) for a value the drive does not take
SDO_ABORT_VALUE_INVALID = 0x06090030
SDO_ABORT_VALUE_TOO_HIGH = 0x06090031
SDO_ABORT_VALUE_TOO_LOW = 0x06090032


def state_of(statusword: int) -> str:
    """The 402 state name a statusword encodes."""
    for name, (mask, bits) in State402.SW_MASK.items():
        if statusword & mask == bits:
            return name
    return "UNKNOWN"
