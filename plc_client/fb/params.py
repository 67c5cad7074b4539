"""Parameter blocks (TcMC manual 4.6-4.11): MC_ReadParameter, MC_ReadBoolParameter, MC_WriteParameter,
MC_WriteBoolParameter, MC_ReadParameterSet (with ST_AxisParameterSet) and MC_ReadAxisComponents (with
ST_AxisComponents).

The numbers, types and what the NC does with them are the parameter table (``schema/params.json``,
``nc_schema.PARAMETERS``, docs/parameters.md). Choices where the manual is silent (zenoh-nc):

* **Types** (TcMC 6.1: "if the data types do not coincide ... an error is generated"): MC_ReadParameter /
  MC_WriteParameter on a BOOL parameter and MC_ReadBoolParameter / MC_WriteBoolParameter on any other are
  refused by the block with 0x4B05 (MC_COMMAND_NOT_PERMITTED, "read/write parameter unsuitable type"),
  nothing sent. A number the table does not know is sent: the NC answers 0x703.
* **MC_ReadParameter / MC_ReadBoolParameter** (Enable, level): ``ReadMode_Once`` (default) reads once on
  Enable's rising edge (ParameterNumber and ReadMode latched then); Done and Value stay while Enable stays
  TRUE. ``ReadMode_Cyclic`` reads again as soon as the previous answer arrived (one request at a time, at most
  one per PLC cycle) while Enable is TRUE; ParameterNumber is taken for each read (a new number: Done falls
  until its value arrives). Error: the NC's code (0x703 unknown, ...), 0x745 without an answer within the
  timeout, 0x4B0F stale axis data, 0x4B04 a ReadMode other than 1/2, 0x4B06 a ParameterNumber that is not an
  integer; a cyclic read recovers by itself. Enable FALSE resets Done/Error/ErrorID; Value keeps the last
  value read. MC_ReadBoolParameter's Value is a BOOL (the manual's declaration says LREAL, its text "the
  boolean value"; Tc2_MC2 declares BOOL).
* **MC_WriteParameter / MC_WriteBoolParameter**: TcMC's input is ``Enable`` ("executed as long as the input
  is TRUE"): the value is written on Enable's rising edge and again whenever ParameterNumber or Value change
  while Enable stays TRUE (the parameter follows the input); Done once the NC accepted the newest write and
  a frame of its cycle arrived (the effect, e.g. an OpModeDWord bit, is visible then), Error with the NC's
  code (stays until the inputs change or Enable falls). Tc2_MC2's edge-triggered ``Execute`` is accepted as
  well: one write of the inputs latched on its rising edge; Done/Error stay while Execute is TRUE (one cycle
  if it already fell). The NC applies a write between two cycles, never within one; values a running motion
  would violate are refused by the NC (0x4221 AxisVeloMax, 0x4222 a software limit, ... docs/parameters.md).
  Value must be a finite number (MC_WriteBoolParameter: a BOOL), else 0x4B06, nothing sent.
* **MC_ReadParameterSet / MC_ReadAxisComponents** (Execute, edge): one ``ReadParameterSet`` /
  ``ReadAxisComponents`` command; on Done the IN_OUT ``Parameter`` (``AxisComponents``) holds the values (the
  block's own instance unless one is passed in). ST_AxisParameterSet has Beckhoff's member names; its
  ``to_bytes()`` is the 1024-byte layout of ``nc_schema.ST_AXIS_PARAMETER_SET`` (offsets by TwinCAT 3's
  natural alignment: a reconstruction, see docs/parameters.md).
"""
from __future__ import annotations

import numbers
from typing import Any, ClassVar

import numpy as np

from nc_schema import (
    PARAMETERS, ST_AXIS_COMPONENTS, ST_AXIS_PARAMETER_SET, E_ReadMode, ErrorCodes,
)
from nc_schema.params import StructLayout

from ..port import PendingCommand, reply_cycle
from .base import ExecuteBlock, FunctionBlock


