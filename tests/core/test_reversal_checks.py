"""0x4289 (illegal motion reversal) and 0x423A (velocity overflow) on every path that gives a moving axis
a new plan: a start (MoveAbsolute/MoveVelocity Aborting), MC_ChangeDynParam, MC_NewPos/MC_NewPosAndVelo.

TcMC 4.20 names both codes for *weaker dynamics* only ("the direction of travel would reverse due to weaker
dynamic parameters", "the velocity would exceed ... due to weaker dynamic parameters"); MC_NewPos may set a
target "greater or smaller than the old" (3.7). So a reversal or a peak that the running motion's own jerk
cannot avoid any more (the running positioning turns the axis towards its target behind it; an axis still
speeding up after an override cut) is no refusal (:func:`nc_server.core.checks.check_reversal`). Before,
bench/nc_cycle.py's stress load saw 9 % of its re-targets refused 0x4289 so, all from such states."""
from __future__ import annotations

from typing import Any

import pytest

from nc_schema import CmdState, ErrorCodes as E
from nc_server.core import NcCore
from znc_testing.engine_check import Trace
from znc_testing.nc_core import cmd, powered, snapshot

DONE = int(CmdState.DONE)
# bench/nc_cycle.py BENCH_PARAMS
BENCH = dict(AxisVeloMax=1000.0, AxisAcc=5000.0, AxisDec=5000.0, AxisJerk=50000.0,
             AxisEnPositionLagMonitoring=False)
JERK = 50000.0


def turning(v_turn: float = 150.0, **params: Any) -> NcCore:
    """MoveAbsolute(+1000) at 400 u/s, then MoveAbsolute(-1000) Aborting: braking at -AxisDec, at
    v_turn u/s, where a^2 / 2j = 250 > v: the running move turns the axis (towards -1000) whatever comes."""
    core = powered(1, **{**BENCH, **params})
    cmd(core, "MoveAbsolute", Position=1000.0, Velocity=400.0)
    while core.nctoplc[0]["SetVelo"] < 400.0 - 1e-9:
        core.step()
    assert cmd(core, "MoveAbsolute", Position=-1000.0, Velocity=400.0)["error"] == 0
    while core.nctoplc[0]["SetVelo"] > v_turn:
        core.step()
    r = core.nctoplc[0]
    assert float(r["SetAcc"]) ** 2 / (2 * JERK) > float(r["SetVelo"]) > 0  # past the point of no return
    return core


def committed_dip(core: NcCore) -> float:
    """How far below 0 the velocity goes at least, with the axis jerk, from the current state."""
    r = core.nctoplc[0]
    return float(r["SetAcc"]) ** 2 / (2 * JERK) - float(r["SetVelo"])


def test_a_retarget_ahead_while_the_running_move_turns_the_axis_is_accepted():
    """The stress load's refused re-targets: the axis still moves +, the running move already reverses
    it towards its target behind; MoveAbsolute back to +1000 (ahead) is a new motion of the same
    dynamics: accepted (was 0x4289), the axis turns no further than it had to and ends Done there."""
    core = turning()
    dip = committed_dip(core)
    tr = Trace(core)
    rep = cmd(core, "MoveAbsolute", Position=1000.0, Velocity=400.0)
    assert rep["error"] == 0, rep
    tr.settle()  # within AxisVeloMax, AxisAcc/Dec, AxisJerk every cycle
    assert tr.rows[-1]["SetPos"] == 1000.0 and int(tr.rows[-1]["CmdNo"]) == rep["CmdNo"]
    assert int(tr.rows[-1]["CmdState"]) == DONE
    assert -tr.col("SetVelo").min() <= dip * (1 + 1e-6) + 1e-6


@pytest.mark.parametrize("args", [dict(Jerk=JERK), dict(Jerk=2 * JERK), dict(Deceleration=4000.0)])
def test_change_dyn_param_while_the_move_turns_to_its_target_is_accepted(args):
    """MC_ChangeDynParam on a positioning that turns the axis towards its target (behind it): the reversal
    is the move's own, not of the new dynamics (TcMC 4.20): accepted (every such change was 0x4289)."""
    core = turning()
    tr = Trace(core, jerk=max(JERK, args.get("Jerk", 0.0)))
    rep = cmd(core, "ChangeDynParam", **args)
    assert rep["error"] == 0, rep
    tr.settle()
    assert tr.rows[-1]["SetPos"] == -1000.0 and int(tr.rows[-1]["CmdState"]) == DONE


