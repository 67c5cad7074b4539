"""Superimposed motion: MC_MoveSuperImposed, MC_MoveSuperImposedExt, MC_AbortSuperposition
(TcMC manual 3.9-3.12, E_SuperpositionMode 6.5).

A superimposed motion is added to whatever moves the axis (its own command, a coupling, the
external set-point generator, or standstill). The ``MoveSuperImposed`` request goes to the
axis's own key with {Mode, Distance, VelocityDiff, Acceleration, Deceleration, VelocityProcess,
Length}; the reply's CmdNo is the superposition's own number, which is **not**
the axis's ActiveCmdNo but its superposition slot in the job record: ``NCJOBS.SuperCmdNo`` /
``SuperState`` / ``SuperErrorId``. The reply's Value is {ActualDistance, ActualVelocityDiff,
ActualLength}.

Following (from the first frame of the reply's NC cycle on):

* SuperCmdNo is ours: ACTIVE -> Busy; DONE -> Done; ABORTED (MC_AbortSuperposition, MC_Stop, an
  error of the axis, ...) -> CommandAborted; ERROR -> Error with ErrorID = SuperErrorId
  (NcToPlc.ErrorCode if that is 0);
* SuperCmdNo is newer than ours (16-bit serial arithmetic) while ours had not ended: a newer
  superposition took over (the NC ends the old one ABORTED) -> CommandAborted;
* SuperCmdNo older than ours, or a frame without job records: Error 0x4B60 (the NC lost it /
  cannot show it).

**Error 0x4243** (compensation incomplete) arrives this way at the end of a correction that did
not fit the parameters (Distance, VelocityDiff, Length, Mode): the block ends with Error 0x4243
although the motion was applied as far as possible (ActualDistance). TcMC leaves it to the user
whether to treat it as an error or merely as a warning; the block reports it as Error, as TcMC
does.

MC_MoveSuperImposed is MC_MoveSuperImposedExt with Mode 4
(SUPERPOSITIONMODE_LENGTHREDUCTION_LIMITEDMOTION) and Length = MaxDistance: TcMC describes
MaxDistance as the distance over which the catching up *may* occur, i.e. an upper limit of the
correction's length, which is what the LENGTHREDUCTION modes do (as short as possible, never
longer than Length), on the axis's own travel (LIMITEDMOTION).

Outputs are TcMC's (Done, Busy, CommandAborted, Error, ErrorID; Ext adds ActualVelocityDiff,
ActualDistance, ActualLength). The general rules hold (inputs latched at the edge, results held
while Execute stays TRUE, one cycle if it fell earlier, a rising edge while Busy ignored). The
Actual* values are the NC's answer (the reply's Value; the NCJOBS Super* values of the first
frame showing the superposition if the reply had none); they are cleared by the next rising edge
only, so they can still be read after Execute fell.

Jerk: TcMC 3.9/3.10 "the jerk value is not used": the input exists (TcMC declares it) but the
block neither checks nor sends it; the NC limits the superimposed part with AxisJerk.

VelocityProcess [u/s]: the mean process velocity, |value| > 0 (TcMC). Its default is 0 as in the
TcMC declaration, which the NC refuses with 0x4B06: a program must set it (e.g. the axis's or the
master's velocity during the correction). With Length it gives the correction's time window.

Input checks, nothing sent on failure: a value that is not a finite number -> Error 0x4B06; a
Mode that is not an integer 1..4 -> 0x4B04. The NC checks the rest (Distance 0, VelocityDiff,
Length or VelocityProcess not > 0, ...).

MC_AbortSuperposition sends ``AbortSuperposition`` and is Done once the NC accepted it and a
frame of the reply's cycle arrived (the superimposed part brakes to its standstill; the running
superposition then ends ABORTED, so its block reports CommandAborted). Nothing running: Done.
"""
from __future__ import annotations

from typing import Any, ClassVar

from nc_schema import CmdState, E_SuperpositionMode, ErrorCodes

from .base import ExecuteBlock
from .coupling import _integer_in


_LENGTHREDUCTION_LIMITED = int(E_SuperpositionMode["SUPERPOSITIONMODE_LENGTHREDUCTION_LIMITEDMOTION"])
_DONE, _ABORTED, _ERROR = int(CmdState.DONE), int(CmdState.ABORTED), int(CmdState.ERROR)
#: reply Value key -> output; NCJOBS field of the same value
_ACTUALS = {"ActualDistance": "SuperDistance", "ActualVelocityDiff": "SuperVelocityDiff",
            "ActualLength": "SuperLength"}


