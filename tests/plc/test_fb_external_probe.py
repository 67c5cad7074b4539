"""MC_ExtSetPointGenEnable / Disable / Feed and MC_TouchProbe / MC_AbortTrigger against the wire
contract alone (a scripted NC): the PLCTONC fields the blocks write, the requests, the job record's
probe slot (NCJOBS.ProbeCmdNo / ProbeState / RecordedPosition), and the PlcEvent touch probe the
block runs itself (windows, edges, MC_AbortTrigger)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from nc_schema import PLCTONC_DTYPE, ErrorCodes
from plc_client import (
    AXIS_REF, E_SignalEdge, E_TargPosType, E_TouchProbe, E_TouchProbeState, MC_AbortTrigger,
    MC_ExtSetPointGenDisable, MC_ExtSetPointGenEnable, MC_ExtSetPointGenFeed, MC_InputRef, MC_TouchProbe,
)
from znc_testing.plc_rig import ABORTED, ACTIVE, DONE, ERROR, IDLE, S, Rig, ScriptNc, powered

EXT = int(S.ExtSetPointGenEnabled)


def drive(nc: ScriptNc, fb: Any, **inputs: Any) -> dict[str, Any]:
    st = {"Axis": nc.ax, **inputs}
    nc.calls.append(lambda: fb(**st))
    nc.watched.append(fb)
    return st


def go_stale(nc: ScriptNc, fb: Any) -> None:
    """The NC's cycle stops advancing until fb reports an error."""
    for _ in range(nc.stale_cycles + 1):
        nc.nc_cycle -= 10
        nc.cycle_once()
        if fb.Error:
            return


# ---- MC_ExtSetPointGenEnable / Disable ---------------------------------------------------------------
def test_enable_writes_the_set_position_before_the_command(nc: ScriptNc) -> None:
    nc.state(IDLE, SetPos=12.5, ActPos=12.49)
    nc.cycle_once()
    out = nc.ax.PlcToNc
    out["ExtSetPos"], out["ExtSetVelo"], out["ExtSetAcc"], out["ExtSetDirection"] = 99.0, 3.0, 4.0, 1
    at_send: list[tuple] = []
    orig = nc.port._transmit

    def spy(pending: Any, payload: bytes) -> None:
        at_send.append((float(out["ExtSetPos"]), float(out["ExtSetVelo"]), float(out["ExtSetAcc"]),
                        int(out["ExtSetDirection"])))
        orig(pending, payload)

    nc.port._transmit = spy  # type: ignore[method-assign]
    fb = MC_ExtSetPointGenEnable()
    st = drive(nc, fb, Execute=True, Position=50.0, PositionType=E_TargPosType.POS_ABSOLUTE)
    nc.cycle_once()
    assert at_send == [(12.5, 0.0, 0.0, 0)], "SetPos into ExtSetPos, the rest 0, before the request"
    p = nc.last_sent("ExtSetPointGenEnable")
    assert p.args == {"Position": 50.0, "PositionType": 1} and type(p.args["PositionType"]) is int
    assert fb.Busy and not fb.Done and not fb.Enabled
    nc.port.answer(p, cycle=nc.nc_cycle + 5)
    nc.cycle_once()
    assert fb.Busy and not fb.Done, "the reply's frame is not there yet"
    nc.state(IDLE | EXT)
    nc.cycle_once()
    assert fb.Done and fb.Enabled and not fb.Busy
    st["Execute"] = False
    nc.cycle_once()
    assert not fb.Done and fb.Enabled, "Enabled is independent of Execute"


def test_enable_on_an_enabled_generator_leaves_the_feed(nc: ScriptNc) -> None:
    """TcMC 4.16: Position is for target position monitoring only, "the external set value generator is
    responsible" for the motion: a second enable must not replace the generator's fed set-point by a seed
    at velocity 0 (over the real NC: a velocity step, axis error 0x4359, test below)."""
    nc.state(IDLE | EXT, SetPos=12.5, ActPos=12.49)
    nc.cycle_once()
    out = nc.ax.PlcToNc
    out["ExtSetPos"], out["ExtSetVelo"], out["ExtSetAcc"], out["ExtSetDirection"] = 13.0, 200.0, 0.0, 1
    fb = MC_ExtSetPointGenEnable()
    drive(nc, fb, Execute=True, Position=50.0)
    nc.cycle_once()
    assert (float(out["ExtSetPos"]), float(out["ExtSetVelo"]), int(out["ExtSetDirection"])) == (13.0, 200.0, 1)
    assert nc.last_sent("ExtSetPointGenEnable").args == {"Position": 50.0, "PositionType": 1}, "the NC answers"