class _Struct:
    """A TwinCAT STRUCT as a Python object: one attribute per member (``LAYOUT`` gives names and types)."""

    LAYOUT: ClassVar[StructLayout]
    __slots__: tuple[str, ...] = ()

    def __init__(self, **values: Any) -> None:
        for k, v in self.LAYOUT.defaults().items():
            object.__setattr__(self, k, v)
        self.update(values)

    def update(self, values: Any) -> None:
        """Set members from a map (unknown names: ValueError)."""
        names = {f.name for f in self.LAYOUT.fields}
        for k, v in dict(values).items():
            if k not in names:
                raise ValueError(f"{type(self).__name__} has no member {k!r}")
            setattr(self, k, list(v) if isinstance(v, (list, tuple)) else v)

    def as_dict(self) -> dict[str, Any]:
        return {f.name: (list(getattr(self, f.name)) if f.count > 1 else getattr(self, f.name))
                for f in self.LAYOUT.fields}

    def to_bytes(self) -> bytes:
        """The struct's bytes (little-endian; layout in schema/params.json)."""
        return self.LAYOUT.encode(self.as_dict())

    @classmethod
    def from_bytes(cls, data: bytes | bytearray | memoryview) -> Any:
        """Raises ValueError when ``data`` is not exactly the struct's size."""
        return cls(**cls.LAYOUT.decode(data))

    def copy(self) -> Any:
        return type(self)(**self.as_dict())

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.as_dict() == other.as_dict()

    def __repr__(self) -> str:
        items = ", ".join(f"{k}={v!r}" for k, v in self.as_dict().items() if v not in (0, 0.0, "", [0] * 9))
        return f"{type(self).__name__}({items})"


class ST_AxisParameterSet(_Struct):
    """The whole parameter set of an axis (Tc2_MC2 ST_AxisParameterSet; MC_ReadParameterSet): AxisId,
    nAxisType, sAxisName, fAxisCycleTime, bEnablePositionAreaControl, ... fAccelerationMax, fDecelerationMax
    (every member and where its value comes from: docs/parameters.md)."""

    LAYOUT = ST_AXIS_PARAMETER_SET
    __slots__ = tuple(f.name for f in ST_AXIS_PARAMETER_SET.fields)


class ST_AxisComponents(_Struct):
    """The sub-elements of an axis (MC_ReadAxisComponents): EncoderIDs, ControllerIDs, DriveIDs, each an
    ARRAY[1..9] OF DWORD as a list of 9 (element k of the ST array is index k - 1); unused entries 0."""

    LAYOUT = ST_AXIS_COMPONENTS
    __slots__ = tuple(f.name for f in ST_AXIS_COMPONENTS.fields)


def _int(v: Any) -> int | None:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Integral):
        return None
    return int(v)


def _bool_like(v: Any) -> bool:
    return isinstance(v, (bool, np.bool_))


def _type_problem(number: int, want_bool: bool) -> int:
    """0x4B05 if the table knows ``number`` with the other type, else 0."""
    e = PARAMETERS.by_number(number)
    if e is not None and e.is_bool != want_bool:
        return ErrorCodes.MC_COMMAND_NOT_PERMITTED
    return 0


class _ReadParam(FunctionBlock):
    """MC_ReadParameter / MC_ReadBoolParameter (see the module docstring)."""

    _BOOL: ClassVar[bool] = False
    _INPUTS: ClassVar[dict[str, Any]] = {"Enable": False, "ParameterNumber": 0, "ReadMode": E_ReadMode.ReadMode_Once}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "Error": False, "ErrorID": 0, "Value": 0.0}
    Enable: bool
    ParameterNumber: int
    ReadMode: int
    Done: bool
    Error: bool
    ErrorID: int
    Value: float

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._prev = False
        self._pending: PendingCommand | None = None
        self._number = 0
        self._mode = int(E_ReadMode.ReadMode_Once)
        self._finished = False  # ReadMode_Once: the one read has a result

    def _reset_outputs(self) -> None:
        """Done, Error and ErrorID; Value keeps the last value read."""
        keep = self.__dict__.get("Value")
        super()._reset_outputs()
        if keep is not None:
            self.Value = keep

    def _cycle(self) -> None:
        en = bool(self.Enable)
        rising = en and not self._prev
        self._prev = en
        if not en:
            self._drop()
            self._reset_outputs()
            return
        if rising:
            self._drop()
            self._reset_outputs()
            self._finished = False
            mode = _int(self.ReadMode)
            self._mode = mode if mode is not None else -1
        if self._mode not in (int(E_ReadMode.ReadMode_Once), int(E_ReadMode.ReadMode_Cyclic)):
            self._fail(ErrorCodes.MC_INVALID_MODE)
            return
        cyclic = self._mode == int(E_ReadMode.ReadMode_Cyclic)
        if self._pending is not None:
            self._poll()
        if self._pending is None and not (self._finished and not cyclic):
            if rising or cyclic:
                self._start(rising)

    def _start(self, rising: bool) -> None:
        number = _int(self.ParameterNumber)
        if number is None:
            self._fail(ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        if not rising and number != self._number:
            self.Done = False  # (cyclic: a new number; its value is not here yet)
        self._number = number
        code = _type_problem(number, self._BOOL) or self._axis_problem()
        if code:
            self._fail(code)
            return
        ax = self.Axis
        assert ax is not None and ax._task is not None
        self._pending = ax._task.send(ax, "ReadParameter", ParameterNumber=number)
        self._poll()  # (an in-process NC answers at once)

    def _poll(self) -> None:
        p = self._pending
        assert p is not None
        if p.done:
            self._pending = None
            self._finished = True
            if p.reply is None:
                self._fail(p.failed or ErrorCodes.NC_INTERNAL)
                return
            err = int(p.reply.get("error", 0))
            if err:
                self._fail(err)
                return
            v = p.reply.get("Value")
            if self._BOOL:
                self.Value = bool(v)
            else:
                self.Value = float(v) if isinstance(v, (int, float)) else 0.0
            self.Done, self.Error, self.ErrorID = True, False, 0
        else:
            task = self.Axis._task if self.Axis is not None else None
            if task is not None and task.now - p.sent_at >= self._timeout():
                p.abandon()
                self._pending = None
                self._finished = True
                self._fail(ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT)

    def _fail(self, code: int) -> None:
        self._finished = True
        self.Done, self.Error, self.ErrorID = False, True, int(code)

    def _drop(self) -> None:
        if self._pending is not None and not self._pending.done:
            self._pending.abandon()
        self._pending = None


class MC_ReadParameter(_ReadParam):
    """Read an axis parameter (TcMC 4.6). Inputs: Enable, ParameterNumber (MC_AxisPara), ReadMode
    (E_ReadMode, default ReadMode_Once). Outputs: Done, Error, ErrorID, Value (LREAL)."""

    _BOOL = False


class MC_ReadBoolParameter(_ReadParam):
    """Read a boolean axis parameter (TcMC 4.7). Inputs: Enable, ParameterNumber, ReadMode. Outputs: Done,
    Error, ErrorID, Value (BOOL)."""

    _BOOL = True
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "Error": False, "ErrorID": 0, "Value": False}
    Value: bool


