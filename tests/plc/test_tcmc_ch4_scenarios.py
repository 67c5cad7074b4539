"""Scenarios of the TcMC manual's chapter 4 (administration blocks) and 6 (MC_AxisPara) against a real NcCore,
written from outside the blocks (an audit; each names the manual's rule it checks)."""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import PARAMETERS, ErrorCodes as E, MC_AxisPara
from nc_server.core import AxisParams
from plc_client import (
    MC_AbortTrigger, MC_ChangeDynParam, MC_ExtSetPointGenDisable, MC_ExtSetPointGenEnable, MC_InputRef,
    MC_MoveAbsolute, MC_Power, MC_ReadAxisComponents, MC_ReadBoolParameter, MC_ReadParameter, MC_ReadParameterSet,
    MC_ReadStatus, MC_Reset, MC_SetActualPosition, MC_SetActualPositionOnTheFly, MC_SetOverride, MC_SetReferenceFlag,
    MC_Stop, MC_WriteBoolParameter, MC_WriteParameter,
)
from znc_testing.plc_rig import Rig, powered


def test_reset_with_nothing_to_reset_is_done(rig: Rig) -> None:
    """4.2: Done "if the reset command is executed without error feedback" - also on an axis without an error."""
    ax, _, calls = powered(rig)
    rst = rig.watch(MC_Reset())
    calls["body"] = lambda p: rst(Axis=ax, Execute=True)
    rig.run_until(lambda: not rst.Busy, 5)
    assert rst.Done and not rst.Error


@pytest.mark.parametrize("ov", [-0.001, 100.0001, math.nan, math.inf, True, "50"])
def test_power_override_outside_0_to_100(rig: Rig, ov: Any) -> None:
    """4.1 Override in percent: outside 0..100 (or not a number) Error 0x4B06, the last valid override stays."""
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    pw = MC_Power()
    plc.program = lambda p: pw(Axis=ax, Enable=True, Override=ov)
    rig.run(3)
    assert pw.Error and pw.ErrorID == E.MC_PARAMETER_NOT_CORRECT
    assert int(rig.core.plctonc["Override"][0]) == 1_000_000 and pw.Status


def test_read_status_flags_in_each_state(rig: Rig) -> None:
    """4.4: one PLCopen state flag at a time through Standstill, DiscreteMotion, Stopping, Errorstop."""
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    pw, rs, stop, mv = MC_Power(), MC_ReadStatus(), MC_Stop(), MC_MoveAbsolute()
    st = {"en": False, "stop": False, "mv": False}
    plc.program = lambda p: (pw(Axis=ax, Enable=st["en"], Enable_Positive=True, Enable_Negative=True),
                             rs(Axis=ax, Enable=True), stop(Axis=ax, Execute=st["stop"]),
                             mv(Axis=ax, Execute=st["mv"], Position=50.0, Velocity=10.0))
    flags = ("Errorstop", "Stopping", "StandStill", "DiscreteMotion", "ContinuousMotion", "SynchronizedMotion",
             "Homing")

    def on() -> list[str]:
        return [f for f in flags if getattr(rs, f)]

    rig.run(2)
    assert on() == [] and rs.Done  # Disabled: TcMC's MC_ReadStatus has no flag for it
    for key, want in (("en", "StandStill"), ("mv", "DiscreteMotion"), ("stop", "Stopping")):
        st[key] = True
        rig.run(3)
        assert on() == [want]
    st["stop"] = False
    rig.run(2)
    assert on() == ["StandStill"]
    rig.core.fault(0, E.NC_POSITION_LAG)
    rig.run(2)
    assert on() == ["Errorstop"] and rs.Done and not rs.Error, "the read succeeded: Error is the block's"


def test_every_mc_axis_para_number_reads_with_its_type(rig: Rig) -> None:
    """6.1: every number of MC_AxisPara reads; MC_ReadBoolParameter for the (* bool *) ones."""
    ax, _, calls = powered(rig)
    fbs: dict[int, Any] = {}
    for m in MC_AxisPara:
        e = PARAMETERS.by_number(int(m))
        assert e is not None, m
        fbs[int(m)] = MC_ReadBoolParameter() if e.is_bool else MC_ReadParameter()
    calls["body"] = lambda p: [fb(Axis=ax, Enable=True, ParameterNumber=n) for n, fb in fbs.items()]
    rig.run(5)
    assert {n: fb.ErrorID for n, fb in fbs.items() if not fb.Done} == {}


@pytest.mark.parametrize("number", [1, 10, 11, 1000, 2000, 2001, 2002])
def test_write_of_a_status_parameter_is_refused(rig: Rig, number: int) -> None:
    """6.1 "axis status information - READ ONLY" (and the PLCopen actual/commanded values): a write is an error."""
    ax, _, calls = powered(rig)
    wp = MC_WriteParameter()
    calls["body"] = lambda p: wp(Axis=ax, Enable=True, ParameterNumber=number, Value=1.0)
    rig.run(3)
    assert wp.Error and wp.ErrorID == E.ADSERR_DEVICE_INVALIDACCESS