def test_enable_again_while_feeding_at_speed_keeps_the_axis_running() -> None:
    rig = Rig()
    ax, _, calls = powered(rig)
    en = rig.watch(MC_ExtSetPointGenEnable())
    st: dict[str, Any] = {"ex": True, "p": 0.0, "v": 0.0, "feed": False}

    def body(p: Any) -> None:
        if st["feed"]:  # the generator runs first in the program, the block after it
            MC_ExtSetPointGenFeed(st["p"], st["v"], 0.0, 1 if st["v"] > 0 else 0, ax)
        en(Axis=ax, Execute=st["ex"], Position=100.0)

    calls["body"] = body
    rig.run_until(lambda: en.Done, 10)
    st.update(feed=True, p=float(ax.NcToPlc["SetPos"]))
    for k in range(20):  # up to 300 u/s at 2000 u/s^2
        st["v"] = min(300.0, st["v"] + 20.0)
        st["p"] += st["v"] * 0.01
        rig.run(1)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 300.0) and not ax.Status.Error
    for ex in (False, True, True, True):
        st["ex"] = ex
        st["p"] += st["v"] * 0.01
        rig.run(1)
    assert en.Error and en.ErrorID == ErrorCodes.MC_AXIS_PROTECTED, "the NC refuses it"
    assert not ax.Status.Error, f"axis error 0x{ax.Status.ErrorId:X}"
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 300.0) and en.Enabled


def test_enabled_shows_the_axis_state_without_execute(nc: ScriptNc) -> None:
    on, off = MC_ExtSetPointGenEnable(), MC_ExtSetPointGenDisable()
    drive(nc, on)
    drive(nc, off)
    nc.cycle_once()
    assert not on.Enabled and not off.Enabled
    nc.state(IDLE | EXT)
    nc.cycle_once()
    assert on.Enabled and off.Enabled and not on.Busy and not nc.port.sent
    for _ in range(nc.stale_cycles + 1):
        nc.nc_cycle -= 10
        nc.cycle_once()
    assert not on.Enabled, "not valid data: FALSE"


def test_disable_done_once_shown(nc: ScriptNc) -> None:
    nc.state(IDLE | EXT)
    nc.cycle_once()
    fb = MC_ExtSetPointGenDisable()
    drive(nc, fb, Execute=True)
    nc.cycle_once()
    assert fb.Enabled and fb.Busy
    p = nc.last_sent("ExtSetPointGenDisable")
    assert p.args == {}
    nc.port.answer(p, cycle=nc.nc_cycle)
    nc.state(IDLE)
    nc.cycle_once()
    assert fb.Done and not fb.Enabled


@pytest.mark.parametrize("block", [MC_ExtSetPointGenEnable, MC_ExtSetPointGenDisable])
def test_enable_disable_refused_by_the_nc(nc: ScriptNc, block: type) -> None:
    fb = block()
    drive(nc, fb, Execute=True)
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == 0x4B01 and not fb.Done and not fb.Busy


