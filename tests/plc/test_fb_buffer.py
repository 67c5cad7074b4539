"""BufferMode, the new move blocks and the amendments against the in-process NC's motion engine,
cycle by cycle (the PLCopen output rules are checked after every cycle by the rig).

The same block rules against the bare contract (no engine) are in test_fb_buffer_contract.py.
"""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import ErrorCodes
from nc_server.core import AxisParams
from plc_client import (
    MC_ChangeDynParam, MC_Halt, MC_MoveAbsolute, MC_MoveAbsoluteOrRestart, MC_MoveAdditive,
    MC_MoveContinuousAbsolute, MC_MoveContinuousRelative, MC_MoveRelative, MC_MoveVelocity, MC_NewPos,
    MC_NewPosAndVelo, MC_OrientedStop,
)
from znc_testing.plc_rig import Rig, powered


def first(trace: list[dict[str, Any]], output: str) -> int:
    """Index of the first cycle in which ``output`` was TRUE."""
    return next(i for i, o in enumerate(trace) if o[output])


def sampler(ax: Any, log: list[tuple[float, float]]) -> None:
    log.append((float(ax.NcToPlc["SetPos"]), float(ax.NcToPlc["SetVelo"])))


def velocity_at(log: list[tuple[float, float]], pos: float) -> float:
    """|SetVelo| of the sample whose SetPos is nearest to ``pos``."""
    return abs(min(log, key=lambda s: abs(s[0] - pos))[1])


def two_moves(rig: Rig, mode: int, log: list[tuple[float, float]] | None = None) -> tuple[Any, Any, Any]:
    """mv1 to 50 at 100 u/s, then (while it runs) mv2 to 120 at 200 u/s with ``mode``; until mv2 is Done."""
    ax, _, calls = powered(rig)
    mv1, mv2 = rig.watch(MC_MoveAbsolute(), MC_MoveAbsolute())
    st = {"go2": False}

    def body(p):
        mv1(Axis=ax, Execute=True, Position=50.0, Velocity=100.0)
        mv2(Axis=ax, Execute=st["go2"], Position=120.0, Velocity=200.0, BufferMode=mode)
        if log is not None:
            sampler(ax, log)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go2"] = True
    rig.run(3)
    assert mv2.Busy and not mv2.Active, "the buffered command waits: Busy, not Active"
    assert mv1.Busy and mv1.Active
    assert ax.Status.CmdBuffered
    rig.run_until(lambda: mv2.Done, 1000)
    return ax, mv1, mv2


@pytest.mark.parametrize("mode", [1, 18, 19, 20, 21])
def test_buffer_mode_transition(rig: Rig, mode: int) -> None:
    ax, mv1, mv2 = two_moves(rig, mode)
    t1, t2 = rig.outputs(mv1), rig.outputs(mv2)
    k = first(t2, "Active")
    assert first(t1, "Done") == k, "the first block is Done in the very cycle the second becomes Active"
    assert not any(o["CommandAborted"] or o["Error"] for o in t1 + t2)
    assert all(o["Busy"] and not o["Active"] for o in t2[first(t2, "Busy"):k])
    assert all(o["Done"] for o in t1[k:]), "Done held while Execute stays TRUE"
    assert math.isclose(ax.ActPos, 120.0, abs_tol=0.02)


@pytest.mark.parametrize("mode, lo, hi", [
    (1, 0.0, 5.0),                                     # MC_Buffered: the axis stops at P1
    (18, 80.0, 120.0),                                 # MC_BlendingLow: the lower velocity (100)
    (19, 80.0, 120.0),                                 # MC_BlendingPrevious: the first command's (100)
    (20, 170.0, 230.0),                                # MC_BlendingNext: the second command's (200)
    (21, 170.0, 230.0),                                # MC_BlendingHigh: the higher velocity (200)
])
def test_velocity_at_the_transition_point(rig: Rig, mode: int, lo: float, hi: float) -> None:
    log: list[tuple[float, float]] = []
    two_moves(rig, mode, log)
    assert lo <= velocity_at(log, 50.0) <= hi, (mode, velocity_at(log, 50.0))


