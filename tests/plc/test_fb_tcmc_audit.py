"""Conformance scenarios of the TcMC manual (3.1-3.6, 3.13, 3.15, appendix 7.1) seen from a PLC program:
the blocks against a real NcCore, cycle by cycle (the checks a TwinCAT or CODESYS user would try first).

Not the manual's words but zenoh-nc's documented choices (plc_client/fb/motion.py, the NC reference):
Busy and Active of the move blocks and of MC_Stop (Tc2_MC2/PLCopen outputs; TcMC's move blocks and MC_Stop
have only Done, CommandAborted, Error, ErrorID); the error codes (TwinCAT NC error table: the manual names
none), NaN/INF inputs as MC_ERROR_PARAMETER_NOT_CORRECT, Error reset by Execute falling; the MC_Stop lock
(0x42EF until Execute falls, from Beckhoff's state diagram, not TcMC 3.15)."""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import ErrorCodes as E
from nc_schema import MC_AxisStates as S
from nc_server.core import AxisParams
from plc_client import (MC_Jog, MC_MoveAbsolute, MC_MoveAbsoluteOrRestart, MC_MoveModulo, MC_MoveRelative,
                        MC_MoveVelocity, MC_Power, MC_Stop)
from znc_testing.plc_rig import OffsetDrive, Rig, powered

POS, SHORT, NEG = 1, 2, 3
NAN, INF = float("nan"), float("inf")


def started(params: AxisParams | None = None, drive_cls: type | None = None) -> tuple[Rig, Any, dict]:
    rig = Rig(params=params, drive_cls=drive_cls)
    ax, _, calls = powered(rig)
    return rig, ax, calls


@pytest.mark.parametrize("block,inputs,code", [
    (MC_MoveAbsolute, dict(Position=10.0, Velocity=0.0), E.NC_VELOCITY_NOT_ALLOWED),
    (MC_MoveAbsolute, dict(Position=10.0, Velocity=-5.0), E.NC_VELOCITY_NOT_ALLOWED),
    (MC_MoveAbsolute, dict(Position=10.0, Velocity=NAN), E.MC_PARAMETER_NOT_CORRECT),
    (MC_MoveAbsolute, dict(Position=10.0, Velocity=INF), E.MC_PARAMETER_NOT_CORRECT),
    (MC_MoveAbsolute, dict(Position=NAN, Velocity=10.0), E.MC_PARAMETER_NOT_CORRECT),
    (MC_MoveAbsolute, dict(Position=10.0, Velocity=10.0, Acceleration=-1.0), 0x422F),
    (MC_MoveAbsolute, dict(Position=10.0, Velocity=10.0, Deceleration=-1.0), 0x4230),
    (MC_MoveAbsolute, dict(Position=10.0, Velocity=10.0, Jerk=-1.0), 0x422E),
    (MC_MoveRelative, dict(Distance=INF, Velocity=10.0), E.MC_PARAMETER_NOT_CORRECT),
    (MC_MoveRelative, dict(Distance=5.0, Velocity=0.0), E.NC_VELOCITY_NOT_ALLOWED),
    (MC_MoveVelocity, dict(Velocity=0.0), E.NC_VELOCITY_NOT_ALLOWED),
    (MC_MoveVelocity, dict(Velocity=-5.0), E.NC_VELOCITY_NOT_ALLOWED),
    (MC_MoveVelocity, dict(Velocity=1e9), E.NC_VELOCITY_NOT_ALLOWED),
    (MC_MoveModulo, dict(Position=400.0, Velocity=10.0, Direction=SHORT), E.NC_MODULO_TARGET_INVALID),
    (MC_MoveModulo, dict(Position=360.0, Velocity=10.0, Direction=SHORT), E.NC_MODULO_TARGET_INVALID),
    (MC_MoveModulo, dict(Position=-10.0, Velocity=10.0, Direction=POS), E.NC_MODULO_TARGET_INVALID),
    (MC_MoveModulo, dict(Position=10.0, Velocity=10.0, Direction=0), E.MC_INVALID_MODE),
    (MC_MoveModulo, dict(Position=10.0, Velocity=10.0, Direction=5), E.MC_INVALID_MODE),
    (MC_MoveAbsoluteOrRestart, dict(Position=10.0, Velocity=0.0), E.NC_VELOCITY_NOT_ALLOWED),
])
def test_invalid_inputs_are_an_error_held_while_execute_and_nothing_moves(block: type, inputs: dict, code: int) -> None:
    rig, ax, calls = started()
    fb = rig.watch(block())
    calls["body"] = lambda p: fb(Axis=ax, Execute=True, **inputs)
    rig.run(10)
    assert fb.Error and fb.ErrorID == code and not fb.Busy
    assert float(ax.NcToPlc["SetPos"]) == 0.0 and int(rig.rec()["ErrorCode"]) == 0  # no axis error
    calls["body"] = lambda p: fb(Axis=ax, Execute=False)
    rig.run(1)
    assert not fb.Error and fb.ErrorID == 0  # reset by the falling edge


