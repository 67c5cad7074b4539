"""MC_PowerStepper (TcMC manual 4.23, 4.23.1): MC_Power for stepper motors on a KL2531/KL2541 terminal, with
stall detection and handling, and monitoring of the terminal's status bits; ST_PowerStepperStruct (6.6),
E_DestallMode (6.7), E_DestallDetectMode (6.8).

What it does (the manual's rules; zenoh-nc's choices where it is silent):

* the enables and the override go through an internal MC_Power (its claim, its Status, its errors: 0x723 a
  refused claim, 0x4B0F stale data, 0x4B06 an Override outside 0..100 %, and the axis's error: NCTOPLC
  ErrorCode, 0x4B09 for the StateDWord Error bit without a code);
* Error/ErrorID (zenoh-nc choice; TcMC 4.23 says only "Error: Becomes TRUE, as soon as an error occurs", and
  that MC_Power is used internally): with Enable TRUE the block's own error (the NC's refusal of a report,
  0x4B04 invalid DestallParams, a failed parameter read) first, then MC_Power's (its own, then the axis's);
  with Enable FALSE MC_Power's, i.e. the axis's error on valid data (a following error, a drive or terminal
  fault of a switched-off stepper shows as it does on MC_Power), no error otherwise (the block's own errors
  are reported only while Enable, as MC_Power's are). Status is FALSE with Enable FALSE;
* **stall detection** (``DestallParams.DestallEnable`` and a DestallDetectMode):
  ``PwStDetectMode_Encoderless``: bits 1-3 of the status byte (KL_Status, the terminal's LoadAngle) at 7,
  the largest load angle; ``PwStDetectMode_Lagging``: the following error |NcToPlc.PosDiff| above the NC's
  AxisMaxPosLagValue for longer than AxisMaxPosLagFilterTime (both read from the NC on Enable's rising edge;
  switch the NC's own following error monitoring off, AxisEnPositionLagMonitoring, or it reports 0x4550
  first);
* **stall handling** (DestallMode): ``PwStMode_None`` nothing; ``PwStMode_SetError`` the axis gets error
  0x4636 (NC command SetExternalError; the log line "MC_PowerStepper(AxId:=3) reporting error 0x4636
  (stall error)!"); ``PwStMode_SetErrNonRef`` the same and the axis is no longer referenced (Homed FALSE);
  ``PwStMode_UseOverride`` the override goes to 0 at once (the profile halts without being aborted, no
  status bit changes); once the set velocity is 0 and the position controller has brought the axis back
  within AxisMaxPosLagValue of the set position, the application's Override applies again and the profile
  covers its remaining distance. UseOverride needs the Lagging detection (the manual's table: "not
  suitable" with Encoderless): that combination is refused with Error 0x4B04 while DestallEnable is TRUE
  (the enables still work), as is an unknown mode number;
* **status monitoring** (``StatusMonEnable``, independent of the stall settings: it runs also while those
  are refused): each error bit of the status word (KL_Status2) that the
  parameter table maps (schema/params.json ``stepper_terminal``: 0x4630 overtemperature .. 0x4635
  overcurrent B) is reported to the NC as that axis error, the lowest bit first;
* a reported error is reported once: again only after the axis error was cleared (MC_Reset) and the
  condition is still there; while the axis shows the code this block reported, Error/ErrorID show it too;
* ``KL_Status`` / ``KL_Status2`` None (the default): taken from the axis's simulated terminal (a SimStepper
  axis: NCJOBS DriveStatus, ``terminal_status()``); with a real terminal wire its status byte and word.

Inputs: Enable, Enable_Positive, Enable_Negative, Override [%], DestallParams (ST_PowerStepperStruct),
KL_Status (USINT), KL_Status2 (UINT). Outputs: Status, Error, ErrorID. The axis is ``Axis`` (an AXIS_REF
holds TcMC's AxisRefIn and AxisRefOut).
"""
from __future__ import annotations

