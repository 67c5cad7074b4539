"""The one mapping from the cyclic interface to the PLCopen axis state.

The PLC clients (``MC_ReadStatus``, ``AXIS_REF.Status.MotionState``) and every
tool reading NCTOPLC call this one mapping, so they can never disagree. Tc2_MC2 does not publish its mapping; this is ours, checked in
order (first match wins):

==================================================  ===========================
condition on NCTOPLC                                MC_AxisStates
==================================================  ===========================
StateDWord.Error                                    ERRORSTOP
not StateDWord.ControlLoopClosed                    DISABLED
StateDWord.MotionCommandsLocked                     STOPPING (MC_Stop active)
HasBeenStopped and (HasJob or not NotMoving)       STOPPING (a stop ramp)
StateDWord.HomingBusy                               HOMING
CoupleState in (SLAVE, MASTERSLAVE)                 SYNCHRONIZEDMOTION
HasJob and ContinuousMotion                         CONTINOUSMOTION
HasJob, or not NotMoving                            DISCRETEMOTION (also a motion without a job: a
                                                    superposition on a standing axis, the NC's
                                                    brake ramp after MC_ExtSetPointGenDisable or
                                                    of the slaves of a disabled master)
otherwise                                           STANDSTILL
==================================================  ===========================

An axis that moves is never STANDSTILL.
"""
from __future__ import annotations

import numpy as np

from .codec import CoupleState, MC_AxisStates, StateDWord

_ERR = int(StateDWord.Error)
_CLC = int(StateDWord.ControlLoopClosed)
_LOCK = int(StateDWord.MotionCommandsLocked)
_NOT_MOVING = int(StateDWord.NotMoving)
_STOPPED = int(StateDWord.HasBeenStopped)
_JOB = int(StateDWord.HasJob)
_HOMING = int(StateDWord.HomingBusy)
_CONT = int(StateDWord.ContinuousMotion)
_SLAVE = (int(CoupleState.SLAVE), int(CoupleState.MASTERSLAVE))


def motion_state(state_dword: int, couple_state: int = 0) -> MC_AxisStates:
    """PLCopen state of one axis from its StateDWord and CoupleState."""
    s = int(state_dword)
    if s & _ERR:
        return MC_AxisStates.MC_AXISSTATE_ERRORSTOP
    if not s & _CLC:
        return MC_AxisStates.MC_AXISSTATE_DISABLED
    moving = not s & _NOT_MOVING
    if s & _LOCK or (s & _STOPPED and (s & _JOB or moving)):
        return MC_AxisStates.MC_AXISSTATE_STOPPING
    if s & _HOMING:
        return MC_AxisStates.MC_AXISSTATE_HOMING
    if int(couple_state) in _SLAVE:
        return MC_AxisStates.MC_AXISSTATE_SYNCHRONIZEDMOTION
    if s & _JOB or moving:
        if s & _CONT and s & _JOB:
            return MC_AxisStates.MC_AXISSTATE_CONTINOUSMOTION
        return MC_AxisStates.MC_AXISSTATE_DISCRETEMOTION
    return MC_AxisStates.MC_AXISSTATE_STANDSTILL


def motion_state_array(state_dword: np.ndarray, couple_state: np.ndarray | None = None) -> np.ndarray:
    """Vectorized :func:`motion_state` (int16 array, MC_AxisStates values)."""
    s = np.asarray(state_dword, dtype=np.uint32)
    cs = np.zeros_like(s) if couple_state is None else np.asarray(couple_state)
    job = (s & _JOB) != 0
    busy = job | ((s & _NOT_MOVING) == 0)
    conds = [
        (s & _ERR) != 0,
        (s & _CLC) == 0,
        ((s & _LOCK) != 0) | (((s & _STOPPED) != 0) & busy),
        (s & _HOMING) != 0,
        (cs == _SLAVE[0]) | (cs == _SLAVE[1]),
        job & ((s & _CONT) != 0),
        busy,
    ]
    choices = [int(MC_AxisStates.MC_AXISSTATE_ERRORSTOP), int(MC_AxisStates.MC_AXISSTATE_DISABLED),
               int(MC_AxisStates.MC_AXISSTATE_STOPPING), int(MC_AxisStates.MC_AXISSTATE_HOMING),
               int(MC_AxisStates.MC_AXISSTATE_SYNCHRONIZEDMOTION), int(MC_AxisStates.MC_AXISSTATE_CONTINOUSMOTION),
               int(MC_AxisStates.MC_AXISSTATE_DISCRETEMOTION)]
    return np.select(conds, choices, default=int(MC_AxisStates.MC_AXISSTATE_STANDSTILL)).astype(np.int16)


def cmdno_newer(a: int, b: int) -> bool:
    """True if command number ``a`` is newer than ``b`` (16-bit serial arithmetic).

    CmdNo runs 1..65535 and wraps to 1, so ``cmdno_newer(1, 65535)`` is True.
    """
    d = (int(a) - int(b)) & 0xFFFF
    return 0 < d < 0x8000


def next_cmdno(n: int) -> int:
    """The command number after ``n`` (skips 0, which means 'none')."""
    n = (int(n) + 1) & 0xFFFF
    return n or 1
