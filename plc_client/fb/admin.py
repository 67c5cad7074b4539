"""Administrative function blocks (TcMC manual 4.1-4.5, 4.14): MC_Power, MC_Reset,
MC_SetOverride, MC_ReadActualPosition, MC_ReadStatus, MC_ReadAxisError.

Choices where the manuals are silent (zenoh-nc):

* MC_Power claims the axis for this PLC client on its first call (the NC applies only the
  claim holder's PLCTONC); a refusal shows as Error with the NC's code (0x723 while another
  client holds the axis) while Enable is TRUE, and is retried on Enable's rising edge and
  every ``claim_retry`` seconds (task parameter, 1 s) while Enable stays TRUE; the refusal's code
  stays while a retry is on its way, until the NC's answer (no drop for each retry's round trip).
* MC_Power outputs: Busy = Enable; Active = Enable and the claim is held (the enables are in
  effect); Status = Active and the NC reports ControlLoopClosed with no axis error on valid
  data. Error/ErrorID report the block's own failures (claim refused, stale data 0x4B0F,
  Override outside 0..100 % 0x4B06, BufferMode other than MC_Aborting 0x4B64 (the block
  still acts as MC_Aborting); only while Enable is TRUE) and also the axis's error (TcMC 4.1
  "Error: Becomes TRUE, as soon as an error occurs"; MC3 MC_Power: "Error occurred within
  function block or axis already signaling an error"): while the block's axis is bound and its
  data valid (not stale) and the NC reports an axis error (NCTOPLC StateDWord Error bit; the NC
  sets it exactly while ErrorCode != 0), Error = TRUE and ErrorID = NCTOPLC.ErrorCode (0x4B09
  if a frame had the bit without a code), whatever Enable is and whoever holds the axis: the
  program finds a following error or a drive fault where TwinCAT shows it, and an axis that
  faulted while switched off shows its error before it is enabled. The block's own failure
  takes precedence while both are there (its cause must be fixed first; the axis error shows
  once it is gone). Error falls with the first frame that shows no axis error (after
  MC_Reset); Status stays FALSE while the axis error is there. With Enable FALSE on stale
  data: no error at all (the block's 0x4B0F is reported only while Enable, the axis's error
  is not known). MC_ReadAxisError still reads the axis error alone. The ErrorCode is read only
  when the StateDWord bit is set (MC_Power runs on every axis every cycle: no unpacking).
* Override: PlcToNc.Override = round(Override * 10000) (100 % = 1000000). MC_Power writes it
  when its Override input changes (and on its first call), MC_SetOverride writes it on its
  Execute edge: the last writer wins, so the two can be combined. An out-of-range Override
  keeps the last valid value.
* MC_SetOverride on an axis this task controls writes PlcToNc.Override and is Done in the
  same cycle (the value goes out with this cycle's PLCTONC frame); on an axis it does not
  control it sends the NC's SetOverride command and is Done on its acceptance.
* MC_Reset is Done when the NC accepted the reset and the first frame of the reset's cycle
  shows no axis error; if the error is still there (its cause persists): Error with the
  axis ErrorCode.
* MC_ReadAxisError (TcMC 4.5: "The error code for an axis is displayed"): while Enable and the
  axis's data is valid, ErrorID = the axis's NCTOPLC.ErrorCode and Error = (ErrorCode != 0), Done
  TRUE (the state was read: Done and Error are both TRUE while the axis has an error). AxisErrorID
  (Tc2_MC2's output) carries the same code and stays; Valid (= Done) and Busy (= Enable) are kept as
  Tc2_MC2 extras. The block's own failure (stale data, an unbound axis) is Error with its code
  (0x4B0F, 0x4012), Done/Valid FALSE, AxisErrorID 0 (no axis error known). Enable FALSE resets every
  output, AxisErrorID included.
* MC_ReadStatus: Tc2_MC2 ``Status`` (a copy of AXIS_REF.Status) plus the TcMC flat outputs
  (Errorstop, Stopping, StandStill, ...).
"""
from __future__ import annotations

import operator
from typing import Any, ClassVar

