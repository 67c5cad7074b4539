"""BufferMode conformance scenarios (Tc2_MC2 MC_BufferMode, PLCopen Part 1) driven cycle by cycle
against the in-process NC (the rig checks the output exclusivity after every cycle).

Sources: Tc2_MC2 "MC_BufferMode" (https://infosys.beckhoff.com/content/1033/tcplclib_tc2_mc2/70147595.html):
"The reference point for the different velocity profiles is always P1. The mode specifies the velocity
v1 or v2 at this point." ... "if the speed of the second command is lower than the first ... the modes
BlendingLow/BlendingNext and BlendingHigh/BlendingPrevious are equivalent." ... "Otherwise, blending is
implemented as best as possible." BkPlcMc MC_BufferMode_BkPlcMc: "If possible, the transition point is
passed with ...". The rest: reference notes 3.5/3.7 (shared/reference/twincat-nc-reference.md).
"""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import ErrorCodes
from plc_client import MC_Halt, MC_Home, MC_MoveAbsolute, MC_MoveVelocity, MC_Stop
from znc_testing.plc_rig import Rig, powered

LOW, PREVIOUS, NEXT, HIGH = 18, 19, 20, 21


def first(trace: list[dict[str, Any]], output: str) -> int:
    return next(i for i, o in enumerate(trace) if o[output])


def velocity_at(log: list[tuple[float, float]], pos: float) -> float:
    return abs(min(log, key=lambda s: abs(s[0] - pos))[1])


def pair(rig: Rig, p1: float, v1: float, p2: float, v2: float, mode: int, log: list[tuple[float, float]],
         acc: float = 0.0) -> tuple[Any, Any, Any]:
    """mv1 to p1 at v1, mv2 (issued two cycles after mv1 is Active) to p2 at v2 with ``mode``; until mv2 ends."""
    ax, _, calls = powered(rig)
    mv1, mv2 = rig.watch(MC_MoveAbsolute(), MC_MoveAbsolute())
    st = {"go2": False}

    def body(p: Any) -> None:
        mv1(Axis=ax, Execute=True, Position=p1, Velocity=v1, Acceleration=acc, Deceleration=acc)
        mv2(Axis=ax, Execute=st["go2"], Position=p2, Velocity=v2, BufferMode=mode, Acceleration=acc,
            Deceleration=acc)
        log.append((float(ax.NcToPlc["SetPos"]), float(ax.NcToPlc["SetVelo"])))

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    rig.run(2)
    st["go2"] = True
    rig.run(2)
    assert mv2.Busy and not mv2.Active
    rig.run_until(lambda: not mv2.Busy, 2000)
    return ax, mv1, mv2


@pytest.mark.parametrize("mode, expect", [(LOW, 100.0), (PREVIOUS, 200.0), (NEXT, 100.0), (HIGH, 200.0)])
def test_velocity_at_p1_when_the_second_is_slower(rig: Rig, mode: int, expect: float) -> None:
    log: list[tuple[float, float]] = []
    ax, mv1, mv2 = pair(rig, 100.0, 200.0, 250.0, 100.0, mode, log)
    assert mv1.Done and mv2.Done
    assert math.isclose(velocity_at(log, 100.0), expect, rel_tol=0.1), velocity_at(log, 100.0)
    assert math.isclose(ax.ActPos, 250.0, abs_tol=0.02)


def crossing_velocity(log: list[tuple[float, float]], pos: float) -> float:
    """SetVelo where SetPos crosses ``pos`` (interpolated between the two samples around it)."""
    for (p0, v0), (p1, v1) in zip(log, log[1:]):
        if p0 <= pos <= p1 and p1 > p0:
            return v0 + (v1 - v0) * (pos - p0) / (p1 - p0)
    raise AssertionError(f"{pos} never crossed")


@pytest.mark.parametrize("mode", [NEXT, HIGH])
@pytest.mark.parametrize("v1, acc, reachable", [(100.0, 500.0, 125.0), (100.0, 0.0, 240.0)])
def test_unreachable_blending_velocity_is_approached_as_well_as_possible(rig: Rig, mode: int, v1: float,
                                                                         acc: float, reachable: float) -> None:
    """P0 -> P1 = 20, then to 300 at 400 u/s (Next/High: 400 at P1, not reachable within 20 u).
    Tc2_MC2 MC_BufferMode: "Otherwise, blending is implemented as best as possible"; BkPlcMc: "If possible,
    the transition point is passed with the higher velocity". The axis passes P1 close to the highest
    velocity it can reach there (a = 500: ~138 u/s; axis defaults a = 5000, j = 50000: ~271 u/s),
    never beyond P1 while the first command is Active, never reversing. (The old plan halved the end
    velocity until one fitted: 100 and 200 u/s.)"""
    log: list[tuple[float, float]] = []
    ax, mv1, mv2 = pair(rig, 20.0, v1, 300.0, 400.0, mode, log, acc=acc)
    assert mv1.Done and mv2.Done
    v = crossing_velocity(log, 20.0)
    assert reachable <= v < 400.0, v
    # (log and the recorded outputs: one sample per PLC cycle, taken from the same NcToPlc)
    first_active = [p for (p, _), o in zip(log, rig.outputs(mv1)[-len(log):]) if o["Active"]]
    assert len(first_active) > 5 and max(first_active) <= 20.0 + 1e-9, max(first_active)
    assert all(s[1] >= -1e-9 for s in log), "no reversal"
    assert math.isclose(ax.ActPos, 300.0, abs_tol=0.02)