@pytest.mark.parametrize("block,inputs", [
    (MC_MoveAbsolute, dict(Position=50.0, Velocity=100.0)),
    (MC_MoveRelative, dict(Distance=50.0, Velocity=100.0)),
    (MC_MoveModulo, dict(Position=50.0, Velocity=100.0, Direction=POS)),
    (MC_MoveAbsoluteOrRestart, dict(Position=50.0, Velocity=100.0)),
    (MC_MoveVelocity, dict(Velocity=100.0)),
])
@pytest.mark.parametrize("acc", [0.0, 300.0])
def test_zero_dynamics_mean_the_axis_defaults(block: type, inputs: dict, acc: float) -> None:
    """TcMC 3.1-3.4, 3.6: "Acceleration (>= 0). If the value is 0, the standard acceleration from the axis
    configuration in the System Manager is used." (Deceleration alike)."""
    rig, ax, calls = started(AxisParams(AxisAcc=1000.0, AxisDec=800.0))
    fb = rig.watch(block())
    acc_seen: list[float] = []

    def body(p: Any) -> None:
        fb(Axis=ax, Execute=True, Acceleration=acc, Deceleration=acc, **inputs)
        acc_seen.append(float(ax.NcToPlc["SetAcc"]))

    calls["body"] = body
    rig.run(300)
    assert not fb.Error
    assert max(acc_seen) == pytest.approx(acc or 1000.0)
    if block is not MC_MoveVelocity:
        assert min(acc_seen) == pytest.approx(-(acc or 800.0))


@pytest.mark.parametrize("block,inputs", [
    (MC_MoveAbsolute, dict(Execute=True, Position=10.0, Velocity=10.0)),
    (MC_MoveVelocity, dict(Execute=True, Velocity=10.0)),
    (MC_MoveModulo, dict(Execute=True, Position=10.0, Velocity=10.0, Direction=POS)),
    (MC_Jog, dict(JogForward=True, Mode=2, Velocity=10.0)),
])
def test_a_move_on_a_disabled_axis_is_an_error(block: type, inputs: dict) -> None:
    rig = Rig()
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    fb = rig.watch(block())
    plc.program = lambda p: fb(Axis=ax, **inputs)
    rig.run(10)
    assert fb.Error and fb.ErrorID == E.NC_NO_ENABLE == 0x4223 and not fb.Busy


@pytest.mark.parametrize("block,inputs,out", [
    (MC_MoveRelative, dict(Distance=5.0, Velocity=100.0), "Done"),
    (MC_MoveVelocity, dict(Velocity=100.0), "InVelocity"),
])
def test_the_result_is_held_while_execute_and_one_cycle_when_execute_fell(block: type, inputs: dict, out: str) -> None:
    """Appendix 7.1: Done "remains TRUE until MC_Move...Execute is TRUE"; with Execute reset early "The
    MC_Move...Done remains TRUE for one cycle" - whatever the cycle Execute falls in around the end."""
    def run(fall_at: int) -> list[bool]:
        rig, ax, calls = started()
        fb = rig.watch(block())
        n = [0]

        def body(p: Any) -> None:
            n[0] += 1
            fb(Axis=ax, Execute=n[0] < fall_at, **inputs)

        calls["body"] = body
        rig.run(60)
        return [o[out] for o in rig.outputs(fb)]

    first = run(10**6).index(True) + 1  # the cycle (1-based) that shows the result first
    for fall in range(first - 2, first + 3):
        shown = [k + 1 for k, v in enumerate(run(fall)) if v]
        assert shown == list(range(first, max(first + 1, fall))), (fall, shown)


def test_two_moves_in_one_cycle_the_later_aborts_the_earlier() -> None:
    rig, ax, calls = started()
    m1, m2 = rig.watch(MC_MoveAbsolute(), MC_MoveAbsolute())
    calls["body"] = lambda p: (m1(Axis=ax, Execute=True, Position=50.0, Velocity=100.0),
                               m2(Axis=ax, Execute=True, Position=-20.0, Velocity=100.0))
    rig.run_until(lambda: m2.Done, 200)
    assert m1.CommandAborted and not m1.Done and math.isclose(ax.ActPos, -20.0, abs_tol=0.02)
    assert not any(o["Active"] for o in rig.outputs(m1))