from nc_schema import NCTOPLC_DTYPE, PLCTONC_DTYPE, ControlDWord, ErrorCodes, StateDWord, member_struct

from ..axis_ref import AXIS_REF, ST_AxisStatus
from .base import EnableBlock, ExecuteBlock, FunctionBlock

_EN = int(ControlDWord.Enable)
_FP = int(ControlDWord.FeedEnablePlus)
_FM = int(ControlDWord.FeedEnableMinus)
_CLC = int(StateDWord.ControlLoopClosed)
_ERR = int(StateDWord.Error)
_NOT_ENABLES = ~(_EN | _FP | _FM)
#: where PLCTONC keeps ControlDWord, and its struct (MC_Power reads and writes it every cycle)
_CDW_OFF, _CDW_STRUCT = member_struct(PLCTONC_DTYPE, "ControlDWord")
_CDW_UNPACK, _CDW_PACK = _CDW_STRUCT.unpack_from, _CDW_STRUCT.pack_into
#: where NCTOPLC keeps ErrorCode (MC_Power reads it only while StateDWord has the Error bit: no record unpacking)
_EC_OFF, _EC_STRUCT = member_struct(NCTOPLC_DTYPE, "ErrorCode")
_EC_UNPACK = _EC_STRUCT.unpack_from


def _axis_error(ax: AXIS_REF) -> int:
    """The axis's error code from this cycle's NCTOPLC (its StateDWord has the Error bit)."""
    return int(_EC_UNPACK(ax.NcToPlc._raw, _EC_OFF)[0]) or ErrorCodes.MC_AXIS_NOT_READY


def override_to_plctonc(percent: float) -> int:
    """Override in percent (0..100) -> PLCTONC Override (0..1000000)."""
    return int(round(float(percent) * 10000.0))


def _valid_override(v: Any) -> bool:
    return FunctionBlock._is_real(v) and 0.0 <= float(v) <= 100.0