PAIRS = [(2, 1018, 123.0), (3, 1016, -77.0), (7, 1020, 3.5), (9, 1003, 700.0), (13, 1004, 4000.0),
         (15, 1005, 3000.0), (16, 1006, 40000.0), (8, 1007, 900.0)]


@pytest.mark.parametrize("a, b, v", PAIRS + [(b, a, v) for a, b, v in PAIRS])
def test_plcopen_and_beckhoff_numbers_of_one_parameter_agree(rig: Rig, a: int, b: int, v: float) -> None:
    """6.1: SWLimitPos/AxisMaxSoftPosLimit, MaxVelocityAppl/AxisVeloMax, ... name the same NC parameter."""
    ax, _, calls = powered(rig)
    w, r = MC_WriteParameter(), MC_ReadParameter()
    calls["body"] = lambda p: (w(Axis=ax, Enable=True, ParameterNumber=a, Value=v),
                               r(Axis=ax, Enable=w.Done, ParameterNumber=b))
    rig.run(6)
    assert w.Done and r.Done and r.Value == v


@pytest.mark.parametrize("want", [True, False])
@pytest.mark.parametrize("a, b", [(4, 1017), (5, 1015), (6, 1019), (1017, 4), (1015, 5), (1019, 6)])
def test_bool_parameter_numbers_agree(rig: Rig, a: int, b: int, want: bool) -> None:
    ax, _, calls = powered(rig)
    w, r = MC_WriteBoolParameter(), MC_ReadBoolParameter()
    calls["body"] = lambda p: (w(Axis=ax, Enable=True, ParameterNumber=a, Value=want),
                               r(Axis=ax, Enable=w.Done, ParameterNumber=b))
    rig.run(6)
    assert w.Done and r.Done and r.Value is want


CASES = [
    (MC_Reset, {}), (MC_SetOverride, {"Override": 50.0}), (MC_ReadParameterSet, {}), (MC_ReadAxisComponents, {}),
    (MC_SetActualPosition, {"Position": 3.0}),
    (MC_SetActualPositionOnTheFly, {"ActualPosition": 3.0, "PreviousPosition": 0.0}),
    (MC_SetReferenceFlag, {"ReferenceFlag": True}), (MC_ExtSetPointGenEnable, {"Position": 0.0}),
    (MC_ExtSetPointGenDisable, {}), (MC_ChangeDynParam, {"Acceleration": 100.0}), (MC_AbortTrigger, {}),
]


@pytest.mark.parametrize("cls, inputs", CASES)
@pytest.mark.parametrize("hold", [1, 30])
def test_result_for_one_cycle_or_while_execute(rig: Rig, cls: type, inputs: dict, hold: int) -> None:
    """Output rules (twincat-nc-reference 3.7, TcMC 7.1): a result (Done/Error/CommandAborted, exclusive) stays
    while Execute stays TRUE; after an Execute that fell before the end it is TRUE for one cycle."""
    ax, _, calls = powered(rig)
    fb = rig.watch(cls())
    extra = {"TriggerInput": MC_InputRef()} if cls is MC_AbortTrigger else {}
    st = {"ex": True}
    calls["body"] = lambda p: fb(Axis=ax, Execute=st["ex"], **extra, **inputs)
    rig.run(hold)
    st["ex"] = False
    rig.run(20)
    ends = [k for k, o in enumerate(rig.outputs(fb)) if any(o.get(n) for n in ("Done", "Error", "CommandAborted"))]
    assert ends
    if hold == 1:
        assert len(ends) == 1
    else:
        assert ends == list(range(ends[0], hold))


@pytest.mark.parametrize("dec_move, dec_new, braking", [(1000.0, 0.0, 5000.0), (1000.0, 3000.0, 3000.0)])
def test_change_dyn_param_zero_is_the_axis_default(dec_move: float, dec_new: float, braking: float) -> None:
    """4.20: "If the value is 0, the standard [deceleration] from the axis configuration ... is used" - also
    when the move had its own Deceleration; Done at the destination."""
    rig = Rig(params=AxisParams(AxisJerk=1e7))
    ax, _, calls = powered(rig)
    mv, cd = rig.watch(MC_MoveAbsolute(), MC_ChangeDynParam())
    st = {"cd": False}
    accs: list[float] = []

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Position=200.0, Velocity=200.0, Deceleration=dec_move)
        cd(Axis=ax, Execute=st["cd"], Acceleration=0.0, Deceleration=dec_new, Jerk=0.0)
        accs.append(float(ax.NcToPlc["SetAcc"]))

    calls["body"] = body
    rig.run_until(lambda: ax.Status.ConstantVelocity, 300)
    st["cd"] = True
    rig.run(2)
    assert cd.Busy
    accs.clear()
    rig.run_until(lambda: mv.Done, 500)
    assert math.isclose(min(accs), -braking, rel_tol=1e-6) and cd.Done