class _SuperBlock(ExecuteBlock):
    """Send MoveSuperImposed and follow the axis's superposition slot (see the module docstring)."""

    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "Busy": False, "CommandAborted": False, "Error": False,
                                          "ErrorID": 0}
    #: the real inputs checked and sent (not Jerk: TcMC does not use it)
    _REALS: ClassVar[tuple[str, ...]] = ("Distance", "VelocityDiff", "Acceleration", "Deceleration",
                                         "VelocityProcess")
    #: the block has the Actual* outputs (MC_MoveSuperImposedExt)
    _ACTUAL_OUTPUTS: ClassVar[bool] = False

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._super_no = 0
        self._super_cycle = 0
        self._actuals_known = False

    def _mode_and_length(self) -> tuple[int, Any] | None:
        """(Mode, Length input value); None (after finishing with Error) if Mode is invalid."""
        raise NotImplementedError  # pragma: no cover

    def _start(self) -> None:
        self._super_no, self._super_cycle, self._actuals_known = 0, 0, False
        if self._ACTUAL_OUTPUTS:
            for out in _ACTUALS:
                setattr(self, out, 0.0)
        ml = self._mode_and_length()
        if ml is None:
            return
        mode, length = ml
        if not self._check_inputs(self._REALS, buffer_mode=False):
            return
        if not self._is_real(length):
            self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        args = {k: float(getattr(self, k)) for k in self._REALS}
        self._send("MoveSuperImposed", Mode=mode, Length=float(length), **args)

    def _progress(self) -> None:
        if not self._super_no:
            got = self._accepted()
            if got is None:
                return
            self._super_no, self._super_cycle, reply = got
            self._take_actuals(reply.get("Value"))
        self._follow()

    def _on_axis_lost(self, ax: Any, task: Any) -> None:
        if self._super_no:
            task.lost_command(ax, self._super_no, "MoveSuperImposed", max(self._super_cycle, ax.Status.NcCycleCounter))

    def _take_actuals(self, value: Any) -> None:
        if not self._ACTUAL_OUTPUTS or not isinstance(value, dict):
            return
        vals: dict[str, Any] = {k: value.get(k) for k in _ACTUALS}
        if all(self._is_real(v) for v in vals.values()):
            for k, v in vals.items():
                setattr(self, k, float(v))
            self._actuals_known = True

    def _follow(self) -> None:
        got = self._own_slot("SuperCmdNo", "SuperState", self._super_no, self._super_cycle)
        if got is None:
            return
        state, jobs = got
        if self._ACTUAL_OUTPUTS and not self._actuals_known:
            for out, field in _ACTUALS.items():
                setattr(self, out, float(jobs[field]))
            self._actuals_known = True
        if state == _DONE:
            self._finish("Done")
        elif state == _ABORTED:
            self._finish("CommandAborted")
        elif state == _ERROR:
            assert self.Axis is not None  # (_own_slot checked it)
            self._finish("Error", int(jobs["SuperErrorId"]) or int(self.Axis.NcToPlc["ErrorCode"]))
        # ACTIVE (or not yet ACTIVE): Busy

    def _reset_outputs(self) -> None:
        # the Actual* values survive the falling edge (cleared by the next start)
        keep = {k: getattr(self, k, 0.0) for k in _ACTUALS} if self._ACTUAL_OUTPUTS else {}
        super()._reset_outputs()
        self.__dict__.update(keep)


_DYN = {"Acceleration": 0.0, "Deceleration": 0.0, "Jerk": 0.0}


class MC_MoveSuperImposed(_SuperBlock):
    """Superimposed relative motion (TcMC 3.9): Mode 4 LENGTHREDUCTION_LIMITEDMOTION, Length = MaxDistance.

    Inputs: Execute, Distance [u] (<> 0), VelocityDiff [u/s] (|.| > 0), Acceleration,
    Deceleration [u/s^2] (0 = axis default), Jerk (not used: AxisJerk; neither checked nor sent),
    VelocityProcess [u/s] (|.| > 0, the mean process velocity; 0 is refused by the NC with
    0x4B06), MaxDistance [u] (|.| > 0: the most travel the correction may take). Outputs: Done, Busy, CommandAborted, Error, ErrorID (0x4243: the
    correction was incomplete, see the module docstring).
    """

    _INPUTS = {"Execute": False, "Distance": 0.0, "VelocityDiff": 0.0, **_DYN, "VelocityProcess": 0.0,
               "MaxDistance": 0.0}
    Distance: float
    VelocityDiff: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    VelocityProcess: float
    MaxDistance: float

    def _mode_and_length(self) -> tuple[int, Any] | None:
        return _LENGTHREDUCTION_LIMITED, self.MaxDistance


class MC_MoveSuperImposedExt(_SuperBlock):
    """Superimposed relative motion with a Mode (TcMC 3.10).

    Inputs: Execute, Mode (E_SuperpositionMode 1..4, default 4), Distance, VelocityDiff,
    Acceleration, Deceleration, Jerk (not used: AxisJerk; neither checked nor sent),
    VelocityProcess [u/s] (|.| > 0; 0: NC error 0x4B06), Length [u] (|.| > 0; its meaning
    depends on Mode). Outputs: Done, Busy, CommandAborted, Error, ErrorID, ActualVelocityDiff [u/s],
    ActualDistance [u], ActualLength [u].
    """

    _INPUTS = {"Execute": False, "Mode": _LENGTHREDUCTION_LIMITED, "Distance": 0.0, "VelocityDiff": 0.0, **_DYN,
               "VelocityProcess": 0.0, "Length": 0.0}
    _OUTPUTS = {**_SuperBlock._OUTPUTS, "ActualVelocityDiff": 0.0, "ActualDistance": 0.0, "ActualLength": 0.0}
    Mode: int
    Distance: float
    VelocityDiff: float
    Acceleration: float
    Deceleration: float
    Jerk: float
    VelocityProcess: float
    Length: float
    ActualVelocityDiff: float
    ActualDistance: float
    ActualLength: float
    _ACTUAL_OUTPUTS = True

    def _mode_and_length(self) -> tuple[int, Any] | None:
        mode = _integer_in(self.Mode, 1, 4)
        if mode is None:
            self._finish("Error", ErrorCodes.MC_INVALID_MODE)
            return None
        return mode, self.Length


class MC_AbortSuperposition(ExecuteBlock):
    """Stop a superimposed motion without stopping the basic motion (TcMC 3.12).

    Inputs: Execute. Outputs: Done, Busy, Error, ErrorID. Done once the NC accepted it and the
    frame of the reply's cycle arrived.
    """

    _OUTPUTS = {"Done": False, "Busy": False, "Error": False, "ErrorID": 0}

    def _start(self) -> None:
        self._cycle_no = 0
        self._send("AbortSuperposition")

    def _progress(self) -> None:
        if self._reply_shown():
            self._finish("Done")