class MC_Power(FunctionBlock):
    """Software enables and override of an axis (TcMC 4.1, Tc2_MC2 MC_Power).

    Inputs: Enable, Enable_Positive, Enable_Negative (feed enables, only with Enable),
    Override [%] (0..100, default 100), BufferMode (only MC_Aborting).
    Outputs: Status, Busy, Active, Error, ErrorID.

    Status is TRUE while this PLC holds the axis, its data is valid and the NC shows the control
    loop closed without an axis error: the axis is ready for motion commands (Tc2_MC2/MC3).
    Stale data (zenoh-nc choice; the manual is silent on a lost NC): while no new NC frame came
    for ``stale_cycles`` (NC frozen, dead or restarting, link cut, frames not received) Status is
    FALSE and Error/ErrorID show 0x4B0F; Busy stays TRUE, the enables stay set in PLCTONC (the PLC
    does not switch an axis off because it cannot see it: the NC's watchdog decides) and Status
    comes back by itself with fresh data. Why not keep the last Status: a readiness signal must not
    be taken from data known to be old (TwinCAT leaves the AXIS_REF as it was when the NC stops
    updating it, and Tc2_MC2 catches exactly that by the NC cycle counter, 0x4B0F), and a motion
    command started then fails with 0x4B0F anyway. So Status may fall and rise again without the
    program doing anything (also after an NC restart or a claim the NC dropped): never wire it to
    a motion block's Execute (a new rising edge, a second move); start motion from a latched step
    sequence that reads Status as the condition of its first step (README, examples/).
    Error/ErrorID also show the axis's error (following error, drive fault, ...: the NCTOPLC
    ErrorCode) while the axis data is valid, with Enable TRUE or FALSE; the block's own failure
    (claim refused, 0x4B0F, 0x4B06, 0x4B64) takes precedence (module docstring).
    """

    _INPUTS = {"Enable": False, "Enable_Positive": False, "Enable_Negative": False, "Override": 100.0,
               "BufferMode": 0}
    _OUTPUTS = {"Status": False, "Busy": False, "Active": False, "Error": False, "ErrorID": 0}
    # inputs
    Enable: bool
    Enable_Positive: bool
    Enable_Negative: bool
    Override: float
    BufferMode: int
    # outputs
    Status: bool
    Busy: bool
    Active: bool
    Error: bool
    ErrorID: int

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._prev_enable = False
        self._written_override: Any = None

    def _cycle(self) -> None:
        en = bool(self.Enable)
        rising = en and not self._prev_enable
        self._prev_enable = en
        ax = self.Axis
        task = ax._task if ax is not None else None
        if task is None:
            task = self._task()
        if task is None or ax is None:
            self._reset_outputs()
            if en:
                self.Error, self.ErrorID = True, ErrorCodes.MC_NO_NC_CYCLE_UPDATE
            return
        claim = task.control(ax, retry=rising)
        # control word: written every cycle (the PLC owns these bits); read and written in the PlcToNc bytes
        # directly (the property's value check: cdw is the UDINT read with some bits changed)
        buf = ax._plctonc_buf
        old = _CDW_UNPACK(buf, _CDW_OFF)[0]
        cdw = old & _NOT_ENABLES
        if en:
            cdw |= _EN
            if self.Enable_Positive:
                cdw |= _FP
            if self.Enable_Negative:
                cdw |= _FM
        if cdw != old:  # (the same value every cycle but when the enables change)
            _CDW_PACK(buf, _CDW_OFF, cdw)
        ov = self.Override
        # (the very object written last was checked then: a float or an int does not change)
        ov_ok = (ov is self._written_override and type(ov) in (float, int)) or _valid_override(ov)
        if ov_ok and ov != self._written_override:
            ax.PlcToNc.Override = override_to_plctonc(self.Override)
            self._written_override = self.Override
        # (_axis_problem's answer for a bound axis with valid data, without the call)
        ok = ax.Status.Valid and not ax.missing and ax._task is not None
        sdw = ax.NcToPlc._sdw if ok else 0  # (its StateDWord, without unpacking the record)
        if not en:
            self._reset_outputs()
            if sdw & _ERR:  # the axis's error shows with Enable FALSE too (on valid data)
                self.Error, self.ErrorID = True, _axis_error(ax)
            return
        state = claim.state
        held = state == "held"
        code = 0 if ok else self._axis_problem()
        if code:
            pass
        elif claim.error:  # refused (or the retry of a refusal on its way: ClaimState.error)
            code = claim.error
        elif not ov_ok:
            code = ErrorCodes.MC_PARAMETER_NOT_CORRECT
        elif (type(bm := self.BufferMode) is not int or bm != 0) and (  # (a plain int 0: no isinstance calls)
                isinstance(bm, bool) or not isinstance(bm, int) or bm != 0):
            code = ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED
        elif sdw & _ERR:  # the axis's error, when the block has none of its own
            code = _axis_error(ax)
        status = held and bool(sdw & _CLC) and not sdw & _ERR
        if self._PLAIN_IO:  # (the five outputs with one update)
            self.__dict__.update(Busy=True, Active=held, Error=bool(code), ErrorID=int(code), Status=status)
            return
        self.Busy = True
        self.Active = held
        self.Error, self.ErrorID = bool(code), int(code)
        self.Status = status


class MC_Reset(ExecuteBlock):
    """Axis reset (TcMC 4.2): clears the axis error. Outputs: Done, Busy, Error, ErrorID."""

    _INPUTS = {"Execute": False}
    _OUTPUTS = {"Done": False, "Busy": False, "Active": False, "CommandAborted": False, "Error": False, "ErrorID": 0}

    def _start(self) -> None:
        self._cycle_no = 0
        self._send("Reset")

    def _progress(self) -> None:
        if not self._reply_shown():
            return
        ax = self.Axis
        assert ax is not None
        if int(ax.NcToPlc["StateDWord"]) & _ERR:
            self._finish("Error", int(ax.NcToPlc["ErrorCode"]) or ErrorCodes.MC_AXIS_NOT_READY)
        else:
            self._finish("Done")