def twin_unchanged(setup: Any, name: str, code: int, **args: Any) -> None:
    """``name`` is refused with ``code`` and changes nothing: a twin core without the command runs
    bit-identically (NCTOPLC and NCJOBS), cycle by cycle, until both stand still (or 2 s)."""
    a, b = setup(), setup()
    before = snapshot(a)
    rep = cmd(a, name, **args)
    assert rep["error"] == code, rep
    assert "CmdNo" not in rep and snapshot(a) == before
    for _ in range(2000):
        a.step()
        b.step()
        assert a.nctoplc.tobytes() == b.nctoplc.tobytes() and a.ncjobs.tobytes() == b.ncjobs.tobytes()
        if not a.moving.any():
            break


def accelerating_after_an_override_cut(how: str) -> NcCore:
    """Speeding up at 3150 u/s^2 at 106 u/s although the override was just cut to 10 %: the axis peaks at
    ~205 u/s with its jerk whatever comes (its running plan does so too)."""
    core = powered(1, **BENCH)
    if how == "MoveVelocity":
        cmd(core, "MoveVelocity", Velocity=400.0, Direction=1)
    else:
        cmd(core, "MoveAbsolute", Position=5000.0, Velocity=400.0)
    while core.nctoplc[0]["SetVelo"] < 100.0:
        core.step()
    assert cmd(core, "SetOverride", Override=10.0)["error"] == 0
    core.step()
    r = core.nctoplc[0]
    assert float(r["SetVelo"]) + float(r["SetAcc"]) ** 2 / (2 * JERK) > 2 * 40.0 * 1.2
    return core


@pytest.mark.parametrize("how,args", [
    ("MoveVelocity", dict(Mode=2, NewPos=0.0, NewVelo=300.0, ActivationPos=0.0)),   # was 0x423A
    ("MoveAbsolute", dict(Mode=3, NewPos=4000.0, NewVelo=300.0, ActivationPos=0.0)),
    ("MoveAbsolute", dict(Mode=2, NewPos=0.0, NewVelo=300.0, ActivationPos=0.0)),
])
def test_a_new_velocity_while_the_axis_overshoots_after_an_override_cut_is_accepted(how, args):
    """NewPosAndVelo keeps the dynamics: a peak the running jerk cannot avoid is no 0x423A."""
    core = accelerating_after_an_override_cut(how)
    peak = float(core.nctoplc[0]["SetVelo"]) + float(core.nctoplc[0]["SetAcc"]) ** 2 / (2 * JERK)
    tr = Trace(core, vmax=peak * (1 + 1e-6))
    rep = cmd(core, "NewPosAndVelo", **args)
    assert rep["error"] == 0, rep
    tr.until(lambda r: abs(float(r["SetVelo"]) - 30.0) < 1e-9)  # NewVelo at 10 %
    assert tr.col("SetVelo").max() <= peak * (1 + 1e-6)


def test_a_weaker_jerk_still_overshoots_after_an_override_cut_is_refused_and_changes_nothing():
    """Beyond what the running jerk implies: 0x423A as before, the move unchanged."""
    twin_unchanged(lambda: accelerating_after_an_override_cut("MoveAbsolute"), "ChangeDynParam",
                   E.NC_VELOCITY_OVERFLOW, Jerk=JERK / 10)