@pytest.mark.parametrize("block,inputs", [
    (MC_MoveAbsolute, dict(Execute=True, Position=5.0, Velocity=10.0)),
    (MC_MoveRelative, dict(Execute=True, Distance=1.0, Velocity=10.0)),
    (MC_MoveVelocity, dict(Execute=True, Velocity=10.0)),
    (MC_MoveModulo, dict(Execute=True, Position=10.0, Velocity=10.0, Direction=POS)),
    (MC_MoveAbsoluteOrRestart, dict(Execute=True, Position=10.0, Velocity=10.0)),
    (MC_Jog, dict(JogForward=True, Mode=2, Velocity=10.0)),
])
def test_a_held_stop_locks_every_move_until_execute_falls(block: type, inputs: dict) -> None:
    """Not in TcMC 3.15: Beckhoff's state diagram (Tc2_MC2 / Tc3 motion libraries), followed as a zenoh-nc
    choice: "After the complete stop the state does not change to 'Standstill' until MC_Stop is called with
    Execute = FALSE. Otherwise the axis remains locked" (0x42EF)."""
    rig, ax, calls = started()
    st, fb = rig.watch(MC_Stop(), block())
    calls["body"] = lambda p: st(Axis=ax, Execute=True)
    rig.run_until(lambda: st.Done, 20)
    assert st.Busy and st.Active
    calls["body"] = lambda p: (st(Axis=ax, Execute=True), fb(Axis=ax, **inputs))
    rig.run(5)
    assert fb.Error and fb.ErrorID == E.NC_AXIS_LOCKED_BY_STOP == 0x42EF
    assert ax.Status.MotionState == S.MC_AXISSTATE_STOPPING and st.Done
    off = {k: False for k in inputs if k in ("Execute", "JogForward")}
    calls["body"] = lambda p: (st(Axis=ax, Execute=False), fb(Axis=ax, **off))
    rig.run(2)
    assert ax.Status.MotionState == S.MC_AXISSTATE_STANDSTILL and not st.Busy
    calls["body"] = lambda p: fb(Axis=ax, **inputs)
    rig.run(3)
    assert fb.Busy and not fb.Error


@pytest.mark.parametrize("move_dec,stop_dec,stop_jerk,seen", [
    (200.0, 0.0, 0.0, 200.0),     # 0: "the deceleration from the move command is used"
    (0.0, 0.0, 0.0, 1000.0),      # ... which was the axis default
    (200.0, 500.0, 1e5, 500.0),   # with its jerk: the stop's own
    (2000.0, 100.0, 1e5, 100.0),  # weaker than the move's (from TwinCAT 2.10 B1243)
])
def test_stop_deceleration(move_dec: float, stop_dec: float, stop_jerk: float, seen: float) -> None:
    rig, ax, calls = started(AxisParams(AxisAcc=1000.0, AxisDec=1000.0, AxisJerk=1e5))
    mv, st = MC_MoveVelocity(), MC_Stop()
    acc_seen: list[float] = []

    def body(p: Any, stop: bool) -> None:
        mv(Axis=ax, Execute=True, Velocity=100.0, Deceleration=move_dec)
        st(Axis=ax, Execute=stop, Deceleration=stop_dec, Jerk=stop_jerk)
        acc_seen.append(float(ax.NcToPlc["SetAcc"]))

    calls["body"] = lambda p: body(p, False)
    rig.run(30)
    acc_seen.clear()
    calls["body"] = lambda p: body(p, True)
    rig.run_until(lambda: st.Done, 200)
    assert min(acc_seen) == pytest.approx(-seen) and mv.CommandAborted is False  # (InVelocity ended it earlier)


@pytest.mark.parametrize("block,inputs", [
    (MC_MoveAbsolute, dict(Execute=True, Position=1.0, Velocity=10.0)),
    (MC_MoveVelocity, dict(Execute=True, Velocity=10.0)),
    (MC_MoveModulo, dict(Execute=True, Position=1.0, Velocity=10.0, Direction=POS)),
    (MC_Jog, dict(JogForward=True, Mode=0)),
])
def test_moves_in_error_stop_are_refused(block: type, inputs: dict) -> None:
    rig, ax, calls = started(AxisParams(SimTimeConstant=0.05, AxisMaxPosLagValue=1.0, AxisMaxPosLagFilterTime=0.01))
    mv = MC_MoveVelocity()
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=100.0)
    rig.run_until(lambda: mv.Error, 50)
    assert mv.ErrorID == E.NC_POSITION_LAG and ax.Status.MotionState == S.MC_AXISSTATE_ERRORSTOP
    rig.run_until(lambda: abs(float(ax.NcToPlc["ActVelo"])) < 1e-6, 300)
    fb = rig.watch(block())
    calls["body"] = lambda p: (mv(Axis=ax, Execute=True, Velocity=100.0), fb(Axis=ax, **inputs))
    rig.run(5)
    assert fb.Error and fb.ErrorID == E.MC_AXIS_CANNOT_BE_STARTED == 0x4B01