class MC_SetOverride(ExecuteBlock):
    """Set the velocity override [%] (0..100) of an axis (TcMC 4.14). Outputs: Done, Busy, Error, ErrorID."""

    _INPUTS = {"Execute": False, "Override": 100.0}
    _OUTPUTS = {"Done": False, "Busy": False, "Active": False, "CommandAborted": False, "Error": False, "ErrorID": 0}
    Override: float

    def _start(self) -> None:
        if not _valid_override(self.Override):
            self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        ax = self._usable_axis()
        if ax is None:
            return
        if ax.controlled:
            ax.PlcToNc["Override"] = override_to_plctonc(self.Override)
            self._finish("Done")
        else:
            self._send("SetOverride", Override=float(self.Override))

    def _progress(self) -> None:
        if self._await_reply() is not None:
            self._finish("Done")


class MC_ReadActualPosition(EnableBlock):
    """Actual position (TcMC 4.3). Outputs: Valid, Done, Busy, Error, ErrorID, Position [u]."""

    _OUTPUTS = {**EnableBlock._OUTPUTS, "Position": 0.0}
    Position: float

    def _read(self, ax: AXIS_REF) -> None:
        self.Position = float(ax.NcToPlc.ActPos)


class MC_ReadStatus(EnableBlock):
    """Axis state (TcMC 4.4 / Tc2_MC2). Outputs: Valid, Done, Busy, Error, ErrorID, Status
    (ST_AxisStatus copy), Errorstop, Stopping, StandStill, DiscreteMotion, ContinuousMotion,
    SynchronizedMotion, Homing, ConstantVelocity, Accelerating, Decelerating.
    """

    _FLAT = {"Errorstop": "ErrorStop", "Stopping": "Stopping", "StandStill": "StandStill",
             "DiscreteMotion": "DiscreteMotion", "ContinuousMotion": "ContinuousMotion",
             "SynchronizedMotion": "SynchronizedMotion", "Homing": "Homing", "ConstantVelocity": "ConstantVelocity",
             "Accelerating": "Accelerating", "Decelerating": "Decelerating"}
    _OUTPUTS: ClassVar[dict[str, Any]] = {**EnableBlock._OUTPUTS, **{k: False for k in _FLAT}}
    #: the outputs of _FLAT and a getter of their ST_AxisStatus members (one C call instead of a comprehension)
    _FLAT_OUT: ClassVar[tuple[str, ...]] = tuple(_FLAT)
    _FLAT_GET: ClassVar[operator.itemgetter[Any]] = operator.itemgetter(*_FLAT.values())  # (no descriptor)
    Status: ST_AxisStatus
    Errorstop: bool
    Stopping: bool
    StandStill: bool
    DiscreteMotion: bool
    ContinuousMotion: bool
    SynchronizedMotion: bool
    Homing: bool
    ConstantVelocity: bool
    Accelerating: bool
    Decelerating: bool

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self.Status = ST_AxisStatus()

    def _read(self, ax: AXIS_REF) -> None:
        st = ax.Status
        self.Status = st.copy()
        if self._PLAIN_IO:  # (every ST_AxisStatus member is in its __dict__)
            self.__dict__.update(zip(self._FLAT_OUT, map(bool, self._FLAT_GET(st.__dict__))))
            return
        for out, field in self._FLAT.items():
            setattr(self, out, bool(getattr(st, field)))


class MC_ReadAxisError(EnableBlock):
    """Axis error code (TcMC 4.5 / Tc2_MC2; the module docstring has the rules).

    Input: Enable. Outputs: Done, Error, ErrorID (TcMC: the axis's NCTOPLC.ErrorCode, Error = code != 0),
    AxisErrorID (Tc2_MC2: the same code), Valid (= Done) and Busy (= Enable).
    """

    _OUTPUTS = {**EnableBlock._OUTPUTS, "AxisErrorID": 0}
    AxisErrorID: int

    def _cycle(self) -> None:
        super()._cycle()
        if not self.Done:
            self.AxisErrorID = 0  # Enable FALSE, or no valid axis data: no axis error known

    def _read(self, ax: AXIS_REF) -> None:
        code = int(ax.NcToPlc["ErrorCode"])
        self.AxisErrorID = self.ErrorID = code
        self.Error = code != 0
