"""The blocks the other integration files do not cover, and every BufferMode's transition, through
the real distributed path: an ``nc-server`` process (default configuration: axes 1-3 linear, 4
modulo 360) and a ``plc-run plc_agent.py`` process on 127.0.0.1, free ports, both killed with their
process groups at the end (fixtures in conftest.py).

The agent reports every change of a block's outputs with the PLC cycle and the axis data of that
cycle (``Rec``); ``plc.trace(axis)`` adds the axis's SetPos/SetVelo of every PLC cycle. Positions
and the order of the outputs are asserted, never how fast anything happened: the simulated axes
move by NC cycles, the wall clock of a loaded 2-core machine is not theirs. Velocities are read
from the NC's set-points (a property of the planned motion), and only where a PLC stall can make
the check weaker, never wrong.
"""
from __future__ import annotations

import math

import pytest

from znc_testing.plc_harness import T, PlcProcess, Rec, ended, exclusive, first_cycle, power_on

#: position tolerance at a target: the axes' AxisTargetPositionWindow (X 0.02)
WINDOW = 0.02


def done_at(p: PlcProcess, name: str, pos: float, where: str = "ActPos") -> Rec:
    """Wait for block ``name``'s result; it must be Done with ``where`` at ``pos``: ActPos within
    the target window (a move's Done waits for it), or SetPos exactly (a Done at the logical end:
    MC_Halt, or a move whose buffered successor took over)."""
    r = p.wait(name, ended, T)
    assert r.o.get("Done"), (r, p.history(name)[-6:])
    assert math.isclose(r.a[where], pos, abs_tol=WINDOW if where == "ActPos" else 1e-6), r
    return r


def clean(recs: list[Rec]) -> None:
    """The output rules held and the block never ended with Error or CommandAborted."""
    exclusive(recs)
    assert not any(r.o.get("Error") or r.o.get("CommandAborted") for r in recs), recs


def moving_records(p: PlcProcess, axis: int, c0: int, c1: int) -> list[Rec]:
    """The trace samples of ``axis`` from PLC cycle ``c0`` to ``c1``."""
    return [s for s in p.trace_of(axis) if c0 <= s.c <= c1]


# ---- amendments ---------------------------------------------------------------------------------
def test_change_dyn_param_applies_to_the_running_move_and_is_done_with_it(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("rs", "MC_ReadStatus", Enable=True)
    # soft ramps (120 u/s^2: 60 u of braking from 120 u/s, starting at 880) ...
    plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=940.0, Velocity=120.0, Acceleration=120.0,
            Deceleration=120.0)
    cruise = plc.wait("rs", lambda r: r.o["ConstantVelocity"] and r.a["ActPos"] > 1.0, T)
    # ... replaced at constant velocity by hard ones (5000 u/s^2 with the axis jerk: ~7.5 u); the axis
    # cruises from 60 to 880: the amendment has more than 6 s to land before 850, however loaded the machine
    plc.set("cd", "MC_ChangeDynParam", Execute=True, Acceleration=5000.0, Deceleration=5000.0)
    busy = plc.wait("cd", lambda r: r.o["Busy"], T)
    assert busy.a["ActPos"] < 850.0, f"issued too late to matter: {busy}"
    # (the hard braking takes ~0.13 s: a stalled PLC may see none of it, only the standstill at 940, which
    # passes the check below; the old deceleration's 1 s of braking it would see)
    brake = plc.wait("rs", lambda r: (r.o["Decelerating"] or r.o["StandStill"]) and r.c > cruise.c, T)
    done = done_at(plc, "mv", 940.0)
    cd = plc.wait("cd", ended, T)
    assert cd.o["Done"], cd
    # Done "when the axis is at its destination": with the move's block, not on the reply
    assert first_cycle(plc.history("cd"), "Done") == first_cycle(plc.history("mv"), "Done") == done.c
    # the first sample showing the braking is at or after its start: the distance left is at most
    # the real braking distance, ~7.5 u with the new deceleration (60 u with the old one)
    assert 940.0 - brake.a["SetPos"] < 25.0, f"braked with the old deceleration: {brake}"
    clean(plc.history("cd"))
    clean(plc.history("mv"))