@pytest.mark.parametrize("mode", [LOW, PREVIOUS, NEXT, HIGH])
def test_second_too_short_to_stop_from_the_blending_velocity(rig: Rig, mode: int) -> None:
    """P1 = 100 at 200, P2 = 101 at 200: the blending velocity is lowered so that P2 is not overrun."""
    log: list[tuple[float, float]] = []
    ax, mv1, mv2 = pair(rig, 100.0, 200.0, 101.0, 200.0, mode, log)
    assert mv1.Done and mv2.Done
    assert max(s[0] for s in log) <= 101.0 + 1e-6
    assert all(s[1] >= -1e-9 for s in log), "no reversal"
    assert math.isclose(ax.ActPos, 101.0, abs_tol=0.02)


@pytest.mark.parametrize("mode", [LOW, PREVIOUS, NEXT, HIGH])
def test_blending_into_the_opposite_direction_passes_p1_at_rest(rig: Rig, mode: int) -> None:
    log: list[tuple[float, float]] = []
    ax, mv1, mv2 = pair(rig, 100.0, 200.0, 0.0, 200.0, mode, log)
    assert mv1.Done and mv2.Done and not (mv1.CommandAborted or mv2.Error)
    assert max(s[0] for s in log) <= 100.0 + 1e-6, "P1 not overrun"
    assert velocity_at(log, 100.0) < 5.0
    assert math.isclose(ax.ActPos, 0.0, abs_tol=0.02)


@pytest.mark.parametrize("mode", [LOW, NEXT])
def test_first_block_done_when_the_blended_second_becomes_active(rig: Rig, mode: int) -> None:
    log: list[tuple[float, float]] = []
    ax, mv1, mv2 = pair(rig, 100.0, 200.0, 250.0, 100.0, mode, log)
    t1, t2 = rig.outputs(mv1), rig.outputs(mv2)
    k = first(t2, "Active")
    assert first(t1, "Done") == k
    assert not any(o["CommandAborted"] for o in t1)
    assert velocity_at(log, 100.0) > 50.0, "no stop at P1"


@pytest.mark.parametrize("stopper", ["halt", "stop"])
def test_halt_or_stop_aborts_the_active_and_the_buffered_command(rig: Rig, stopper: str) -> None:
    ax, _, calls = powered(rig)
    mv1, mv2 = rig.watch(MC_MoveAbsolute(), MC_MoveAbsolute())
    st_fb = rig.watch(MC_Halt() if stopper == "halt" else MC_Stop())
    st = {"go2": False, "stop": False}

    def body(p: Any) -> None:
        mv1(Axis=ax, Execute=True, Position=200.0, Velocity=100.0)
        mv2(Axis=ax, Execute=st["go2"], Position=300.0, Velocity=100.0, BufferMode=1)
        st_fb(Axis=ax, Execute=st["stop"])

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go2"] = True
    rig.run_until(lambda: ax.Status.CmdBuffered, 5)
    st["stop"] = True
    rig.run_until(lambda: st_fb.Done, 500)
    assert mv1.CommandAborted and mv2.CommandAborted
    assert not mv2.Done and not mv2.Error
    assert ax.ActPos < 200.0 and ax.Status.StandStill is (stopper == "halt")


@pytest.mark.parametrize("mode", [1, NEXT])
def test_move_behind_move_velocity_starts_when_in_velocity(rig: Rig, mode: int) -> None:
    ax, _, calls = powered(rig)
    mv, ma = rig.watch(MC_MoveVelocity(), MC_MoveAbsolute())
    st = {"go": False}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Velocity=100.0)
        ma(Axis=ax, Execute=st["go"], Position=100.0, Velocity=50.0, BufferMode=mode)

    calls["body"] = body
    rig.run_until(lambda: mv.Busy, 5)
    st["go"] = True
    rig.run_until(lambda: ma.Done or ma.Error, 1000)
    assert ma.Done
    tv, ta = rig.outputs(mv), rig.outputs(ma)
    assert first(tv, "InVelocity") <= first(ta, "Active")
    assert not any(o["CommandAborted"] or o["Error"] for o in tv)
    assert math.isclose(ax.ActPos, 100.0, abs_tol=0.02)


@pytest.mark.parametrize("mode", [2, 3, 4, 5, 17, 22, -1, 255])
def test_invalid_buffer_mode_is_refused(rig: Rig, mode: int) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveAbsolute())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=10.0, Velocity=100.0, BufferMode=mode)
    rig.run_until(lambda: not mv.Busy, 10)
    assert mv.Error and mv.ErrorID == ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED == 0x4B64
    rig.run(5)
    assert ax.Status.StandStill and float(ax.NcToPlc["SetPos"]) == 0.0