def test_the_stress_sequence_refuses_no_command():
    """bench/nc_cycle.py's stress load on 8 axes, 3000 cycles: one command a cycle, round robin, each axis
    cycling re-target (MoveAbsolute Aborting +-1000), MC_Buffered, NewPos, re-target, BlendingNext,
    NewPosAndVelo. Before, 11 re-targets were refused 0x4289 (all with the running move turning the axis,
    0.8..5.6 u/s past the point of no return), and the Buffered/BlendingNext behind them 0x4292."""
    n = 8
    core = powered(n, **BENCH)
    mix = ("retarget", "buffered", "new_pos", "retarget", "blending_next", "new_pos_velo")
    count, sign = [0] * n, [-1.0] * n

    def command(i: int) -> dict[str, Any]:
        kind = mix[count[i] % len(mix)]
        count[i] += 1
        v = 100.0 + (i % 4) * 100.0
        if kind == "retarget":
            sign[i] = -sign[i]
        s = sign[i]
        args: dict[str, Any]
        if kind == "retarget":
            name, args = "MoveAbsolute", dict(Position=1000.0 * s, Velocity=v, BufferMode=0)
        elif kind == "buffered":
            name, args = "MoveAbsolute", dict(Position=-1000.0 * s, Velocity=200.0, BufferMode=1)
        elif kind == "blending_next":
            name, args = "MoveAbsolute", dict(Position=-1000.0 * s, Velocity=200.0, BufferMode=20)
        elif kind == "new_pos":
            name, args = "NewPos", dict(NewPos=900.0 * s)
        else:
            name, args = "NewPosAndVelo", dict(Mode=1 if i % 2 else 3, NewPos=800.0 * s,
                                               NewVelo=150.0 + (i % 4) * 50.0, ActivationPos=0.0)
        return cmd(core, name, axis=i + 1, **args)

    refused = []
    for i in range(n):
        assert command(i)["error"] == 0
    for c in range(3000):
        rep = command(c % n)
        if rep["error"]:
            refused.append((c, rep["cmd"], hex(rep["error"])))
        core.step()
        assert not core.nctoplc["ErrorCode"].any()
    assert refused == []


def braking_since(k: int) -> NcCore:
    """MoveAbsolute(+1000) at 400 u/s, then MoveAbsolute(-1000) Aborting and k cycles of its braking (jerk
    AxisJerk up to -AxisDec): from k = 92 on the running move turns the axis (a^2 / 2j > v), before not."""
    core = powered(1, **BENCH)
    cmd(core, "MoveAbsolute", Position=1000.0, Velocity=400.0)
    while core.nctoplc[0]["SetVelo"] < 400.0 - 1e-9:
        core.step()
    assert cmd(core, "MoveAbsolute", Position=-1000.0, Velocity=400.0)["error"] == 0
    for _ in range(k):
        core.step()
    assert float(core.nctoplc[0]["SetVelo"]) > 0
    return core


@pytest.mark.parametrize("k", [84, 88, 92, 100, 108])
def test_a_weaker_jerk_is_refused_before_and_after_the_running_move_starts_turning(k):
    """MoveAbsolute(+1000, Jerk 30000) Aborting during that braking turns the axis: before k = 92 the weaker
    jerk alone causes the turn; after, the running move turns it anyway, but the weaker jerk 72..167 u/s
    deeper (-(a^2 / 2j) + v with 30000 against 50000): that part is the new dynamics' turn. Refused 0x4289,
    the move unchanged (bc642d3 accepted it from k = 92 on and let the axis turn to -164..-307 u/s)."""
    core = braking_since(k)
    assert (committed_dip(core) > 0) == (k >= 92)
    twin_unchanged(lambda: braking_since(k), "MoveAbsolute", E.NC_ILLEGAL_REVERSAL,
                   Position=1000.0, Velocity=100.0, Jerk=30000.0)


@pytest.mark.parametrize("k", [92, 100, 108])
@pytest.mark.parametrize("jerk", [0.0, 2 * JERK])
def test_the_same_or_a_stronger_jerk_re_target_while_the_move_turns_is_accepted(k, jerk):
    """The same state with the running jerk (0: AxisJerk) or a stronger one: the plan turns no deeper than
    the running move has to; accepted, Done at +1000."""
    core = braking_since(k)
    dip = committed_dip(core)
    tr = Trace(core, jerk=max(JERK, jerk))
    rep = cmd(core, "MoveAbsolute", Position=1000.0, Velocity=100.0, Jerk=jerk)
    assert rep["error"] == 0, rep
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 1000.0 and int(tr.rows[-1]["CmdState"]) == DONE
    assert -tr.col("SetVelo").min() <= dip * (1 + 1e-6) + 1e-6