@pytest.mark.parametrize("mode, activation", [(3, None), (11, 60.0)])  # CHANGE_POSANDVELO, ..._AT_SWITCHPOS
def test_new_pos_and_velo(plc: PlcProcess, mode: int, activation: float | None) -> None:
    power_on(plc)
    plc.trace(1)
    # slow (10 u/s): the amendment has 5.5 s to land before the switching position
    plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=100.0, Velocity=10.0)
    plc.wait_trace(1, lambda s: s.a["SetPos"] > 5.0, T)
    plc.set("npv", "MC_NewPosAndVelo", Execute=True, Mode=mode, NewPos=150.0, NewVelo=150.0,
            ActivationPos=activation or 0.0)
    npv = plc.wait("npv", ended, T)
    assert npv.o["Done"], npv
    assert activation is None or npv.a["SetPos"] < activation, f"issued too late for the test: {npv}"
    assert not any(ended(r) for r in plc.history("mv")), "the amended move goes on"
    done = done_at(plc, "mv", 150.0)
    clean(plc.history("mv"))
    clean(plc.history("npv"))
    samples = moving_records(plc, 1, 0, done.c)
    assert max(abs(s.a["SetVelo"]) for s in samples) > 100.0, "the new velocity was used"
    assert max(abs(s.a["SetVelo"]) for s in samples) <= 150.0 + 1e-6
    if activation is not None:  # before the switching position: the old velocity
        before = [s for s in samples if s.a["SetPos"] < activation - 0.5]
        assert before and max(abs(s.a["SetVelo"]) for s in before) <= 10.0 + 1e-6, before[-3:]


def test_move_additive_adds_to_the_aborted_target(plc: PlcProcess) -> None:
    power_on(plc)
    plc.trace(1)
    # slow (15 u/s): the additive move has 6 s to land while this one runs, and so has add2 below
    plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=100.0, Velocity=15.0)
    plc.wait_trace(1, lambda s: s.a["SetPos"] > 5.0, T)
    plc.set("add", "MC_MoveAdditive", Execute=True, Distance=30.0, Velocity=100.0)
    add = done_at(plc, "add", 130.0)  # 100 + 30, not where the axis was (~5) + 30
    mv = plc.wait("mv", ended, T)
    assert mv.o["CommandAborted"] and mv.c <= add.c, mv
    # aborted when the additive move starts (seen no later than the new block sees its reply)
    assert first_cycle(plc.history("mv"), "CommandAborted") <= first_cycle(plc.history("add"), "Active")
    clean(plc.history("add"))
    # at rest: added to the set position
    c = plc.edge("add", Distance=-20.0)
    r = plc.wait("add", lambda r: r.c > c and ended(r), T)
    assert r.o["Done"] and math.isclose(r.a["ActPos"], 110.0, abs_tol=WINDOW), r
    # buffered behind a running move: added to that move's target
    c = plc.edge("mv", Position=200.0)
    plc.wait("mv", lambda r: r.c > c and r.o["Active"], T)
    plc.set("add2", "MC_MoveAdditive", Execute=True, Distance=15.0, Velocity=100.0, BufferMode=1)
    w = plc.wait("add2", lambda r: r.o["Busy"], T)
    assert not w.o["Active"] and w.a["SetPos"] < 200.0, w
    done_at(plc, "add2", 215.0)
    h1, h2 = [r for r in plc.history("mv") if r.c > c], plc.history("add2")
    assert first_cycle(h1, "Done") == first_cycle(h2, "Active")
    clean(h1)
    clean(h2)


@pytest.mark.parametrize("fb, inputs", [("MC_MoveContinuousAbsolute", {"Position": 60.0}),
                                        ("MC_MoveContinuousRelative", {"Distance": 50.0})])
def test_move_continuous_in_end_velocity(plc: PlcProcess, fb: str, inputs: dict) -> None:
    power_on(plc)
    plc.set("start", "MC_MoveAbsolute", Execute=True, Position=10.0, Velocity=100.0)
    done_at(plc, "start", 10.0)
    plc.trace(1)
    plc.set("mc", fb, Execute=True, Velocity=100.0, EndVelocity=20.0, **inputs)  # target 60 either way
    r = plc.wait("mc", ended, T)
    assert r.o["InEndVelocity"], (r, plc.history("mc"))
    assert 60.0 - 1e-6 <= r.a["SetPos"] < 80.0, f"InEndVelocity before the target or long after: {r}"
    assert math.isclose(r.a["SetVelo"], 20.0, rel_tol=1e-3), r
    assert not r.o["Busy"] and not r.o["Active"], "finished: the axis is no longer monitored"
    # the axis goes on with EndVelocity, a continuous motion
    later = plc.wait_trace(1, lambda s: s.c > r.c and s.a["SetPos"] > r.a["SetPos"] + 2.0, T)
    assert math.isclose(later.a["SetVelo"], 20.0, rel_tol=1e-3) and later.a["State"] == "CONTINOUSMOTION", later
    plc.set("halt", "MC_Halt", Execute=True)
    h = plc.wait("halt", ended, T)
    assert h.o["Done"] and h.a["State"] == "STANDSTILL", h
    assert plc.last("mc").o["InEndVelocity"], "held while Execute stays TRUE; no CommandAborted"
    clean(plc.history("mc"))


