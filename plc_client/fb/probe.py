"""Touch probe: MC_InputRef, MC_TouchProbe, MC_AbortTrigger (TcMC manual 4.21, 4.22, data types 6.3).

Call style: ``tp(Axis=ax, TriggerInput=ref, Execute=True, WindowOnly=False)`` with
``ref = MC_InputRef()``; TriggerInput is VAR_IN_OUT (kept once passed, like Axis), and the
MC_AbortTrigger that interrupts a cycle must get the same MC_InputRef object.

**Signal source TouchProbe1** (the drive's latch, TouchProbe 1..4 on the wire): MC_TouchProbe
sends ``TouchProbe`` {EncoderID, TouchProbe, Edge, ModuloPositions, WindowOnly, FirstPosition,
LastPosition}; the NC arms the latch and rejects events outside the window itself. The reply's
CmdNo is the probe cycle's own number, followed in the job record (from the first frame of the
reply's NC cycle on): ``NCJOBS.ProbeCmdNo`` ours and ProbeState ACTIVE -> Busy; DONE -> Done
with RecordedPosition = NCJOBS.RecordedPosition (modulo if ModuloPositions); ABORTED
(MC_AbortTrigger) or ProbeCmdNo moved on to a newer cycle -> CommandAborted; ERROR -> Error
with NCJOBS.ProbeErrorId (MC_Reset: 0x4B0C "latch disabled"); ProbeCmdNo older than ours or a frame
without job records -> Error 0x4B60. A TriggerInput the NC cannot use (EncoderID outside
1..255, TouchProbe 2..4, Edge not 0/1) is the NC's answer, 0x4B0B; values that cannot even be
sent (not integers, BOOLs, beyond 32 bits) are refused by the block with 0x4B0B.

**Signal source PlcEvent** (10): handled in the block, nothing is sent. While the block is Busy,
an edge of ``TriggerInput.PlcEvent`` (rising, or falling with Edge = FallingEdge; an edge in
the cycle of Execute's rising edge counts) records the axis's ActPos of this cycle's snapshot
(ModuloActPos with ModuloPositions): cycle-time dependent, not a latch, as TcMC says. With
WindowOnly a position outside the window is rejected and the next edge awaited: with
ModuloPositions the window repeats every modulo period (FirstPosition..LastPosition compared
with ModuloActPos; FirstPosition > LastPosition wraps through 0, i.e. accepts >= FirstPosition
or <= LastPosition); absolute windows are the one interval FirstPosition..LastPosition, and an
absolute window with FirstPosition > LastPosition is empty: zenoh-nc refuses it at the start
with Error 0x4B06 instead of waiting for ever (both bounds inclusive). The block checks the
TriggerInput itself: EncoderID an integer 1..255, Edge 0 or 1, else 0x4B0B. Stale axis data
while waiting: 0x4B0F.

Both sources (TcMC 4.21): once started, a probe cycle ends only with Done, Error or
CommandAborted - Execute falling does not end it (the end output is then TRUE for one cycle,
the general output rule). ``TriggerInput.ProbeState``: TouchProbeActivated while the block is
Busy, TouchProbeAborted after CommandAborted, TouchProbeInactive after Done or Error.
RecordedPosition keeps its value until the next rising edge (it is a value, not a result flag).
Non-finite FirstPosition/LastPosition with WindowOnly: Error 0x4B06, nothing armed (without
WindowOnly they are not used, TcMC: "if WindowOnly is TRUE"; non-finite values then go out as
0.0). TriggerInput not given: 0x4B0B.

MC_AbortTrigger: NC sources - sends ``AbortTrigger`` and is Done once the NC accepted it and a
frame of the reply's cycle arrived (the MC_TouchProbe then sees its cycle ABORTED). PlcEvent -
sets ``TriggerInput.ProbeState := TouchProbeAborted`` and is Done in the same cycle; the
MC_TouchProbe using that MC_InputRef reports CommandAborted on its next call. Outputs: Done,
Busy, Error, ErrorID.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Self

from nc_schema import CmdState, E_SignalEdge, E_TouchProbe, E_TouchProbeState, ErrorCodes

from ..axis_ref import AXIS_REF
from .base import ExecuteBlock
from .coupling import _integer_in


_PLC_EVENT = int(E_TouchProbe["PlcEvent"])
_RISING, _FALLING = int(E_SignalEdge["RisingEdge"]), int(E_SignalEdge["FallingEdge"])
_INACTIVE = E_TouchProbeState["TouchProbeInactive"]
_ACTIVATED = E_TouchProbeState["TouchProbeActivated"]
_ABORTED_STATE = E_TouchProbeState["TouchProbeAborted"]
_DONE, _ABORTED, _ERROR = int(CmdState.DONE), int(CmdState.ABORTED), int(CmdState.ERROR)
_INT32 = (-(2**31), 2**31 - 1)


@dataclass
class MC_InputRef:
    """The trigger signal source of a touch probe (TcMC 6.3 MC_InputRef).

    Attributes:
        EncoderID: encoder of the drive hardware (1..255).
        TouchProbe: E_TouchProbe signal source (TouchProbe1, or PlcEvent: the PLC's own signal).
        Edge: E_SignalEdge, which edge of the signal is evaluated.
        PlcEvent: the PLC trigger signal when TouchProbe is PlcEvent.
        ProbeState: E_TouchProbeState, written by MC_TouchProbe / MC_AbortTrigger (do not write).
        ModuloPositions: FirstPosition, LastPosition and RecordedPosition are modulo values.
    """

    EncoderID: int = 1
    TouchProbe: int = E_TouchProbe["TouchProbe1"]
    Edge: int = E_SignalEdge["RisingEdge"]
    PlcEvent: bool = False
    ProbeState: int = _INACTIVE
    ModuloPositions: bool = False


def _is_plc_event(ref: MC_InputRef) -> bool:
    return _integer_in(ref.TouchProbe, *_INT32) == _PLC_EVENT


def in_window(position: float, first: float, last: float, modulo: bool) -> bool:
    """Whether a recorded position lies in the window FirstPosition..LastPosition (inclusive);
    a modulo window with first > last wraps through 0."""
    if modulo and first > last:
        return position >= first or position <= last
    return first <= position <= last


class _TriggerBlock(ExecuteBlock):
    """An Execute block with the VAR_IN_OUT TriggerInput (an MC_InputRef) besides the Axis."""

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self.TriggerInput: MC_InputRef | None = None

    def __call__(self, Axis: AXIS_REF | None = None, TriggerInput: MC_InputRef | None = None,
                 **inputs: Any) -> Self:
        if TriggerInput is not None:
            if not isinstance(TriggerInput, MC_InputRef):
                raise TypeError(f"{type(self).__name__}: TriggerInput must be an MC_InputRef, "
                                f"got {type(TriggerInput).__name__}")
            self.TriggerInput = TriggerInput
        return super().__call__(Axis=Axis, **inputs)


class MC_TouchProbe(_TriggerBlock):
    """Record the axis position at a trigger event (TcMC 4.21); see the module docstring.

    Inputs: Execute, WindowOnly, FirstPosition [u], LastPosition [u]. Outputs: Done, Busy,
    CommandAborted, Error, ErrorID, RecordedPosition [u]. VAR_IN_OUT: TriggerInput (MC_InputRef),
    Axis.
    """

    _INPUTS = {"Execute": False, "WindowOnly": False, "FirstPosition": 0.0, "LastPosition": 0.0}
    _OUTPUTS = {"Done": False, "Busy": False, "CommandAborted": False, "Error": False, "ErrorID": 0,
                "RecordedPosition": 0.0}
    WindowOnly: bool
    FirstPosition: float
    LastPosition: float
    RecordedPosition: float

    def __init__(self, timeout: float | None = None) -> None:
        super().__init__(timeout)
        self._ref: MC_InputRef | None = None  # the TriggerInput of the running cycle
        self._plc_event = False
        self._probe_no = 0
        self._probe_cycle = 0
        # PlcEvent: the latched trigger settings and the signal's previous level (every call)
        self._edge = _RISING
        self._modulo = False
        self._window: tuple[float, float] | None = None
        self._prev_level = False
        self._rose = self._fell = False

    def _cycle(self) -> None:
        ref = self.TriggerInput
        level = bool(ref.PlcEvent) if ref is not None else False
        # the signal's edges of this cycle, whatever the block does (an edge at Execute's edge counts)
        self._rose, self._fell = level and not self._prev_level, self._prev_level and not level
        self._prev_level = level
        super()._cycle()

    def _reset_outputs(self) -> None:
        # RecordedPosition survives the falling edge (cleared by the next start)
        keep = getattr(self, "RecordedPosition", 0.0)
        super()._reset_outputs()
        self.RecordedPosition = keep

    def _finish(self, result: str, error_id: int = 0) -> None:
        super()._finish(result, error_id)
        if self._ref is not None:
            self._ref.ProbeState = _ABORTED_STATE if result == "CommandAborted" else _INACTIVE

    # -- start -----------------------------------------------------------------------------
    def _start(self) -> None:
        self.RecordedPosition = 0.0
        self._probe_no, self._probe_cycle, self._window = 0, 0, None
        self._cycle_no = 0
        ref = self._ref = self.TriggerInput
        if ref is None:
            self._finish("Error", ErrorCodes.MC_TRIGGER_INPUT_INVALID)
            return
        window_only = bool(self.WindowOnly)
        reals = self._is_real(self.FirstPosition) and self._is_real(self.LastPosition)
        if window_only and not reals:
            self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)
            return
        # (without WindowOnly the window is not used, TcMC 4.21: non-finite bounds go out as 0.0)
        first, last = (float(self.FirstPosition), float(self.LastPosition)) if reals else (0.0, 0.0)
        self._plc_event = _is_plc_event(ref)
        if self._plc_event:
            self._start_plc_event(ref, window_only, first, last)
            return
        encoder = _integer_in(ref.EncoderID, *_INT32)
        source = _integer_in(ref.TouchProbe, *_INT32)
        edge = _integer_in(ref.Edge, *_INT32)
        if encoder is None or source is None or edge is None:
            self._finish("Error", ErrorCodes.MC_TRIGGER_INPUT_INVALID)
            return
        if self._send("TouchProbe", EncoderID=encoder, TouchProbe=source, Edge=edge,
                      ModuloPositions=bool(ref.ModuloPositions), WindowOnly=window_only,
                      FirstPosition=first, LastPosition=last):
            ref.ProbeState = _ACTIVATED

    def _start_plc_event(self, ref: MC_InputRef, window_only: bool, first: float, last: float) -> None:
        edge = _integer_in(ref.Edge, _RISING, _FALLING)
        if _integer_in(ref.EncoderID, 1, 255) is None or edge is None:
            self._finish("Error", ErrorCodes.MC_TRIGGER_INPUT_INVALID)
            return
        self._modulo = bool(ref.ModuloPositions)
        if window_only:
            if not self._modulo and first > last:
                self._finish("Error", ErrorCodes.MC_PARAMETER_NOT_CORRECT)  # an empty absolute window
                return
            self._window = (first, last)
        ax = self._usable_axis()
        if ax is None:
            return
        self._epoch = ax.nc_epoch
        self._edge = edge
        ref.ProbeState = _ACTIVATED
        self._watch_plc_event()

    # -- progress ----------------------------------------------------------------------------
    def _progress(self) -> None:
        if self._plc_event:
            if not self._lost_axis():
                self._watch_plc_event()
            return
        if not self._probe_no:
            got = self._accepted()
            if got is None:
                return
            self._probe_no, self._probe_cycle, _ = got
        self._follow()

    def _watch_plc_event(self) -> None:
        ref = self._ref
        assert ref is not None and self.Axis is not None
        if ref.ProbeState == _ABORTED_STATE:
            self._finish("CommandAborted")  # MC_AbortTrigger
            return
        if not (self._fell if self._edge == _FALLING else self._rose):
            return
        rec = self.Axis.NcToPlc
        pos = float(rec["ModuloActPos"] if self._modulo else rec["ActPos"])
        if self._window is not None and not in_window(pos, *self._window, self._modulo):
            return  # rejected: wait for the next edge
        self.RecordedPosition = pos
        self._finish("Done")

    def _follow(self) -> None:
        got = self._own_slot("ProbeCmdNo", "ProbeState", self._probe_no, self._probe_cycle)
        if got is None:
            return
        state, jobs = got
        if state == _DONE:
            self.RecordedPosition = float(jobs["RecordedPosition"])
            self._finish("Done")
        elif state == _ABORTED:
            self._finish("CommandAborted")
        elif state == _ERROR:
            self._finish("Error", int(jobs["ProbeErrorId"]) or ErrorCodes.MC_LATCH_DISABLED)
        # ACTIVE: the latch is armed - Busy


class MC_AbortTrigger(_TriggerBlock):
    """Interrupt a touch probe cycle (TcMC 4.22); see the module docstring.

    Inputs: Execute. Outputs: Done, Busy, Error, ErrorID. VAR_IN_OUT: TriggerInput (the same
    MC_InputRef as the MC_TouchProbe's), Axis.
    """

    _OUTPUTS = {"Done": False, "Busy": False, "Error": False, "ErrorID": 0}

    def _start(self) -> None:
        self._cycle_no = 0
        ref = self.TriggerInput
        if ref is None:
            self._finish("Error", ErrorCodes.MC_TRIGGER_INPUT_INVALID)
            return
        if _is_plc_event(ref):
            ref.ProbeState = _ABORTED_STATE  # the MC_TouchProbe with this MC_InputRef ends CommandAborted
            self._finish("Done")
            return
        self._send("AbortTrigger")

    def _progress(self) -> None:
        if self._reply_shown():
            self._finish("Done")