def test_buffered_behind_a_velocity_move_starts_at_in_velocity(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, halt = rig.watch(MC_MoveVelocity(), MC_Halt())
    calls["body"] = lambda p: (mv(Axis=ax, Execute=True, Velocity=100.0),
                               halt(Axis=ax, Execute=mv.Busy or halt.Busy or halt.Done, BufferMode=1))
    rig.run_until(lambda: halt.Done, 500)
    assert first(rig.outputs(mv), "InVelocity") <= first(rig.outputs(halt), "Active")
    assert not any(o["CommandAborted"] for o in rig.outputs(mv))
    assert ax.Status.StandStill


def test_second_buffered_command_is_refused(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv1, mv2, mv3 = rig.watch(MC_MoveAbsolute(), MC_MoveRelative(), MC_MoveRelative())
    st = {"go": False}

    def body(p):
        mv1(Axis=ax, Execute=True, Position=60.0, Velocity=100.0)
        mv2(Axis=ax, Execute=st["go"], Distance=10.0, Velocity=100.0, BufferMode=1)
        mv3(Axis=ax, Execute=st["go"] and mv2.Busy, Distance=10.0, Velocity=100.0, BufferMode=18)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go"] = True
    rig.run_until(lambda: mv3.Error, 10)
    assert mv3.ErrorID == ErrorCodes.NC_COMMAND_BUFFER_FULL == 0x4292
    assert mv2.Busy and not mv2.Active and mv1.Active
    rig.run_until(lambda: mv2.Done, 1000)
    assert mv1.Done and math.isclose(ax.ActPos, 70.0, abs_tol=0.02)


def test_aborting_command_aborts_the_active_and_the_waiting_one(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv1, mv2, mv3 = rig.watch(MC_MoveAbsolute(), MC_MoveAbsolute(), MC_MoveAbsolute())
    st = {"go2": False, "go3": False}

    def body(p):
        mv1(Axis=ax, Execute=True, Position=80.0, Velocity=100.0)
        mv2(Axis=ax, Execute=st["go2"], Position=150.0, Velocity=100.0, BufferMode=20)
        mv3(Axis=ax, Execute=st["go3"], Position=-5.0, Velocity=100.0)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go2"] = True
    rig.run(3)
    assert mv2.Busy and not mv2.Active
    st["go3"] = True
    rig.run_until(lambda: mv3.Active, 5)
    assert mv1.CommandAborted and mv2.CommandAborted, "an Aborting command replaces both"
    assert not mv2.Error and mv2.ErrorID == 0
    rig.run_until(lambda: mv3.Done, 1000)
    assert math.isclose(ax.ActPos, -5.0, abs_tol=0.02)


@pytest.mark.parametrize("new_pos", [40.0, 90.0])
def test_new_pos_ends_the_move_done_at_the_new_target(rig: Rig, new_pos: float) -> None:
    ax, _, calls = powered(rig)
    mv, npos = rig.watch(MC_MoveAbsolute(), MC_NewPos())
    st = {"go": False}

    def body(p):
        mv(Axis=ax, Execute=True, Position=60.0, Velocity=50.0)
        npos(Axis=ax, Execute=st["go"], NewPos=new_pos)

    calls["body"] = body
    rig.run_until(lambda: mv.Active and ax.ActPos > 10.0, 100)
    cmdno = int(ax.NcToPlc["CmdNo"])
    st["go"] = True
    rig.run_until(lambda: npos.Done, 5)
    assert mv.Busy and mv.Active, "the amended command goes on"
    rig.run(1)
    assert int(ax.NcToPlc["CmdNo"]) == cmdno, "an amendment keeps the job's CmdNo"
    assert ax.Status.NewTargetPosition and math.isclose(float(ax.NcToPlc["TargetPos"]), new_pos)
    rig.run_until(lambda: mv.Done, 1000)
    assert math.isclose(ax.ActPos, new_pos, abs_tol=0.02)
    assert not any(o["CommandAborted"] for o in rig.outputs(mv))


def test_new_pos_on_an_axis_at_rest_is_refused(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    npos = rig.watch(MC_NewPos())
    calls["body"] = lambda p: npos(Axis=ax, Execute=True, NewPos=5.0)
    rig.run_until(lambda: not npos.Busy, 5)
    assert npos.Error and npos.ErrorID == ErrorCodes.MC_AXIS_NOT_MOVING == 0x4B03


def test_new_pos_and_velo(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, npv = rig.watch(MC_MoveAbsolute(), MC_NewPosAndVelo())
    st = {"go": False}
    log: list[tuple[float, float]] = []

    def body(p):
        mv(Axis=ax, Execute=True, Position=100.0, Velocity=50.0)
        npv(Axis=ax, Execute=st["go"], Mode=3, NewPos=150.0, NewVelo=150.0)
        sampler(ax, log)

    calls["body"] = body
    rig.run_until(lambda: mv.Active and ax.ActPos > 10.0, 100)
    st["go"] = True
    rig.run_until(lambda: npv.Done, 5)
    rig.run_until(lambda: mv.Done, 1000)
    assert math.isclose(ax.ActPos, 150.0, abs_tol=0.02)
    assert max(abs(v) for _, v in log) > 100.0, "the new velocity was used"


def test_move_additive_adds_to_the_aborted_target(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, add = rig.watch(MC_MoveAbsolute(), MC_MoveAdditive())
    st = {"go": False}

    def body(p):
        mv(Axis=ax, Execute=True, Position=50.0, Velocity=50.0)
        add(Axis=ax, Execute=st["go"], Distance=10.0, Velocity=50.0)

    calls["body"] = body
    rig.run_until(lambda: mv.Active and ax.ActPos > 20.0, 100)
    st["go"] = True
    rig.run_until(lambda: add.Done, 1000)
    assert mv.CommandAborted
    assert math.isclose(ax.ActPos, 60.0, abs_tol=0.02), "Distance is added to the last commanded target"


@pytest.mark.parametrize("cls, inputs, target", [
    (MC_MoveContinuousAbsolute, {"Position": 50.0}, 50.0),
    (MC_MoveContinuousRelative, {"Distance": 50.0}, 50.0),
])
def test_move_continuous_in_end_velocity(rig: Rig, cls: Any, inputs: dict, target: float) -> None:
    ax, _, calls = powered(rig)
    mc, halt = rig.watch(cls(), MC_Halt())
    st = {"halt": False}

    def body(p):
        mc(Axis=ax, Execute=True, Velocity=100.0, EndVelocity=20.0, **inputs)
        halt(Axis=ax, Execute=st["halt"])

    calls["body"] = body
    rig.run_until(lambda: mc.Active, 5)
    rig.run_until(lambda: mc.InEndVelocity or not mc.Busy, 500)
    assert mc.InEndVelocity, rig.outputs(mc)[-1]
    assert float(ax.NcToPlc["SetPos"]) >= target
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 20.0, rel_tol=1e-3)
    assert not mc.Busy and not mc.Active  # Tc2_MC2: finished, the axis is no longer monitored
    rig.run(20)
    assert ax.Status.HasJob and math.isclose(float(ax.NcToPlc["SetVelo"]), 20.0, rel_tol=1e-3), \
        "the axis goes on with EndVelocity"
    st["halt"] = True
    rig.run_until(lambda: halt.Done, 200)
    assert mc.InEndVelocity and not mc.CommandAborted
    assert ax.Status.StandStill


def test_move_absolute_or_restart(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsoluteOrRestart())
    st = {"ex": True, "pos": 100.0}
    calls["body"] = lambda p: mv(Axis=ax, Execute=st["ex"], Position=st["pos"], Velocity=50.0)
    rig.run_until(lambda: mv.Active and ax.ActPos > 20.0, 100)
    first_cmdno = int(ax.NcToPlc["CmdNo"])
    st["ex"] = False
    rig.run(1)
    st["ex"], st["pos"] = True, 40.0
    rig.run(3)
    assert int(ax.NcToPlc["CmdNo"]) != first_cmdno, "the retrigger sent a new command"
    assert mv.Busy and mv.Active
    rig.run_until(lambda: mv.Done, 1000)
    assert math.isclose(ax.ActPos, 40.0, abs_tol=0.02)
    assert not any(o["CommandAborted"] or o["Error"] for o in rig.outputs(mv))


def test_change_dyn_param_done_at_the_destination(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, cd = rig.watch(MC_MoveAbsolute(), MC_ChangeDynParam())
    st = {"go": False}

    def body(p):
        mv(Axis=ax, Execute=True, Position=80.0, Velocity=100.0, Acceleration=500.0, Deceleration=500.0)
        cd(Axis=ax, Execute=st["go"], Acceleration=2000.0, Deceleration=2000.0)

    calls["body"] = body
    rig.run_until(lambda: mv.Active and ax.ActPos > 5.0, 100)
    st["go"] = True
    rig.run(5)
    assert cd.Busy and not cd.Done and not cd.Error
    rig.run_until(lambda: cd.Done or cd.Error, 1000)
    assert cd.Done and mv.Done
    assert math.isclose(ax.ActPos, 80.0, abs_tol=0.02)


def test_oriented_stop() -> None:
    rig = Rig(n_axes=1, params=AxisParams(Modulo=True, AxisEncoderModuloValue=360.0))
    ax, _, calls = powered(rig)
    mv, os_, bad = rig.watch(MC_MoveVelocity(), MC_OrientedStop(), MC_OrientedStop())
    st = {"stop": False, "bad": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=180.0)
        bad(Axis=ax, Execute=st["bad"], Position=360.0)
        os_(Axis=ax, Execute=st["stop"], Position=90.0)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 200)
    st["bad"] = True
    rig.run_until(lambda: not bad.Busy, 5)
    assert bad.Error and bad.ErrorID == 0x4281, "Position outside [0, period): the NC's 0x4281"
    st["stop"] = True
    rig.run_until(lambda: os_.Done or os_.Error, 1000)
    assert os_.Done
    assert math.isclose(float(ax.NcToPlc["SetPos"]) % 360.0, 90.0, abs_tol=1e-6)
    assert ax.Status.StandStill


def test_oriented_stop_beyond_a_soft_limit_stops_the_axis_with_error() -> None:
    """TcMC 3.16: an oriented stop that would exceed an active software limit is a fault condition;
    "for all fault conditions, the axis is stopped safely": Busy during the standard stop, then Error 0x4222."""
    rig = Rig(n_axes=1, params=AxisParams(Modulo=True, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=200.0))
    ax, _, calls = powered(rig)
    mv, os_ = rig.watch(MC_MoveVelocity(), MC_OrientedStop())
    st = {"stop": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=100.0)
        os_(Axis=ax, Execute=st["stop"], Position=350.0)

    calls["body"] = body
    rig.run_until(lambda: ax.ActPos > 100.0, 300)
    st["stop"] = True
    rig.run_until(lambda: os_.Active, 5)
    rig.run_until(lambda: not os_.Busy, 300)
    assert os_.Error and os_.ErrorID == ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED
    assert ax.Status.StandStill and ax.ActPos < 200.0


def test_oriented_stop_ending_in_error_aborts_the_buffered_command_behind_it() -> None:
    """Errors clear the queue: MC_MoveRelative (MC_Buffered) waiting behind an MC_OrientedStop that ends
    in Error 0x4222 (beyond the software limit) never starts: CommandAborted, the axis stands."""
    rig = Rig(n_axes=1, params=AxisParams(Modulo=True, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=200.0))
    ax, _, calls = powered(rig)
    mv, os_, mr = rig.watch(MC_MoveVelocity(), MC_OrientedStop(), MC_MoveRelative())
    st = {"stop": False, "rel": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=100.0)
        os_(Axis=ax, Execute=st["stop"], Position=350.0)
        mr(Axis=ax, Execute=st["rel"], Distance=30.0, Velocity=50.0, BufferMode=1)

    calls["body"] = body
    rig.run_until(lambda: ax.ActPos > 100.0, 300)
    st["stop"] = True
    rig.run_until(lambda: os_.Active, 5)
    st["rel"] = True
    rig.run_until(lambda: ax.Status.CmdBuffered, 10)
    assert os_.Busy and mr.Busy and not mr.Active, "queued behind the oriented stop"
    rig.run_until(lambda: not os_.Busy and not mr.Busy, 300)
    assert os_.Error and os_.ErrorID == ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED
    assert mr.CommandAborted and not mr.Error and not mr.Done
    p = float(ax.NcToPlc["SetPos"])
    rig.run(50)
    assert float(ax.NcToPlc["SetPos"]) == p and float(ax.NcToPlc["SetVelo"]) == 0.0, "the axis stands"
    assert ax.Status.StandStill and not ax.Status.Error and p < 200.0


def test_waiting_command_that_can_no_longer_start_is_an_error() -> None:
    """Checked again when it becomes active: its target is now beyond the software limit."""
    from nc_schema import MC_AxisPara

    rig = Rig(n_axes=1, params=AxisParams(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0))
    ax, _, calls = powered(rig)
    mv1, mv2 = rig.watch(MC_MoveAbsolute(), MC_MoveRelative())
    st = {"go2": False}

    def body(p):
        mv1(Axis=ax, Execute=True, Position=50.0, Velocity=50.0)
        mv2(Axis=ax, Execute=st["go2"], Distance=30.0, Velocity=50.0, BufferMode=1)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go2"] = True
    rig.run(3)
    assert mv2.Busy and not mv2.Active
    w = ax.task.send(ax, "WriteParameter", ParameterNumber=int(MC_AxisPara.AxisMaxSoftPosLimit), Value=60.0)
    rig.run_until(lambda: not mv2.Busy, 500)
    assert w.reply is not None and w.reply["error"] == 0
    assert mv2.Error and mv2.ErrorID == ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED == 0x4222
    rig.run_until(lambda: not mv1.Busy, 100)
    assert mv1.Done, "the first command ended normally"
    assert not ax.Status.Error and ax.Status.StandStill, "no axis error"
    assert math.isclose(ax.ActPos, 50.0, abs_tol=0.02)