def test_modulo_application_example_of_3_5() -> None:
    """TcMC 3.5 "Application example": 90 deg is the start of each cycle, 450 deg turns once in positive
    direction; after a controller activation the set position is the actual one (here 0.5 deg short: the
    drive lags by that); with a tolerance window of 1.5 deg a target of 90 deg is a minimum move and 450 deg
    one turn, never a move backwards beyond the window."""
    rig, ax, calls = started(AxisParams(Modulo=True, AxisModuloToleranceWindow=1.5, AxisPositionRangeWindow=1.0,
                                        AxisTargetPositionWindow=1.0, AxisVeloMax=3600.0),
                             drive_cls=OffsetDrive)
    mv = rig.watch(MC_MoveModulo())
    pw = MC_Power()
    enable = [True]

    def body(p: Any, target: float, ex: bool) -> None:
        pw(Axis=ax, Enable=enable[0], Enable_Positive=True, Enable_Negative=True)
        mv(Axis=ax, Execute=ex, Position=target, Velocity=720.0, Direction=POS)

    def modulo_move(target: float) -> float:
        calls["body"] = lambda p: body(p, target, False)
        rig.run(1)
        start = float(ax.NcToPlc["SetPos"])
        velo: list[float] = []
        calls["body"] = lambda p: (body(p, target, True), velo.append(float(ax.NcToPlc["SetVelo"])))
        rig.run_until(lambda: mv.Done, 500)
        assert min(velo) >= -1e-9  # positive direction all the way
        return float(ax.NcToPlc["SetPos"]) - start

    assert modulo_move(90.0) == pytest.approx(90.0)
    # controller off and on: the actual position (0.5 short) becomes the set position
    enable[0] = False
    calls["body"] = lambda p: body(p, 90.0, False)
    rig.run(3)
    enable[0] = True
    rig.run_until(lambda: pw.Status, 20)
    assert float(ax.NcToPlc["SetPos"]) == pytest.approx(89.5, abs=0.01)
    assert modulo_move(90.0) == pytest.approx(0.5, abs=0.01)    # minimum motion to exactly 90
    assert float(ax.NcToPlc["SetPos"]) == pytest.approx(90.0)
    assert modulo_move(450.0) == pytest.approx(360.0)           # one full turn
    assert modulo_move(90.0) == pytest.approx(0.0)              # identical: no motion


def test_or_restart_keeps_the_running_dynamics_and_takes_the_new_target_and_velocity() -> None:
    """TcMC 3.6: "target position and velocity are changed, if the building block during a movement is
    triggered"; Acceleration "will only be used with a start from standstill". The new target lies far
    enough behind for the new Velocity 300 to be reached with the running 200 u/s^2."""
    rig, ax, calls = started(AxisParams(AxisAcc=1000.0, AxisDec=1000.0))
    mr = rig.watch(MC_MoveAbsoluteOrRestart())
    acc_seen: list[float] = []
    velo_seen: list[float] = []

    def body(p: Any, **kw: Any) -> None:
        mr(Axis=ax, **kw)
        acc_seen.append(float(ax.NcToPlc["SetAcc"]))
        velo_seen.append(float(ax.NcToPlc["SetVelo"]))

    calls["body"] = lambda p: body(p, Execute=True, Position=500.0, Velocity=100.0, Acceleration=200.0,
                                   Deceleration=200.0)
    rig.run(20)
    calls["body"] = lambda p: body(p, Execute=False)
    rig.run(1)
    assert 0.0 < max(velo_seen) < 100.0
    calls["body"] = lambda p: body(p, Execute=True, Position=-500.0, Velocity=300.0, Acceleration=1000.0,
                                   Deceleration=1000.0)
    rig.run_until(lambda: mr.Done, 1000)
    assert max(abs(a) for a in acc_seen) == pytest.approx(200.0)
    assert min(velo_seen) == pytest.approx(-300.0)  # the new velocity
    assert float(ax.NcToPlc["SetPos"]) == pytest.approx(-500.0)
    assert not any(o["CommandAborted"] for o in rig.outputs(mr))