import logging
import math
import numbers
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from nc_schema import PARAMETERS, E_DestallDetectMode, E_DestallMode, ErrorCodes, MC_AxisPara
from nc_schema.params import STEPPER_TERMINAL

from ..axis_ref import AXIS_REF
from ..port import PendingCommand, reply_cycle
from .admin import MC_Power
from .base import FunctionBlock

log = logging.getLogger("plc_client.fb")

_TERMINAL = STEPPER_TERMINAL
#: status word bit -> (name, NC error code), in bit order
STATUS_WORD_ERRORS: dict[int, tuple[str, int]] = {
    int(b["bit"]): (b["name"], int(b["error"], 16)) for b in _TERMINAL["status_word"]}
STALL_ERROR = int(_TERMINAL["stall_error"], 16)
_LOAD_ANGLE_STALL = 7
_PRESENT = 1 << 31
_LAG_MAX = int(MC_AxisPara.AxisMaxPosLagValue)
_LAG_TIME = int(MC_AxisPara.AxisMaxPosLagFilterTime)
assert PARAMETERS.by_number(_LAG_MAX) is not None and PARAMETERS.by_number(_LAG_TIME) is not None


@dataclass
class ST_PowerStepperStruct:
    """MC_PowerStepper's working rules (TcMC 6.6)."""

    DestallDetectMode: int = E_DestallDetectMode.PwStDetectMode_None
    DestallMode: int = E_DestallMode.PwStMode_None
    DestallEnable: bool = False
    StatusMonEnable: bool = False


def terminal_status(ax: AXIS_REF) -> tuple[int, int] | None:
    """(KL_Status, KL_Status2) of the axis's simulated stepper terminal (NCJOBS DriveStatus); None when the
    axis has none (not a SimStepper axis, or no job records)."""
    ds = int(ax.NcJobs["DriveStatus"]) if "DriveStatus" in (ax.NcJobs.dtype.names or ()) else 0
    if not ds & _PRESENT:
        return None
    return ds & 0xFF, (ds >> 8) & 0xFFFF


def _int(v: Any) -> int | None:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        return None
    return int(v)


