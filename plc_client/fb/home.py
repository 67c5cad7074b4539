"""MC_Home: homing (referencing, calibration) of an axis (TcMC manual 3.14; Tc2_MC2 MC_Home: inputs
HomingMode and BufferMode, outputs Busy, Active, CommandAborted).

Inputs: Execute, Position [u] (default ``nc_schema.DEFAULT_HOME_POSITION``: the NC uses the axis
parameter AxisCalibrationValue instead), HomingMode (``nc_schema.MC_HomingMode``, default
MC_DefaultHoming), BufferMode (``MC_BufferMode``), bCalibrationCam (BOOL, the reference cam).
Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.

The sequence is the NC's (``Home`` in ``schema/protocol.json``): towards the cam, off the cam to
the drive's sync pulse, stop, set the actual position; ``NcToPlc.HomingState`` shows the phase
(1..6, 0 = ready) and StateDWord.HomingBusy is set meanwhile (PLCopen state Homing). The block
sends ``Home`` {Position, HomingMode, BufferMode} on the rising edge of Execute and follows it like
every motion command (``MotionBlock``): Busy/Active while the job runs, CommandAborted if another
command ends it (MC_Stop, ...), Error with the NC's code - e.g. 0x4B01 on a moving axis, 0x4223
on one without enable (the NC decides the code).

Done (zenoh-nc choice; the manual: "TRUE once referencing is complete"): the NC ended the job
DONE (CmdState DONE, HasJob fell), HomingState is back to 0 (READY) and - except with
MC_ResetCalibration, which clears it - StateDWord.Homed is set. If the job ended DONE but the
last two do not hold within 6 s (``DONE_WINDOW_TIMEOUT``): Error 0x4B0A (MC_HOMING_ERROR).
There is no target window to wait for: the axis stands where its stop ramp ended (the Tc2_MC2
note: "the standstill position deviates by the braking distance ... the calibration is exact").

**The cam signal (bCalibrationCam)** travels in the cyclic PLC->NC interface: every call writes
it into ``Axis.PlcToNc["ControlDWord"]`` bit ``ControlDWord.HomingSensor`` (also while the block
is idle, so the NC knows whether the search starts on the cam). That record is published only
for an axis this PLC controls, i.e. one that an ``MC_Power`` of this PLC task drives (it holds
the NC's claim): the NC applies only the claim holder's PLCTONC. From another PLC the cam has no
effect, and homing waits for a cam edge that never comes. The bit keeps the value of the last
call while the block is not called. The command and the cam travel separately - the command as
a request sent during the cycle, the cam with the PLCTONC frame sent at its end - so a cam that is
already occupied when homing starts should be TRUE before the Execute edge (the NC reads it
again a cycle after the command, but a frame can take longer over the network).

**Homing without a reference cam** (TcMC 3.14 note): only the sync pulse of the encoder is
wanted, so the program simulates the cam - bCalibrationCam TRUE when the command starts, then
FALSE once ``Axis.NcToPlc["HomingState"] >= 4`` (WAIT_CAM_FALLING): the NC then looks for the
next sync pulse::

    cam = home.Busy and int(X.NcToPlc["HomingState"]) < 4
    home(Axis=X, Execute=start, bCalibrationCam=cam if home.Busy else True)

(``examples/06_home_and_jog.py`` runs this.)

Other inputs: HomingMode must be an integer (else Error 0x4B04, nothing sent); which modes the
NC supports is the NC's answer (the protocol lists 0 MC_DefaultHoming, 4 MC_Direct,
7 MC_ForceCalibration, 8 MC_ResetCalibration; zenoh-nc's NC refuses the others with 0x4B04, the
modes Tc2_MC2 does not implement either). BufferMode is checked and sent like every motion
block's BufferMode (``MotionBlock``; Tc2_MC2 says "currently not implemented", zenoh-nc's NC
accepts MC_Aborting and MC_Buffered for a Home). Tc2_MC2's ``Options`` (ST_HomingOptions) is not
offered: the wire contract has no field for it.
"""
from __future__ import annotations

import numbers
from typing import Any, ClassVar

import numpy as np

from nc_schema import DEFAULT_HOME_POSITION, ControlDWord, ErrorCodes, HomingState, MC_HomingMode, StateDWord

from .motion import DONE_WINDOW_TIMEOUT, MotionBlock

_CAM = int(ControlDWord.HomingSensor)
_HASJOB = int(StateDWord.HasJob)
_HOMED = int(StateDWord.Homed)
_READY = int(HomingState.READY)
_RESET_CAL = int(MC_HomingMode.MC_ResetCalibration)


def _int_input(v: Any) -> int | None:
    """An INT input as int; None for a bool or a non-integer."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        return None
    return int(v)


class MC_Home(MotionBlock):
    """Homing (TcMC 3.14 / Tc2_MC2); see the module docstring for the cam and the Done rule.

    Inputs: Execute, Position [u] (DEFAULT_HOME_POSITION), HomingMode (MC_DefaultHoming),
    BufferMode (MC_Aborting), bCalibrationCam.
    Outputs: Done, Busy, Active, CommandAborted, Error, ErrorID.
    """

    CMD = "Home"
    _INPUTS: ClassVar[dict[str, Any]] = {
        "Execute": False, "Position": DEFAULT_HOME_POSITION, "HomingMode": int(MC_HomingMode.MC_DefaultHoming),
        "BufferMode": 0, "bCalibrationCam": False,
    }
    Position: float
    HomingMode: int
    BufferMode: int
    bCalibrationCam: bool
    _REALS = ("Position",)
    _END = "standstill"

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._homing_mode = 0

    def _cycle(self) -> None:
        self._write_cam()
        super()._cycle()

    def _write_cam(self) -> None:
        ax = self.Axis
        if ax is None:
            return
        self._task()  # bind the axis to the running task (its PLCTONC is published if controlled)
        cdw = int(ax.PlcToNc["ControlDWord"])
        ax.PlcToNc["ControlDWord"] = (cdw | _CAM) if self.bCalibrationCam else (cdw & ~_CAM)

    def _start(self) -> None:
        mode = _int_input(self.HomingMode)
        if mode is None:
            self._finish("Error", ErrorCodes.MC_INVALID_MODE)
            return
        self._homing_mode = mode
        super()._start()

    def _args(self) -> dict[str, Any] | None:
        a = super()._args()  # Position and BufferMode, checked as every motion block checks them
        if a is None:
            return None
        a["HomingMode"] = self._homing_mode
        if "BufferMode" not in a:
            bm = _int_input(self.BufferMode)
            a["BufferMode"] = -1 if bm is None else bm
        return a

    def _on_done(self, rec: Any, sdw: int) -> None:
        if sdw & _HASJOB:
            return
        ready = int(rec["HomingState"]) == _READY
        homed_ok = self._homing_mode == _RESET_CAL or bool(sdw & _HOMED)
        if ready and homed_ok:
            self._finish("Done")
            return
        ax = self.Axis
        assert ax is not None and ax._task is not None  # (_follow: bound, valid data)
        now = ax._task.now
        if self._done_since is None:
            self._done_since = now
        elif now - self._done_since >= DONE_WINDOW_TIMEOUT:
            self._finish("Error", ErrorCodes.MC_HOMING_ERROR)