def test_move_absolute_or_restart_retriggered_while_moving(plc: PlcProcess) -> None:
    power_on(plc)
    plc.trace(1)
    # slow (20 u/s): the restart has 3.5 s to land before 80, 7 s before 150
    plc.set("mv", "MC_MoveAbsoluteOrRestart", Execute=True, Position=200.0, Velocity=20.0)
    plc.wait_trace(1, lambda s: s.a["SetPos"] > 10.0, T)
    c = plc.edge("mv", Position=80.0)  # a rising edge while Busy: not ignored, a new target
    done = done_at(plc, "mv", 80.0)
    hist = plc.history("mv")
    clean(hist)
    active = first_cycle(hist, "Active")
    assert active < c < done.c
    assert all(r.o["Busy"] and r.o["Active"] for r in hist if active <= r.c < done.c), \
        "Busy and Active across the restart, no result in between"
    assert max(s.a["SetPos"] for s in plc.trace_of(1)) < 200.0 - 50.0, "the first target was given up"


# ---- stops --------------------------------------------------------------------------------------
def test_oriented_stop_on_the_modulo_axis(plc: PlcProcess) -> None:
    power_on(plc, axis=4)
    plc.set("rest", "MC_OrientedStop", axis=4, Execute=True, Position=90.0)
    r = plc.wait("rest", ended, T)
    assert r.o["Error"] and r.o["ErrorID"] == 0x4B03, f"refused on an axis at rest: {r}"
    plc.set("mv", "MC_MoveVelocity", axis=4, Execute=True, Velocity=180.0)
    plc.wait("mv", lambda r: r.o["InVelocity"], T)
    plc.set("bad", "MC_OrientedStop", axis=4, Execute=True, Position=360.0)  # outside [0, 360)
    r = plc.wait("bad", ended, T)
    assert r.o["Error"] and r.o["ErrorID"] == 0x4281 and r.a["State"] == "CONTINOUSMOTION", r
    plc.set("os", "MC_OrientedStop", axis=4, Execute=True, Position=90.0)
    active = plc.wait("os", lambda r: r.o["Active"], T)
    done = plc.wait("os", ended, T)
    assert done.o["Done"] and done.a["State"] == "STANDSTILL", done
    end = done.a["SetPos"]
    assert math.isclose(end % 360.0, 90.0, abs_tol=1e-6), done
    # the next reachable 90: less than a turn (plus the braking distance, 4.5 deg) beyond the start
    assert 0.0 < end - active.a["SetPos"] < 360.0 + 10.0, (active, done)
    clean(plc.history("os"))
    plc.wait_cycles(5)
    assert plc.last("os").o["Done"], "Done held while Execute stays TRUE"


def test_halt_buffered_behind_a_move_and_behind_a_velocity(plc: PlcProcess) -> None:
    power_on(plc)
    # slow (25 u/s): the Halt has 6 s to land while the move runs
    plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=150.0, Velocity=25.0)
    plc.wait("mv", lambda r: r.o["Active"], T)
    plc.set("halt", "MC_Halt", Execute=True, BufferMode=1)  # MC_Buffered: after the move, not now
    w = plc.wait("halt", lambda r: r.o["Busy"], T)
    assert not w.o["Active"], w
    halt = done_at(plc, "halt", 150.0, "SetPos")  # an Aborting Halt would have stopped short of 150
    done_at(plc, "mv", 150.0, "SetPos")
    h1, h2 = plc.history("mv"), plc.history("halt")
    # the Halt takes over at the move's logical end, at rest: nothing left to stop. The NC activates it in the
    # cycle the move ends and ends it in the next NC cycle (tests/core: one frame apart), so the PLC sees its Done
    # in the PLC cycle of the move's Done or, when its view of the NC fell on the frame between, the next one
    # (Active may never show, or show in the move's Done cycle when that view fell on the frame between); Busy
    # until then, never Active while the move runs
    mv_done = first_cycle(h1, "Done")
    assert mv_done <= halt.c <= mv_done + 1, (h1[-3:], h2[-3:])
    assert all(r.o["Busy"] for r in h2 if r.c < halt.c), h2
    assert not any(r.o["Active"] for r in h2 if r.c < mv_done), h2
    clean(h1)
    clean(h2)
    # behind a velocity job: the Halt starts once the velocity is reached (InVelocity), then stops
    plc.set("vel", "MC_MoveVelocity", Execute=True, Velocity=50.0)
    plc.set("halt2", "MC_Halt", Execute=True, BufferMode=1)
    h = plc.wait("halt2", ended, T)
    assert h.o["Done"] and h.a["State"] == "STANDSTILL" and h.a["ActPos"] > 150.0 + 1.0, h
    v1, v2 = plc.history("vel"), plc.history("halt2")
    # (its Active, ~0.1 s of braking, may never show in a PLC cycle of a loaded machine: then its Done)
    started = next(r.c for r in v2 if r.o["Active"] or r.o["Done"])
    assert first_cycle(v1, "InVelocity") <= started, (v1, v2)
    clean(v1)
    clean(v2)