def test_home_refuses_blending(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv1, hm = rig.watch(MC_MoveAbsolute(), MC_Home())
    st = {"go": False}

    def body(p: Any) -> None:
        mv1(Axis=ax, Execute=True, Position=100.0, Velocity=100.0)
        hm(Axis=ax, Execute=st["go"], Position=0.0, HomingMode=4, BufferMode=LOW)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go"] = True
    rig.run_until(lambda: not hm.Busy, 10)
    assert hm.Error and hm.ErrorID == 0x4B64
    rig.run_until(lambda: mv1.Done, 500)


def test_buffered_command_whose_execute_fell_still_runs_and_shows_done_once(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv1, mv2 = rig.watch(MC_MoveAbsolute(), MC_MoveAbsolute())
    st = {"go2": False}

    def body(p: Any) -> None:
        mv1(Axis=ax, Execute=True, Position=50.0, Velocity=100.0)
        mv2(Axis=ax, Execute=st["go2"], Position=80.0, Velocity=100.0, BufferMode=1)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go2"] = True
    rig.run(2)
    st["go2"] = False
    rig.run_until(lambda: mv2.Done, 1000)
    rig.run(1)
    assert not mv2.Done and not mv2.Busy
    assert sum(o["Done"] for o in rig.outputs(mv2)) == 1
    assert math.isclose(ax.ActPos, 80.0, abs_tol=0.02)


def test_buffered_command_while_mc_stop_holds_the_axis_is_refused(rig: Rig) -> None:
    """Stopping: "the axis remains locked for further motion commands" (0x42EF), buffered or not."""
    ax, _, calls = powered(rig)
    mv1, stop, mv2 = rig.watch(MC_MoveAbsolute(), MC_Stop(), MC_MoveAbsolute())
    st = {"stop": False, "go2": False}

    def body(p: Any) -> None:
        mv1(Axis=ax, Execute=True, Position=200.0, Velocity=100.0)
        stop(Axis=ax, Execute=st["stop"])
        mv2(Axis=ax, Execute=st["go2"], Position=300.0, Velocity=100.0, BufferMode=1)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["stop"] = True
    rig.run_until(lambda: stop.Active, 5)
    st["go2"] = True
    rig.run_until(lambda: not mv2.Busy, 10)
    assert mv2.Error and mv2.ErrorID == 0x42EF
    rig.run_until(lambda: stop.Done, 500)
    assert ax.Status.StandStill is False


def test_buffered_move_behind_halt_starts_at_its_done(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv1, halt, mv2 = rig.watch(MC_MoveAbsolute(), MC_Halt(), MC_MoveAbsolute())
    st = {"halt": False, "go2": False}

    def body(p: Any) -> None:
        mv1(Axis=ax, Execute=True, Position=200.0, Velocity=100.0)
        halt(Axis=ax, Execute=st["halt"])
        mv2(Axis=ax, Execute=st["go2"], Position=0.0, Velocity=100.0, BufferMode=1)

    calls["body"] = body
    rig.run_until(lambda: ax.ActPos > 20.0, 100)
    st["halt"] = True
    rig.run_until(lambda: halt.Active, 5)
    st["go2"] = True
    rig.run_until(lambda: mv2.Done, 1000)
    assert first(rig.outputs(halt), "Done") == first(rig.outputs(mv2), "Active")
    assert mv1.CommandAborted and math.isclose(ax.ActPos, 0.0, abs_tol=0.02)


def test_refused_aborting_command_leaves_the_active_and_the_buffered_one() -> None:
    """An Aborting command the NC refuses (target beyond the software limit, 0x4222) aborts nothing."""
    from nc_server.core import AxisParams

    rig = Rig(n_axes=1, params=AxisParams(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=500.0))
    ax, _, calls = powered(rig)
    mv1, mv2, mv3 = rig.watch(MC_MoveAbsolute(), MC_MoveAbsolute(), MC_MoveAbsolute())
    st = {"go2": False, "go3": False}

    def body(p: Any) -> None:
        mv1(Axis=ax, Execute=True, Position=100.0, Velocity=100.0)
        mv2(Axis=ax, Execute=st["go2"], Position=150.0, Velocity=100.0, BufferMode=NEXT)
        mv3(Axis=ax, Execute=st["go3"], Position=900.0, Velocity=100.0)

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go2"] = True
    rig.run_until(lambda: ax.Status.CmdBuffered, 5)
    st["go3"] = True
    rig.run_until(lambda: not mv3.Busy, 10)
    assert mv3.Error and mv3.ErrorID == ErrorCodes.NC_TARGET_POSITION_NOT_ALLOWED
    assert mv1.Active and mv2.Busy and not mv2.Active and ax.Status.CmdBuffered
    rig.run_until(lambda: mv2.Done, 1000)
    assert mv1.Done and not ax.Status.CmdBuffered and math.isclose(ax.ActPos, 150.0, abs_tol=0.02)