@pytest.mark.parametrize("inputs, code", [
    ({"PositionType": 3}, ErrorCodes.MC_INVALID_MODE),
    ({"PositionType": True}, ErrorCodes.MC_INVALID_MODE),
    ({"PositionType": 1.0}, ErrorCodes.MC_INVALID_MODE),
    ({"Position": math.nan}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
    ({"Position": "0"}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
])
def test_enable_invalid_inputs_write_and_send_nothing(nc: ScriptNc, inputs: dict, code: int) -> None:
    nc.state(IDLE, SetPos=7.0)
    fb = MC_ExtSetPointGenEnable()
    drive(nc, fb, Execute=True, **inputs)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == code and not nc.port.sent
    assert nc.ax.PlcToNc["ExtSetPos"] == 0.0


def test_enable_on_stale_axis_writes_nothing(nc: ScriptNc) -> None:
    ax = AXIS_REF(nc="nc2", axis_id=1)  # no frames from nc2
    fb = MC_ExtSetPointGenEnable()
    nc.calls.append(lambda: fb(Axis=ax, Execute=True))
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE and not nc.port.sent
    assert not fb.Enabled


# ---- MC_ExtSetPointGenFeed ---------------------------------------------------------------------------
def test_feed_copies_into_the_plctonc_record() -> None:
    ax = AXIS_REF(nc="nc1", axis_id=1)
    assert MC_ExtSetPointGenFeed(1.5, 2.5, -3.5, 1, ax.PlcToNc) is False
    out = ax.PlcToNc
    assert (out["ExtSetPos"], out["ExtSetVelo"], out["ExtSetAcc"], out["ExtSetDirection"]) == (1.5, 2.5, -3.5, 1)
    assert MC_ExtSetPointGenFeed(Position=4.0, Velocity=-1.0, Acceleration=0.0, Direction=-1, AxisRefOut=ax) is False
    assert (out["ExtSetPos"], out["ExtSetVelo"], out["ExtSetDirection"]) == (4.0, -1.0, -1)
    rec = np.zeros(1, dtype=PLCTONC_DTYPE)[0]
    MC_ExtSetPointGenFeed(np.float32(0.5), np.float64(1.0), 0, np.int64(0), rec)
    assert rec["ExtSetPos"] == 0.5 and rec["ExtSetDirection"] == 0


@pytest.mark.parametrize("args", [
    (math.nan, 0.0, 0.0, 0), (1.0, math.inf, 0.0, 0), (1.0, 0.0, None, 0), (1.0, 0.0, 0.0, 2),
    (1.0, 0.0, 0.0, 0.5), (1.0, 0.0, 0.0, True), ("1", 0.0, 0.0, 0),
])
def test_feed_with_a_bad_value_keeps_the_last_set_point(args: tuple) -> None:
    ax = AXIS_REF(nc="nc1", axis_id=1)
    MC_ExtSetPointGenFeed(10.0, 1.0, 0.5, 1, ax)
    assert MC_ExtSetPointGenFeed(*args, ax) is False
    out = ax.PlcToNc
    assert (out["ExtSetPos"], out["ExtSetVelo"], out["ExtSetAcc"], out["ExtSetDirection"]) == (10.0, 1.0, 0.5, 1)


def test_feed_needs_a_plctonc_record() -> None:
    with pytest.raises(TypeError):
        MC_ExtSetPointGenFeed(1.0, 0.0, 0.0, 0, "axis 1")  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        MC_ExtSetPointGenFeed(1.0, 0.0, 0.0, 0, AXIS_REF().NcToPlc)  # the wrong record


# ---- MC_InputRef ---------------------------------------------------------------------------------------
def test_input_ref_defaults() -> None:
    r = MC_InputRef()
    assert (r.EncoderID, r.TouchProbe, r.Edge, r.PlcEvent, r.ProbeState, r.ModuloPositions) == (
        1, E_TouchProbe.TouchProbe1, E_SignalEdge.RisingEdge, False, E_TouchProbeState.TouchProbeInactive, False)
    assert int(E_TouchProbe.PlcEvent) == 10
    r.PlcEvent = True  # mutable
    assert MC_InputRef() != r


# ---- MC_TouchProbe: PlcEvent ----------------------------------------------------------------------------
def plc_probe(nc: ScriptNc, **inputs: Any) -> tuple[MC_TouchProbe, MC_InputRef, dict[str, Any]]:
    ref = MC_InputRef(TouchProbe=E_TouchProbe.PlcEvent)
    for k in ("Edge", "ModuloPositions", "EncoderID"):
        if k in inputs:
            setattr(ref, k, inputs.pop(k))
    tp = MC_TouchProbe()
    st = drive(nc, tp, TriggerInput=ref, **{"Execute": True, **inputs})
    return tp, ref, st


def test_plc_event_records_the_actual_position(nc: ScriptNc) -> None:
    tp, ref, st = plc_probe(nc)
    nc.state(IDLE, ActPos=10.0, ModuloActPos=10.0)
    nc.cycle_once(2)
    assert tp.Busy and ref.ProbeState == E_TouchProbeState.TouchProbeActivated
    nc.state(IDLE, ActPos=12.25, ModuloActPos=12.25)
    ref.PlcEvent = True
    nc.cycle_once()
    assert tp.Done and tp.RecordedPosition == 12.25 and not tp.Busy
    assert ref.ProbeState == E_TouchProbeState.TouchProbeInactive
    assert not nc.port.sent, "PlcEvent is handled in the block"
    st["Execute"] = False
    nc.cycle_once()
    assert not tp.Done and tp.RecordedPosition == 12.25, "the value is kept after the falling edge"
    ref.PlcEvent = False
    st["Execute"] = True
    nc.cycle_once()
    assert tp.Busy and tp.RecordedPosition == 0.0


def test_plc_event_level_already_true_is_not_an_edge(nc: ScriptNc) -> None:
    tp, ref, st = plc_probe(nc, Execute=False)
    ref.PlcEvent = True
    nc.cycle_once()
    st["Execute"] = True
    nc.cycle_once(3)
    assert tp.Busy, "the signal was already TRUE: wait for an edge"
    ref.PlcEvent = False
    nc.cycle_once()
    ref.PlcEvent = True
    nc.cycle_once()
    assert tp.Done


def test_plc_event_edge_in_the_cycle_of_execute_counts(nc: ScriptNc) -> None:
    nc.state(IDLE, ActPos=3.0)
    tp, ref, _ = plc_probe(nc)
    ref.PlcEvent = True
    nc.cycle_once()
    assert tp.Done and tp.RecordedPosition == 3.0


def test_plc_event_falling_edge(nc: ScriptNc) -> None:
    nc.state(IDLE, ActPos=4.0)
    tp, ref, _ = plc_probe(nc, Edge=E_SignalEdge.FallingEdge)
    nc.cycle_once()
    ref.PlcEvent = True
    nc.cycle_once(2)
    assert tp.Busy
    ref.PlcEvent = False
    nc.cycle_once()
    assert tp.Done and tp.RecordedPosition == 4.0


def pulse(nc: ScriptNc, **pos: float) -> None:
    """One PlcEvent pulse (rising edge in the first cycle) with the axis at ``pos``."""
    tp_ref = nc.ref  # type: ignore[attr-defined]
    nc.state(IDLE, **pos)
    tp_ref.PlcEvent = True
    nc.cycle_once()
    tp_ref.PlcEvent = False
    nc.cycle_once()


def test_plc_event_absolute_window(nc: ScriptNc) -> None:
    tp, ref, _ = plc_probe(nc, WindowOnly=True, FirstPosition=100.0, LastPosition=200.0)
    nc.ref = ref  # type: ignore[attr-defined]
    nc.cycle_once()
    for outside in (99.9, 200.1, -150.0):
        pulse(nc, ActPos=outside, ModuloActPos=150.0)
        assert tp.Busy and not tp.Done, f"{outside} is outside the window"
    pulse(nc, ActPos=200.0, ModuloActPos=0.0)
    assert tp.Done and tp.RecordedPosition == 200.0, "bounds are inclusive"


def test_plc_event_modulo_window_repeats_and_wraps(nc: ScriptNc) -> None:
    tp, ref, st = plc_probe(nc, ModuloPositions=True, WindowOnly=True, FirstPosition=350.0, LastPosition=10.0)
    nc.ref = ref  # type: ignore[attr-defined]
    nc.cycle_once()
    pulse(nc, ActPos=1000.0, ModuloActPos=180.0)
    assert tp.Busy
    pulse(nc, ActPos=1075.0, ModuloActPos=355.0)
    assert tp.Done and tp.RecordedPosition == 355.0, "modulo positions, the window wraps through 0"
    st["Execute"] = False
    nc.cycle_once()
    st.update(Execute=True, FirstPosition=90.0, LastPosition=95.0)
    nc.cycle_once()
    pulse(nc, ActPos=365.0, ModuloActPos=5.0)
    assert tp.Busy
    pulse(nc, ActPos=812.0, ModuloActPos=92.0)
    assert tp.Done and tp.RecordedPosition == 92.0, "the window repeats every period"


def test_plc_event_empty_absolute_window_is_refused(nc: ScriptNc) -> None:
    tp, ref, _ = plc_probe(nc, WindowOnly=True, FirstPosition=200.0, LastPosition=100.0)
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT
    assert ref.ProbeState == E_TouchProbeState.TouchProbeInactive


def test_plc_event_window_ignored_without_window_only(nc: ScriptNc) -> None:
    tp, ref, _ = plc_probe(nc, WindowOnly=False, FirstPosition=200.0, LastPosition=100.0)
    nc.ref = ref  # type: ignore[attr-defined]
    nc.cycle_once()
    pulse(nc, ActPos=7.0)
    assert tp.Done and tp.RecordedPosition == 7.0


def test_plc_event_execute_falling_does_not_end_the_cycle(nc: ScriptNc) -> None:
    tp, ref, st = plc_probe(nc)
    nc.cycle_once()
    st["Execute"] = False
    nc.cycle_once(3)
    assert tp.Busy and ref.ProbeState == E_TouchProbeState.TouchProbeActivated
    nc.state(IDLE, ActPos=1.0)
    ref.PlcEvent = True
    nc.cycle_once(3)
    assert nc.history(tp, "Done").count(True) == 1 and not tp.Done


def test_plc_event_rising_edge_while_busy_ignored(nc: ScriptNc) -> None:
    tp, ref, st = plc_probe(nc, WindowOnly=True, FirstPosition=0.0, LastPosition=1.0)
    nc.ref = ref  # type: ignore[attr-defined]
    nc.cycle_once()
    st["Execute"] = False
    nc.cycle_once()
    st.update(Execute=True, FirstPosition=5.0, LastPosition=6.0)  # ignored: the window stays latched
    nc.cycle_once()
    pulse(nc, ActPos=5.5)
    assert tp.Busy
    pulse(nc, ActPos=0.5)
    assert tp.Done


@pytest.mark.parametrize("execute_fell", [False, True])
def test_abort_trigger_plc_event(nc: ScriptNc, execute_fell: bool) -> None:
    tp, ref, st = plc_probe(nc)
    nc.cycle_once()
    if execute_fell:
        st["Execute"] = False
        nc.cycle_once()
    ab = MC_AbortTrigger()
    ast = drive(nc, ab, TriggerInput=ref, Execute=True)
    nc.cycle_once()
    assert ab.Done and not ab.Busy and not nc.port.sent
    assert ref.ProbeState == E_TouchProbeState.TouchProbeAborted
    nc.cycle_once()  # the probe block was called before the abort in that cycle: it sees it now
    assert tp.CommandAborted and not tp.Busy and not tp.Done
    assert ref.ProbeState == E_TouchProbeState.TouchProbeAborted
    nc.cycle_once()
    assert tp.CommandAborted is (not execute_fell)
    ast["Execute"] = False
    nc.cycle_once()
    assert not ab.Done


@pytest.mark.parametrize("field, value", [("EncoderID", 0), ("EncoderID", 256), ("EncoderID", 1.0),
                                          ("Edge", 2), ("Edge", True), ("Edge", None)])
def test_plc_event_bad_trigger_input(nc: ScriptNc, field: str, value: Any) -> None:
    tp, ref, _ = plc_probe(nc, **{field: value})
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == ErrorCodes.MC_TRIGGER_INPUT_INVALID == 0x4B0B and not nc.port.sent


def test_plc_event_stale_axis(nc: ScriptNc) -> None:
    tp, ref, _ = plc_probe(nc)
    nc.cycle_once()
    go_stale(nc, tp)
    assert tp.Error and tp.ErrorID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE
    assert ref.ProbeState == E_TouchProbeState.TouchProbeInactive


@pytest.mark.parametrize("bad", [{"FirstPosition": math.nan}, {"LastPosition": "1"}])
def test_touch_probe_non_finite_window(nc: ScriptNc, bad: dict) -> None:
    tp, _, _ = plc_probe(nc, WindowOnly=True, **bad)
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == 0x4B06


@pytest.mark.parametrize("source", [E_TouchProbe.PlcEvent, E_TouchProbe.TouchProbe1])
def test_touch_probe_window_inputs_unused_without_window_only(nc: ScriptNc, source: int) -> None:
    """TcMC 4.21: FirstPosition/LastPosition bound the window "if WindowOnly is TRUE"; without it their
    values (NaN here: an unset LREAL from a failed computation) do not stop the probe cycle."""
    ref = MC_InputRef(TouchProbe=source)
    tp = MC_TouchProbe()
    drive(nc, tp, TriggerInput=ref, Execute=True, WindowOnly=False, FirstPosition=math.nan, LastPosition="x")
    nc.cycle_once()
    assert tp.Busy and not tp.Error, f"0x{tp.ErrorID:X}"
    if source == E_TouchProbe.TouchProbe1:
        p = nc.last_sent("TouchProbe")
        assert p.args["WindowOnly"] is False and (p.args["FirstPosition"], p.args["LastPosition"]) == (0.0, 0.0)


def test_touch_probe_without_trigger_input(nc: ScriptNc) -> None:
    tp, ab = MC_TouchProbe(), MC_AbortTrigger()
    drive(nc, tp, Execute=True)
    drive(nc, ab, Execute=True)
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == 0x4B0B and ab.Error and ab.ErrorID == 0x4B0B
    with pytest.raises(TypeError):
        MC_TouchProbe()(Axis=nc.ax, TriggerInput={"TouchProbe": 10})


# ---- MC_TouchProbe: the drive's latch (the NC) ------------------------------------------------------------
def probe_slot(nc: ScriptNc, no: int, state: int, pos: float = 0.0, error: int = 0) -> None:
    assert nc.jobs is not None
    j = nc.jobs[0]
    j["ProbeCmdNo"], j["ProbeState"], j["RecordedPosition"], j["ProbeErrorId"] = no, state, pos, error
    if state == DONE:
        j["ProbeCounter"] += 1


def nc_probe(nc: ScriptNc, no: int, ref: MC_InputRef | None = None, **inputs: Any) -> tuple[MC_TouchProbe,
                                                                                            MC_InputRef, dict]:
    ref = ref or MC_InputRef()
    tp = MC_TouchProbe()
    st = drive(nc, tp, TriggerInput=ref, Execute=True, **inputs)
    nc.cycle_once()
    assert tp.Busy
    nc.port.answer(nc.port.sent[-1], cycle=nc.nc_cycle, cmdno=no)
    return tp, ref, st


def test_nc_probe_request_and_done(nc: ScriptNc) -> None:
    ref = MC_InputRef(EncoderID=3, Edge=E_SignalEdge.FallingEdge, ModuloPositions=True)
    tp, _, st = nc_probe(nc, 4, ref, WindowOnly=True, FirstPosition=350.0, LastPosition=10.0)
    p = nc.last_sent("TouchProbe")
    assert p.axis_id == 1 and p.args == {"EncoderID": 3, "TouchProbe": 1, "Edge": 1, "ModuloPositions": True,
                                         "WindowOnly": True, "FirstPosition": 350.0, "LastPosition": 10.0}
    assert all(type(p.args[k]) is int for k in ("EncoderID", "TouchProbe", "Edge"))
    assert ref.ProbeState == E_TouchProbeState.TouchProbeActivated
    probe_slot(nc, 4, ACTIVE)
    nc.cycle_once(3)
    assert tp.Busy and not tp.Done
    probe_slot(nc, 4, DONE, pos=2.75)
    nc.cycle_once()
    assert tp.Done and tp.RecordedPosition == 2.75 and not tp.Busy
    assert ref.ProbeState == E_TouchProbeState.TouchProbeInactive
    st["Execute"] = False
    nc.cycle_once()
    assert not tp.Done and tp.RecordedPosition == 2.75


def test_nc_probe_execute_fell_done_for_one_cycle(nc: ScriptNc) -> None:
    tp, _, st = nc_probe(nc, 4)
    st["Execute"] = False
    probe_slot(nc, 4, ACTIVE)
    nc.cycle_once(2)
    assert tp.Busy
    probe_slot(nc, 4, DONE, pos=1.0)
    nc.cycle_once(2)
    assert nc.history(tp, "Done").count(True) == 1 and not tp.Done


@pytest.mark.parametrize("how", ["aborted", "replaced"])
def test_nc_probe_aborted(nc: ScriptNc, how: str) -> None:
    tp, ref, _ = nc_probe(nc, 4)
    probe_slot(nc, 4, ACTIVE)
    nc.cycle_once()
    probe_slot(nc, 4, ABORTED) if how == "aborted" else probe_slot(nc, 5, ACTIVE)
    nc.cycle_once()
    assert tp.CommandAborted and not tp.Busy and not tp.Done
    assert ref.ProbeState == E_TouchProbeState.TouchProbeAborted


def test_nc_probe_error(nc: ScriptNc) -> None:
    tp, ref, _ = nc_probe(nc, 4)
    probe_slot(nc, 4, ERROR)
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == ErrorCodes.MC_LATCH_DISABLED
    assert ref.ProbeState == E_TouchProbeState.TouchProbeInactive
    tp2, _, _ = nc_probe(nc, 6)
    probe_slot(nc, 6, ERROR, error=0x4B0B)
    nc.cycle_once()
    assert tp2.Error and tp2.ErrorID == 0x4B0B  # the slot's ProbeErrorId


@pytest.mark.parametrize("slot", [0, 3])
def test_nc_probe_lost(nc: ScriptNc, slot: int) -> None:
    tp, _, _ = nc_probe(nc, 4)
    probe_slot(nc, slot, DONE)
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == ErrorCodes.MC_CMD_NOT_ACTIVE


def test_nc_probe_refused_by_the_nc(nc: ScriptNc) -> None:
    tp = MC_TouchProbe()
    ref = MC_InputRef(TouchProbe=E_TouchProbe.TouchProbe2)
    drive(nc, tp, TriggerInput=ref, Execute=True)
    nc.cycle_once()
    assert nc.last_sent("TouchProbe").args["TouchProbe"] == 2, "2..4 are the NC's to refuse"
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.MC_TRIGGER_INPUT_INVALID, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == 0x4B0B
    assert ref.ProbeState == E_TouchProbeState.TouchProbeInactive


@pytest.mark.parametrize("field, value", [("TouchProbe", "x"), ("TouchProbe", 1.0), ("EncoderID", True),
                                          ("Edge", 2**40)])
def test_nc_probe_unsendable_trigger_input(nc: ScriptNc, field: str, value: Any) -> None:
    ref = MC_InputRef()
    setattr(ref, field, value)
    tp = MC_TouchProbe()
    drive(nc, tp, TriggerInput=ref, Execute=True)
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == 0x4B0B and not nc.port.sent


def test_nc_probe_without_job_records() -> None:
    nc = ScriptNc(jobs=False)
    nc.cycle_once()
    tp, _, _ = nc_probe(nc, 4)
    nc.cycle_once()
    assert tp.Error and tp.ErrorID == ErrorCodes.MC_CMD_NOT_ACTIVE


def test_abort_trigger_nc_source(nc: ScriptNc) -> None:
    tp, ref, _ = nc_probe(nc, 4)
    probe_slot(nc, 4, ACTIVE)
    nc.cycle_once()
    ab = MC_AbortTrigger()
    drive(nc, ab, TriggerInput=ref, Execute=True)
    nc.cycle_once()
    p = nc.last_sent("AbortTrigger")
    assert p.args == {} and ab.Busy
    assert ref.ProbeState == E_TouchProbeState.TouchProbeActivated, "the NC's fate decides"
    nc.port.answer(p, cycle=nc.nc_cycle)
    probe_slot(nc, 4, ABORTED)
    nc.cycle_once()
    assert ab.Done and tp.CommandAborted and ref.ProbeState == E_TouchProbeState.TouchProbeAborted


def test_abort_trigger_nc_error(nc: ScriptNc) -> None:
    ab = MC_AbortTrigger()
    drive(nc, ab, TriggerInput=MC_InputRef(), Execute=True)
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.NC_FUNCTION_NOT_ALLOWED, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert ab.Error and ab.ErrorID == ErrorCodes.NC_FUNCTION_NOT_ALLOWED