# ---- position administration ----------------------------------------------------------------
def test_set_reference_flag(plc: PlcProcess) -> None:
    pw = power_on(plc)
    assert not pw.a["Homed"]
    plc.set("ref", "MC_SetReferenceFlag", Execute=True, ReferenceFlag=True)
    r = plc.wait("ref", ended, T)
    assert r.o["Done"] and r.a["Homed"], f"the Homed bit is visible when Done is: {r}"
    c = plc.edge("ref", ReferenceFlag=False)
    r = plc.wait("ref", lambda r: r.c > c and ended(r), T)
    assert r.o["Done"] and not r.a["Homed"], r
    exclusive(plc.history("ref"))


def test_set_actual_position_at_standstill_and_on_the_fly(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("sp", "MC_SetActualPosition", Execute=True, Position=50.0)
    r = plc.wait("sp", ended, T)
    assert r.o["Done"] and math.isclose(r.a["ActPos"], 50.0, abs_tol=1e-9), f"visible when Done is: {r}"
    assert math.isclose(r.a["SetPos"], 50.0, abs_tol=1e-9), r
    plc.trace(1)
    # to 350 in 10 s: the refusal and the shift below have 9.8 s to land while it moves
    plc.set("mv", "MC_MoveRelative", Execute=True, Distance=300.0, Velocity=30.0)
    plc.wait_trace(1, lambda s: s.a["SetPos"] > 55.0, T)
    c = plc.edge("sp", Position=0.0)
    r = plc.wait("sp", lambda r: r.c > c and ended(r), T)
    assert r.o["Error"] and r.o["ErrorID"] == 0x4B01, f"refused while moving: {r}"
    plc.set("fly", "MC_SetActualPositionOnTheFly", Execute=True, ActualPosition=200.0, PreviousPosition=100.0)
    f = plc.wait("fly", ended, T)
    assert f.o["Done"], f
    done = done_at(plc, "mv", 450.0)  # shifted by +100 while moving: the same distance, 100 further
    assert f.c <= done.c and f.a["ActPos"] > 150.0, (f, done)
    clean(plc.history("mv"))
    clean(plc.history("fly"))


# ---- AXACT --------------------------------------------------------------------------------------
def test_axact_modes_and_stop(plc: PlcProcess) -> None:
    power_on(plc)  # AXACT only sends commands; MC_Power of this PLC holds the axis
    plc.trace(1)
    plc.set("ax", "AXACT", AXID=1, START=True, MODE=1, TARGPOS=30.0, VELOCITY=100.0)  # absolute
    r = plc.wait("ax", lambda r: not r.o["BUSY"], T)
    assert not r.o["ERR"], r
    plc.wait_trace(1, lambda s: s.a["State"] == "STANDSTILL" and abs(s.a["ActPos"] - 30.0) < WINDOW, T)
    c = plc.edge("ax", "START", MODE=2, TARGPOS=-5.0)  # relative
    r = plc.wait("ax", lambda r: r.c > c and not r.o["BUSY"], T)
    assert not r.o["ERR"], r
    plc.wait_trace(1, lambda s: s.c > c and s.a["State"] == "STANDSTILL" and abs(s.a["ActPos"] - 25.0) < WINDOW, T)
    c = plc.edge("ax", "START", MODE=3, VELOCITY=40.0)  # endless, positive
    plc.wait_trace(1, lambda s: s.c > c and s.a["State"] == "CONTINOUSMOTION"
                   and math.isclose(s.a["SetVelo"], 40.0, rel_tol=1e-9), T)
    c = plc.edge("ax", "STOP")
    r = plc.wait("ax", lambda r: r.c > c and not r.o["BUSY"], T)
    assert not r.o["ERR"], r
    s = plc.wait_trace(1, lambda s: s.c > c and s.a["State"] == "STANDSTILL", T)
    assert not s.a["Locked"] and s.a["ActPos"] > 25.0, f"STOP is a Halt: not locked: {s}"
    plc.set("ax", STOP=False)
    c = plc.edge("ax", "START", MODE=6)
    r = plc.wait("ax", lambda r: r.c > c and r.o["ERR"], T)
    assert r.o["ERRID"] == 0x4B04 and not r.o["BUSY"], r


# ---- BufferMode transitions ---------------------------------------------------------------------
#: the velocity a blending mode passes the first target with: (v1, v2) -> velocity
BLEND_VELOCITY = {18: min, 19: lambda v1, v2: v1, 20: lambda v1, v2: v2, 21: max}


def two_moves(plc: PlcProcess, mode: int, first: str, second: str, p0: float, v1: float, v2: float) -> None:
    """From rest at ``p0``: block ``first`` to p0 + 100 at ``v1``, block ``second`` (sent while the
    first runs, with ``mode``) to p0 + 200 at ``v2``, both at 1000 u/s^2; checks the transition."""
    dyn = {"Acceleration": 1000.0, "Deceleration": 1000.0}
    p1, p2 = p0 + 100.0, p0 + 200.0
    plc.set(first, "MC_MoveAbsolute", Execute=True, Position=p1, Velocity=v1, **dyn)
    plc.wait(first, lambda r: r.o["Active"], T)
    plc.set(second, "MC_MoveAbsolute", Execute=True, Position=p2, Velocity=v2, BufferMode=mode, **dyn)
    w = plc.wait(second, lambda r: r.o["Busy"], T)
    assert not w.o["Active"] and w.a["SetPos"] < p1, f"waiting behind {first}: {w}"
    done = done_at(plc, second, p2)
    h1, h2 = plc.history(first), plc.history(second)
    clean(h1)
    clean(h2)
    k = first_cycle(h2, "Active")
    assert first_cycle(h1, "Done") == k, f"{first} Done exactly when {second} becomes Active"
    assert all(r.o["Busy"] and not r.o["Active"] for r in h2 if r.c < k), h2
    assert all(r.o["Done"] for r in h1 if r.c >= k), "Done held while Execute stays TRUE"
    samples = moving_records(plc, 1, first_cycle(h1, "Active"), done.c)
    near = [s for s in samples if abs(s.a["SetPos"] - p1) < 5.0]
    if mode == 1:  # comes to rest at p1 (|v| < 100 u/s within 5 u of it, for ~0.2 s)
        assert near and min(abs(s.a["SetVelo"]) for s in near) < 75.0, near
        return
    # no standstill between: fast everywhere between the ramps of the whole motion
    between = [s for s in samples if p0 + 20.0 < s.a["SetPos"] < p2 - 20.0]
    assert between and min(abs(s.a["SetVelo"]) for s in between) > 100.0, between
    assert "STANDSTILL" not in {s.a["State"] for s in between}
    # the velocity at p1 (if the second move waited from early on: 150 -> 250 takes 20 u, a later
    # one lowers the blending velocity as the distance left allows; within 5 u of p1 the ramps to
    # or from it change it by less than 30 u/s downwards, 50 upwards)
    v = BLEND_VELOCITY[mode](v1, v2)
    if w.a["SetPos"] < p0 + 40.0:
        for s in near:
            assert v - 30.0 <= abs(s.a["SetVelo"]) <= min(v + 50.0, max(v1, v2) + 1e-6), (mode, v, s)


@pytest.mark.parametrize("mode", [1, 18, 19, 20, 21])
def test_buffer_mode_transition(plc: PlcProcess, mode: int) -> None:
    """Twice, so that each blending mode's velocity differs from another mode's: slower then faster
    (150, 250: Low = Previous = 150, Next = High = 250), then faster then slower (250, 150: Low =
    Next = 150, Previous = High = 250). The first block is Done in the very cycle the second
    becomes Active; Buffered comes to rest at the first target, blending passes it at the mode's
    velocity."""
    power_on(plc)
    plc.trace(1)
    two_moves(plc, mode, "m1", "m2", 0.0, 150.0, 250.0)
    two_moves(plc, mode, "m3", "m4", 200.0, 250.0, 150.0)
