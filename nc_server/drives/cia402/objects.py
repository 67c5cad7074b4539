"""CiA 402 object dictionary entries the NC uses, and the bits of controlword and statusword.

Sources: CiA 402-2 (IEC 61800-7-201) as summarised in python-canopen's ``canopen.profiles.p402`` and the
Beckhoff AX5000/EL72x1 CoE documentation. Positions are in the drive's increments, velocities in increments/s
(the drive's velocity unit is configured so), torque in per mille of the rated torque (0x6077).
"""
from __future__ import annotations

from enum import IntEnum

ERROR_CODE = 0x603F            # UINT16: the drive's last error (CiA 301 EMCY code), 0 = none
CONTROLWORD = 0x6040           # UINT16
STATUSWORD = 0x6041            # UINT16
QUICK_STOP_OPTION = 0x605A     # INT16
MODES_OF_OPERATION = 0x6060    # INT8
MODES_OF_OPERATION_DISPLAY = 0x6061  # INT8
POSITION_ACTUAL = 0x6064       # INT32 [inc]
VELOCITY_ACTUAL = 0x606C       # INT32 [inc/s]
TORQUE_ACTUAL = 0x6077         # INT16 [per mille of rated torque]
TARGET_POSITION = 0x607A       # INT32 [inc]
QUICK_STOP_DECELERATION = 0x6085  # UINT32 [inc/s^2]
TOUCH_PROBE_FUNCTION = 0x60B8  # UINT16
TOUCH_PROBE_STATUS = 0x60B9    # UINT16
TOUCH_PROBE_POS1_POS = 0x60BA  # INT32 [inc]: probe 1, positive (rising) edge
TOUCH_PROBE_POS2_POS = 0x60BC  # INT32 [inc]: probe 2, positive (rising) edge
TOUCH_PROBE_POS2_NEG = 0x60BD  # INT32 [inc]: probe 2, negative (falling) edge
INTERPOLATION_TIME_PERIOD = 0x60C2  # RECORD: sub 1 value (UINT8), sub 2 index (INT8): period = value * 10^index s
TARGET_VELOCITY = 0x60FF       # INT32 [inc/s]
SUPPORTED_DRIVE_MODES = 0x6502  # UINT32


class Mode(IntEnum):
    """Modes of operation (0x6060 / 0x6061) the NC uses."""

    HOMING = 6
    CSP = 8   # cyclic synchronous position: the NC's default
    CSV = 9   # cyclic synchronous velocity


class CW(IntEnum):
    """Controlword bits (0x6040)."""

    SWITCH_ON = 1 << 0
    ENABLE_VOLTAGE = 1 << 1
    QUICK_STOP = 1 << 2      # low active: 0 = quick stop
    ENABLE_OPERATION = 1 << 3
    FAULT_RESET = 1 << 7     # on its rising edge
    HALT = 1 << 8


#: The device control commands (CiA 402 table "Command coding"), as full controlwords.
CMD_SHUTDOWN = 0x0006
CMD_SWITCH_ON = 0x0007
CMD_DISABLE_VOLTAGE = 0x0000
CMD_QUICK_STOP = 0x0002
CMD_DISABLE_OPERATION = 0x0007
CMD_ENABLE_OPERATION = 0x000F
CMD_FAULT_RESET = 0x0080


class SW(IntEnum):
    """Statusword bits (0x6041)."""

    READY_TO_SWITCH_ON = 1 << 0
    SWITCHED_ON = 1 << 1
    OPERATION_ENABLED = 1 << 2
    FAULT = 1 << 3
    VOLTAGE_ENABLED = 1 << 4
    QUICK_STOP = 1 << 5      # low active: 0 = quick stop active
    SWITCH_ON_DISABLED = 1 << 6
    WARNING = 1 << 7
    REMOTE = 1 << 9
    TARGET_REACHED = 1 << 10
    INTERNAL_LIMIT = 1 << 11
    DRIVE_FOLLOWS = 1 << 12  # CSP/CSV: the drive follows the command value


class State(IntEnum):
    """The power states (the ``state`` arrays hold these values)."""

    NOT_READY_TO_SWITCH_ON = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7
