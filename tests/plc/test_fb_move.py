"""MC_MoveAbsolute / MC_MoveRelative / MC_MoveVelocity / MC_Halt against a real NcCore, cycle by cycle."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nc_schema import CmdState, ErrorCodes, MC_BufferMode, StateDWord
from nc_server.core import AxisParams
from plc_client import MC_Halt, MC_MoveAbsolute, MC_MoveModulo, MC_MoveRelative, MC_MoveVelocity, MC_Power
from plc_client.fb import DONE_WINDOW_TIMEOUT
from znc_testing.plc_rig import OffsetDrive, Rig, powered


def test_move_absolute_done_held_while_execute_true(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=20.0, Velocity=100.0)
    rig.run(1)
    assert mv.Busy and not mv.Active  # reply not seen yet (it arrives with the next cycle)
    rig.run(1)
    assert mv.Busy and mv.Active
    n = rig.run_until(lambda: mv.Done, 200)
    assert n > 5
    st = ax.Status
    assert not st.HasJob and st.InTargetPosition and math.isclose(ax.ActPos, 20.0, abs_tol=0.02)
    rig.run(20)  # Done is held while Execute stays TRUE
    assert all(o["Done"] for o in rig.outputs(mv)[-20:])
    assert not mv.Busy and not mv.Active
    calls["body"] = lambda p: mv(Execute=False)
    rig.run(1)
    assert not any((mv.Done, mv.Busy, mv.Error, mv.CommandAborted))


def test_done_is_a_one_cycle_pulse_when_execute_fell_early(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveRelative())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Distance=5.0, Velocity=100.0)
    rig.run(1)
    calls["body"] = lambda p: mv(Axis=ax, Execute=False)
    rig.run(1)
    assert mv.Busy  # the command goes on after Execute fell
    rig.run(150)
    dones = [o["Done"] for o in rig.outputs(mv)]
    assert dones.count(True) == 1, "Done must be TRUE for exactly one cycle"
    i = dones.index(True)
    assert not rig.outputs(mv)[i]["Busy"] and rig.outputs(mv)[i - 1]["Busy"]
    assert math.isclose(ax.ActPos, 5.0, abs_tol=0.02)


def test_inputs_latched_and_retrigger_ignored(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=10.0, Velocity=50.0)
    rig.run(3)
    cmdno = int(rig.rec()["CmdNo"])
    # change an input while Busy: latched at the edge, so no effect
    calls["body"] = lambda p: mv(Axis=ax, Position=-30.0)
    rig.run(1)
    # new rising edge while Busy, with another position: ignored
    calls["body"] = lambda p: mv(Axis=ax, Execute=False)
    rig.run(1)
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=-50.0)
    rig.run(1)
    assert int(rig.rec()["CmdNo"]) == cmdno, "a retrigger while Busy must not send a command"
    rig.run_until(lambda: mv.Done, 300)
    assert math.isclose(ax.ActPos, 10.0, abs_tol=0.02)
    assert int(rig.rec()["CmdNo"]) == cmdno
    # after completion a new edge starts a new command with the current inputs
    calls["body"] = lambda p: mv(Axis=ax, Execute=False)
    rig.run(1)
    calls["body"] = lambda p: mv(Axis=ax, Execute=True)
    rig.run_until(lambda: mv.Done, 500)
    assert math.isclose(ax.ActPos, -50.0, abs_tol=0.02)


def test_second_block_aborts_first(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv1, mv2 = rig.watch(MC_MoveAbsolute(), MC_MoveAbsolute())
    state = {"go2": False}

    def body(p):
        mv1(Axis=ax, Execute=True, Position=100.0, Velocity=50.0)
        mv2(Axis=ax, Execute=state["go2"], Position=-5.0, Velocity=50.0)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    state["go2"] = True
    rig.run_until(lambda: mv1.CommandAborted, 5)
    assert mv1.ErrorID == 0 and not mv1.Busy and not mv1.Active
    rig.run_until(lambda: mv2.Done, 600)
    assert mv1.CommandAborted  # held: Execute still TRUE
    assert math.isclose(ax.ActPos, -5.0, abs_tol=0.02)


def test_command_from_another_client_aborts(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveVelocity())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=20.0)
    rig.run_until(lambda: mv.Active, 5)
    other = rig.plc("plc2")
    ax2 = other.axis("nc1", 1)
    halt = MC_Halt()
    other.program = lambda p: halt(Axis=ax2, Execute=True)
    rig.run_until(lambda: mv.CommandAborted or mv.InVelocity, 10)
    assert mv.CommandAborted
    rig.run_until(lambda: halt.Done, 100)
    assert ax.Status.StandStill


def test_move_velocity_in_velocity_and_halt(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, halt = rig.watch(MC_MoveVelocity(), MC_Halt())
    state = {"halt": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=30.0, Direction=3)
        halt(Axis=ax, Execute=state["halt"])

    calls["body"] = body
    rig.run(2)
    assert mv.Busy and mv.Active and not mv.InVelocity
    rig.run_until(lambda: mv.InVelocity, 100)
    # Tc2_MC2: finished at constant velocity, no further monitoring
    assert not mv.Busy and not mv.Active
    assert ax.Status.ConstantVelocity and ax.Status.ContinuousMotion
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), -30.0)
    state["halt"] = True
    rig.run_until(lambda: halt.Done, 100)
    assert mv.InVelocity and not mv.CommandAborted  # a finished block is not aborted any more
    assert ax.Status.StandStill and ax.Status.NotMoving


def test_move_velocity_aborted_during_acceleration(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, mv2 = rig.watch(MC_MoveVelocity(), MC_MoveAbsolute())
    state = {"go": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=900.0, Acceleration=100.0, Jerk=1000.0)
        mv2(Axis=ax, Execute=state["go"], Position=0.0, Velocity=50.0)

    calls["body"] = body
    rig.run_until(lambda: mv.Active, 5)
    state["go"] = True
    rig.run_until(lambda: mv.CommandAborted, 5)
    assert not mv.InVelocity


@pytest.mark.parametrize("bm", [1.0, True, "1", None, 2**40])
def test_buffer_mode_that_is_not_a_wire_integer_is_refused_locally(rig: Rig, bm) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    before = int(rig.rec()["CmdNo"])
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=1.0, Velocity=1.0, BufferMode=bm)
    rig.run(1)
    assert mv.Error and mv.ErrorID == ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED == 0x4B64
    rig.run(3)
    assert int(rig.rec()["CmdNo"]) == before, "no command may be sent"
    assert mv.Error  # held while Execute


@pytest.mark.parametrize("cls, inputs", [
    (MC_MoveAbsolute, {"Position": 1.0, "Velocity": 1.0}),
    (MC_MoveRelative, {"Distance": 1.0, "Velocity": 1.0}),
    (MC_MoveModulo, {"Position": 1.0, "Velocity": 1.0}),
    (MC_MoveVelocity, {"Velocity": 1.0}),
    (MC_Halt, {}),
])
@pytest.mark.parametrize("bm", [1, 18, 21, np.int64(19), MC_BufferMode.MC_BlendingNext, 7, -1])
def test_integer_buffer_mode_is_passed_to_the_nc(rig: Rig, cls, inputs: dict, bm) -> None:
    """The block no longer refuses non-zero modes: the integer goes out as it is (the NC checks it)."""
    ax, _, calls = powered(rig)
    fb = cls()
    sent: list = []
    port = ax.task.port
    orig = port.send

    def spy(nc, axis_id, cmd, **args):
        sent.append((cmd, args))
        return orig(nc, axis_id, cmd, **args)

    port.send = spy  # type: ignore[method-assign]
    calls["body"] = lambda p: fb(Axis=ax, Execute=True, BufferMode=bm, **inputs)
    rig.run(2)
    assert sent and sent[0][0] == cls.CMD
    assert sent[0][1]["BufferMode"] == int(bm) and type(sent[0][1]["BufferMode"]) is int
    if int(bm) in (0, 1, 18, 19, 20, 21):
        assert not fb.Error, hex(fb.ErrorID)  # on an axis at rest every valid mode starts at once
    else:
        assert fb.Error and fb.ErrorID == ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED, "the NC's 0x4B64"


@pytest.mark.parametrize("inputs, code", [
    ({"Position": 1.0, "Velocity": -1.0}, ErrorCodes.NC_VELOCITY_NOT_ALLOWED),  # NC rejects: 0x4221
    ({"Position": 1.0, "Velocity": 1e9}, ErrorCodes.NC_VELOCITY_NOT_ALLOWED),
    ({"Position": 1.0, "Velocity": 1.0, "Acceleration": -1.0}, ErrorCodes.NC_ACCELERATION_NOT_ALLOWED),
    ({"Position": float("nan"), "Velocity": 1.0}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),  # caught locally
    ({"Position": "ten", "Velocity": 1.0}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
])
def test_rejected_command_reports_the_code(rig: Rig, inputs: dict, code: int) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, **inputs)
    rig.run_until(lambda: not mv.Busy, 5)
    assert mv.Error and mv.ErrorID == code
    calls["body"] = lambda p: mv(Axis=ax, Execute=False)
    rig.run(1)
    assert not mv.Error and mv.ErrorID == 0


def test_move_without_enable_is_rejected_by_the_nc(rig: Rig) -> None:
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    mv = rig.watch(MC_MoveAbsolute())
    plc.program = lambda p: mv(Axis=ax, Execute=True, Position=1.0, Velocity=1.0)
    rig.run(3)
    assert mv.Error and mv.ErrorID == ErrorCodes.NC_NO_ENABLE


def test_axis_fault_while_moving_is_a_block_error(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=50.0, Velocity=50.0)
    rig.run_until(lambda: mv.Active, 5)
    rig.core.fault(0, ErrorCodes.NC_POSITION_LAG)
    rig.run(2)
    assert mv.Error and mv.ErrorID == ErrorCodes.NC_POSITION_LAG
    assert ax.Status.ErrorStop


def test_disable_while_moving_aborts(rig: Rig) -> None:
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    pw, mv = MC_Power(), MC_MoveAbsolute()
    rig.watch(mv)
    st = {"en": True}

    def program(p):
        pw(Axis=ax, Enable=st["en"], Enable_Positive=True, Enable_Negative=True)
        mv(Axis=ax, Execute=pw.Status or mv.Busy, Position=80.0, Velocity=40.0)

    plc.program = program
    rig.run_until(lambda: mv.Active, 10)
    st["en"] = False
    rig.run_until(lambda: not mv.Busy, 5)
    assert mv.CommandAborted
    assert int(rig.rec()["CmdState"]) == CmdState.ABORTED


@pytest.mark.parametrize("target_mon, area_mon, expect", [
    (True, True, "timeout"),     # case 1: InTargetPosition never comes (0.5 u off, window 0.02)
    (False, True, "done"),       # case 2: InPositionArea (window 5) is enough
    (False, False, "done"),      # case 3: HasJob fell is enough
])
def test_done_rule_of_appendix_7_1(target_mon: bool, area_mon: bool, expect: str) -> None:
    from nc_server.core import AxisParams
    rig = Rig(n_axes=1, params=AxisParams(AxisEnTargetPositionMonitoring=target_mon,
                                          AxisEnPositionRangeMonitoring=area_mon), drive_cls=OffsetDrive)
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=10.0, Velocity=100.0)
    rig.run_until(lambda: mv.Active, 5)
    rig.run_until(lambda: not ax.Status.HasJob, 100)
    end = ax.task.now  # the logical end, as the PLC sees it
    rig.run_until(lambda: not mv.Busy, 1000)
    if expect == "done":
        assert mv.Done
        assert ax.task.now - end < 0.1
    else:
        assert mv.Error and mv.ErrorID == ErrorCodes.MC_TIMEOUT_AXIS_FB == 0x4B07
        assert DONE_WINDOW_TIMEOUT - 0.05 <= ax.task.now - end <= DONE_WINDOW_TIMEOUT + 0.05
        assert ax.Status.InPositionArea and not ax.Status.InTargetPosition


def test_move_modulo(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveModulo())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=90.0, Velocity=500.0, Direction=1)
    rig.run_until(lambda: mv.Done, 300)
    assert math.isclose(ax.ActPos, 90.0, abs_tol=0.02)
    assert int(ax.NcToPlc["StateDWord"]) & int(StateDWord.InTargetPosition)


def test_numpy_scalar_inputs_are_numbers() -> None:
    """Inputs computed with numpy (np.float32/np.int64) are as good as Python numbers."""
    import numpy as np

    from plc_client.fb.base import FunctionBlock

    assert FunctionBlock._is_real(np.float32(1.5)) and FunctionBlock._is_real(np.int64(3))
    assert not FunctionBlock._is_real(np.bool_(True)) and not FunctionBlock._is_real(float("nan"))


def test_a_loop_movement_is_one_command_done_at_the_target_after_the_return() -> None:
    """AxisEnLoopingDistance/AxisLoopingDistance: MC_MoveAbsolute from below with a positive looping distance
    passes its target to the loop point and returns; the block stays Busy/Active (no Done while passing the
    target on the way out) and is Done at the target."""
    rig = Rig(params=AxisParams(AxisEnLoopingDistance=True, AxisLoopingDistance=5.0))
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=20.0, Velocity=100.0)
    peak = 0.0

    def tracking() -> bool:
        nonlocal peak
        peak = max(peak, ax.ActPos)
        assert not mv.Done or peak > 24.9, "Done before the loop point was reached"
        return bool(mv.Done)

    rig.run_until(tracking, 400)
    assert peak > 24.9 and math.isclose(ax.ActPos, 20.0, abs_tol=0.02) and not mv.Error
    assert all(o["Busy"] for o in rig.outputs(mv)[1:-1])