class MC_PowerStepper(FunctionBlock):
    """Enables, override, stall detection/handling and terminal monitoring of a stepper axis (TcMC 4.23; see
    the module docstring)."""

    _INPUTS: ClassVar[dict[str, Any]] = {"Enable": False, "Enable_Positive": False, "Enable_Negative": False,
                                         "Override": 100.0, "DestallParams": None, "KL_Status": None,
                                         "KL_Status2": None}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Status": False, "Error": False, "ErrorID": 0}
    Enable: bool
    Enable_Positive: bool
    Enable_Negative: bool
    Override: float
    DestallParams: ST_PowerStepperStruct | dict[str, Any]
    KL_Status: int | None
    KL_Status2: int | None
    Status: bool
    Error: bool
    ErrorID: int

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self.DestallParams = ST_PowerStepperStruct()
        self._power = MC_Power(timeout)
        self._prev_enable = False
        self._reads: dict[int, PendingCommand] = {}
        self._lag: dict[int, float] = {}      # AxisMaxPosLagValue, AxisMaxPosLagFilterTime as read
        self._read_error = 0
        self._lag_since: float | None = None  # since when the following error is above the maximum
        self._holding = False                 # UseOverride: the override is held at 0
        self._reported = 0                    # the code reported to the NC (0: none)
        self._report: PendingCommand | None = None
        self._report_error = 0
        self._report_cycle = 0
        self.stalled = False                  # (diagnostics) a stall is detected now

    # -- the cycle ---------------------------------------------------------------------------------------------
    def _cycle(self) -> None:
        en = bool(self.Enable)
        rising = en and not self._prev_enable
        self._prev_enable = en
        ax = self.Axis
        if rising:
            self._restart()
        code = 0
        if en and ax is not None and self._task() is not None and ax.Status.Valid:
            code = self._supervise(ax)  # (first: a stall holds the override in this very cycle)
        ov = 0.0 if (en and self._holding) else self.Override
        self._power(Axis=ax, Enable=en, Enable_Positive=self.Enable_Positive, Enable_Negative=self.Enable_Negative,
                    Override=ov)
        self.Status = bool(self._power.Status)
        if not en:
            self._reset_outputs()
            self._holding = False
            # MC_Power's error with Enable FALSE: the axis's (module docstring)
            self.Error, self.ErrorID = bool(self._power.Error), int(self._power.ErrorID)
            return
        own = self._own_error(ax)
        self.Error, self.ErrorID = (True, own) if own else (bool(self._power.Error), int(self._power.ErrorID))
        if code and not own:
            self.Error, self.ErrorID = True, int(code)

    def _restart(self) -> None:
        for p in self._reads.values():
            if not p.done:
                p.abandon()
        self._reads, self._lag, self._read_error = {}, {}, 0
        self._lag_since, self._holding, self.stalled = None, False, False
        self._report_error = 0

    def _params(self) -> tuple[int, int, bool, bool] | None:
        dp = self.DestallParams
        if isinstance(dp, dict):  # (a map of the members, e.g. from JSON)
            try:
                dp = ST_PowerStepperStruct(**dp)
            except TypeError:
                return None
        try:
            detect, mode = _int(dp.DestallDetectMode), _int(dp.DestallMode)
            enable, mon = bool(dp.DestallEnable), bool(dp.StatusMonEnable)
        except AttributeError:
            return None
        # (an unknown mode number: -1, refused by _supervise after the status monitoring, which does not use it)
        detect = detect if detect in {int(m) for m in E_DestallDetectMode} else -1
        mode = mode if mode in {int(m) for m in E_DestallMode} else -1
        return detect, mode, enable, mon

    def _terminal_inputs(self, ax: AXIS_REF) -> tuple[int, int]:
        sim = terminal_status(ax)
        sb = self.KL_Status if self.KL_Status is not None else (sim[0] if sim else 0)
        sw = self.KL_Status2 if self.KL_Status2 is not None else (sim[1] if sim else 0)
        return (_int(sb) or 0) & 0xFF, (_int(sw) or 0) & 0xFFFF

    def _supervise(self, ax: AXIS_REF) -> int:
        """Stall detection/handling and status monitoring; returns a code to show (0: none)."""
        params = self._params()
        if params is None:
            self._holding = False
            return ErrorCodes.MC_INVALID_MODE
        detect, mode, enable, mon = params
        sb, sw = self._terminal_inputs(ax)
        # status monitoring: the terminal's errors
        if mon:
            for bit, (name, err) in STATUS_WORD_ERRORS.items():
                if sw >> bit & 1:
                    self._raise(ax, err, f"terminal: {name}", unreference=False)
                    break
        if detect < 0 or mode < 0:
            self._holding = False
            return ErrorCodes.MC_INVALID_MODE
        if not enable or detect == E_DestallDetectMode.PwStDetectMode_None:
            self._holding, self.stalled, self._lag_since = False, False, None
            return 0
        if detect == E_DestallDetectMode.PwStDetectMode_Encoderless and mode == E_DestallMode.PwStMode_UseOverride:
            self._holding = False
            return ErrorCodes.MC_INVALID_MODE  # "not suitable" (TcMC 4.23.1)
        lag = abs(float(ax.NcToPlc["PosDiff"]))
        if detect == E_DestallDetectMode.PwStDetectMode_Encoderless:
            self.stalled = (sb >> 1) & 7 == _LOAD_ANGLE_STALL
        else:
            limits = self._lag_limits(ax)
            if limits is None:
                return self._read_error
            lag_max, lag_time = limits
            assert ax._task is not None  # (_cycle checked it)
            now = ax._task.now
            if lag > lag_max:
                if self._lag_since is None:
                    self._lag_since = now
                self.stalled = self.stalled or now - self._lag_since > lag_time
            else:
                self._lag_since = None
                if not self._holding:
                    self.stalled = False
        if mode == E_DestallMode.PwStMode_UseOverride:
            if self.stalled and not self._holding:
                self._holding = True
                log.warning("MC_PowerStepper(AxId:=%d) stall: override held at 0 until the axis caught up", ax.axis_id)
            elif self._holding:
                lag_max = self._lag.get(_LAG_MAX, math.inf)
                if abs(float(ax.NcToPlc["SetVelo"])) <= 1e-9 and lag <= lag_max:
                    self._holding, self.stalled, self._lag_since = False, False, None
        elif self.stalled and mode in (E_DestallMode.PwStMode_SetError, E_DestallMode.PwStMode_SetErrNonRef):
            self._raise(ax, STALL_ERROR, "stall error", unreference=mode == E_DestallMode.PwStMode_SetErrNonRef)
        return 0

    def _lag_limits(self, ax: AXIS_REF) -> tuple[float, float] | None:
        """(AxisMaxPosLagValue, AxisMaxPosLagFilterTime) once read from the NC (read on Enable's rising edge)."""
        if len(self._lag) == 2:
            return self._lag[_LAG_MAX], self._lag[_LAG_TIME]
        task = ax._task
        assert task is not None
        for number in (_LAG_MAX, _LAG_TIME):
            p = self._reads.get(number)
            if p is None and number not in self._lag and not self._read_error:
                self._reads[number] = task.send(ax, "ReadParameter", ParameterNumber=number)
            elif p is not None and p.done:
                del self._reads[number]
                err = int(p.reply.get("error", 0)) if p.reply is not None else int(p.failed or ErrorCodes.NC_INTERNAL)
                if err:
                    self._read_error = err
                else:
                    assert p.reply is not None  # (no reply: err is set)
                    self._lag[number] = float(p.reply["Value"])
            elif p is not None and task.now - p.sent_at >= self._timeout():
                p.abandon()
                del self._reads[number]
                self._read_error = ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT
        if len(self._lag) == 2:
            return self._lag[_LAG_MAX], self._lag[_LAG_TIME]
        return None

    # -- reporting errors to the NC -------------------------------------------------------------------------------
    def _raise(self, ax: AXIS_REF, code: int, what: str, unreference: bool) -> None:
        """Report ``code`` to the NC unless it is reported already (see the module docstring)."""
        if self._report is not None or self._reported or ax.Status.Error:
            return
        log.warning("MC_PowerStepper(AxId:=%d) reporting error 0x%04X (%s)!", ax.axis_id, code, what)
        self._reported, self._report_error = code, 0
        assert ax._task is not None  # (_supervise runs on a bound axis)
        self._report = ax._task.send(ax, "SetExternalError", ErrorCode=code, Unreference=unreference)

    def _own_error(self, ax: AXIS_REF | None) -> int:
        """The code this block reported while the axis shows it (or the NC's refusal of the report)."""
        p = self._report
        if p is not None and p.done:
            self._report = None
            err = int(p.reply.get("error", 0)) if p.reply is not None else int(p.failed or ErrorCodes.NC_INTERNAL)
            if err:
                self._report_error, self._reported = err, 0
            else:
                assert p.reply is not None  # (no reply: err is set)
                self._report_cycle = reply_cycle(p.reply)
        if self._report_error:
            return self._report_error
        if not self._reported:
            return 0
        if self._report is not None or ax is None or not ax.Status.Valid or not ax.shows_cycle(self._report_cycle):
            return self._reported  # (sent; the frames do not show it yet)
        if int(ax.NcToPlc["ErrorCode"]) == self._reported:
            return self._reported
        self._reported = 0  # cleared (MC_Reset), or another error came first
        self.stalled, self._lag_since = False, None
        return 0


__all__ = ["MC_PowerStepper", "ST_PowerStepperStruct", "E_DestallMode", "E_DestallDetectMode", "terminal_status",
           "STATUS_WORD_ERRORS", "STALL_ERROR"]