class _WriteParam(FunctionBlock):
    """MC_WriteParameter / MC_WriteBoolParameter (see the module docstring)."""

    _BOOL: ClassVar[bool] = False
    _INPUTS: ClassVar[dict[str, Any]] = {"Enable": False, "Execute": False, "ParameterNumber": 0, "Value": 0.0}
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "Error": False, "ErrorID": 0}
    Enable: bool
    Execute: bool
    ParameterNumber: int
    Value: float
    Done: bool
    Error: bool
    ErrorID: int

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        if self._BOOL:
            self.Value = False
        self.Busy = False
        self._prev_en = False
        self._prev_ex = False
        self._pending: PendingCommand | None = None
        self._cycle_no = 0          # the accepted write's NC cycle, waiting for its frame
        self._by_execute = False    # the running/last write came from Execute's edge
        self._written: tuple[Any, Any] | None = None  # (ParameterNumber, Value) of the newest write (Enable)

    def _inputs(self) -> tuple[Any, Any]:
        return (self.ParameterNumber, self.Value)

    def _cycle(self) -> None:
        en, ex = bool(self.Enable), bool(self.Execute)
        en_rise, ex_rise = en and not self._prev_en, ex and not self._prev_ex
        self._prev_en, self._prev_ex = en, ex
        if self._by_execute:
            if not self.Busy and (not ex or ex_rise):
                self._reset_outputs()  # Execute fell (or a result shown for its one cycle)
                self._by_execute = False
        elif not en:
            self._drop()
            self._reset_outputs()
            self._written = None
        if self.Busy:
            self._progress()
        if self.Busy:
            return
        if ex_rise:
            self._by_execute = True
            self._start()
        elif en and not self._by_execute and (en_rise or self._inputs() != self._written):
            self._start()

    def _start(self) -> None:
        self._reset_outputs()
        self._written = self._inputs()
        number, value = _int(self.ParameterNumber), self.Value
        if self._BOOL:
            ok = _bool_like(value)
            value = bool(value)
        else:
            ok = FunctionBlock._is_real(value)
            value = float(value) if ok else 0.0
        if number is None or not ok:
            self._end(ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        code = _type_problem(number, self._BOOL) or self._axis_problem()
        if code:
            self._end(code)
            return
        ax = self.Axis
        assert ax is not None and ax._task is not None
        self.Busy = True
        self._cycle_no = 0
        self._epoch = ax.nc_epoch
        self._pending = ax._task.send(ax, "WriteParameter", ParameterNumber=number, Value=value)
        self._progress()

    def _progress(self) -> None:
        ax = self.Axis
        code = self._axis_problem()
        if not code and ax is not None and ax.nc_epoch != self._epoch:
            code = ErrorCodes.MC_NO_NC_CYCLE_UPDATE
        if code:
            self._end(code)
            return
        p = self._pending
        if p is not None:
            if not p.done:
                if ax is not None and ax._task is not None and ax._task.now - p.sent_at >= self._timeout():
                    self._end(ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT)
                return
            self._pending = None
            if p.reply is None:
                self._end(p.failed or ErrorCodes.NC_INTERNAL)
                return
            err = int(p.reply.get("error", 0))
            if err:
                self._end(err)
                return
            self._cycle_no = reply_cycle(p.reply)
        if ax is not None and ax.shows_cycle(self._cycle_no):
            self._end(0)

    def _end(self, code: int) -> None:
        self._drop()
        self.Busy = False
        if code:
            self.Done, self.Error, self.ErrorID = False, True, int(code)
        else:
            self.Done, self.Error, self.ErrorID = True, False, 0

    def _drop(self) -> None:
        if self._pending is not None and not self._pending.done:
            self._pending.abandon()
        self._pending = None
        self.Busy = False


class MC_WriteParameter(_WriteParam):
    """Write an axis parameter (TcMC 4.10). Inputs: Enable (TcMC, level) or Execute (Tc2_MC2, edge),
    ParameterNumber (MC_AxisPara), Value (LREAL). Outputs: Done, Error, ErrorID (and a Busy attribute)."""

    _BOOL = False


class MC_WriteBoolParameter(_WriteParam):
    """Write a boolean axis parameter (TcMC 4.11). Inputs: Enable or Execute, ParameterNumber, Value (BOOL).
    Outputs: Done, Error, ErrorID."""

    _BOOL = True
    _INPUTS: ClassVar[dict[str, Any]] = {"Enable": False, "Execute": False, "ParameterNumber": 0, "Value": False}
    Value: bool


class _ReadStruct(ExecuteBlock):
    """MC_ReadParameterSet / MC_ReadAxisComponents: one read command, the reply fills an IN_OUT struct."""

    CMD: ClassVar[str] = ""
    STRUCT: ClassVar[type[_Struct]]
    IN_OUT: ClassVar[str] = ""
    _OUTPUTS: ClassVar[dict[str, Any]] = {"Done": False, "Busy": False, "Error": False, "ErrorID": 0}

    def __init__(self, timeout: float | None = None) -> None:
        self.Active = False
        self.CommandAborted = False
        super().__init__(timeout)
        if getattr(self, self.IN_OUT) is None:
            setattr(self, self.IN_OUT, self.STRUCT())

    def _start(self) -> None:
        if not isinstance(getattr(self, self.IN_OUT), self.STRUCT):
            self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        self._send(self.CMD)

    def _progress(self) -> None:
        if self._lost_axis():
            return
        reply = self._await_reply()
        if reply is None:
            return
        value = reply.get("Value")
        target = getattr(self, self.IN_OUT)
        try:
            if not isinstance(value, dict) or not isinstance(target, self.STRUCT):
                raise ValueError("no struct in the reply")
            target.update(value)
        except (ValueError, TypeError):
            self._finish("Error", ErrorCodes.ADSERR_DEVICE_INVALIDDATA)
            return
        self._finish("Done")


class MC_ReadParameterSet(_ReadStruct):
    """Read the whole parameter set of an axis (TcMC 4.8). Inputs: Execute. IN_OUT: Parameter
    (ST_AxisParameterSet; the block's own instance unless passed). Outputs: Done, Busy, Error, ErrorID."""

    CMD = "ReadParameterSet"
    STRUCT = ST_AxisParameterSet
    IN_OUT = "Parameter"
    _INPUTS: ClassVar[dict[str, Any]] = {"Execute": False, "Parameter": None}
    Parameter: ST_AxisParameterSet


class MC_ReadAxisComponents(_ReadStruct):
    """Read the encoder, controller and drive ids of an axis (TcMC 4.9). Inputs: Execute. IN_OUT:
    AxisComponents (ST_AxisComponents). Outputs: Done, Busy, Error, ErrorID."""

    CMD = "ReadAxisComponents"
    STRUCT = ST_AxisComponents
    IN_OUT = "AxisComponents"
    _INPUTS: ClassVar[dict[str, Any]] = {"Execute": False, "AxisComponents": None}
    AxisComponents: ST_AxisComponents


__all__ = ["MC_ReadParameter", "MC_ReadBoolParameter", "MC_WriteParameter", "MC_WriteBoolParameter",
           "MC_ReadParameterSet", "MC_ReadAxisComponents", "ST_AxisParameterSet", "ST_AxisComponents", "E_ReadMode"]

