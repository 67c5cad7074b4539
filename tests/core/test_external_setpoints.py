"""The external set-point generator through the NC (MC_ExtSetPointGenEnable/Disable/Feed, TcMC 4.16-4.18).

Cycle-stepped NcCore tests: enabling at standstill (the job, StateDWord.ExtSetPointGenEnabled,
NCJOBS SyncFlags), feeds of PLCTONC ExtSetPos/ExtSetVelo/ExtSetAcc at PLC/NC cycle ratios 1, 4 and
10 from known trajectories (applied exactly in the cycle they arrive, extrapolated with the fed
velocity and acceleration in between: p = ExtSetPos + ExtSetVelo t + ExtSetAcc t^2 / 2), the
no-jump rule at the start, jumping or too fast feeds (0x4359 and a stop), disabling while moving
and at standstill, motion commands while enabled (0x4B08; AxisAllowMotionCmdToExtSetAxis: a
seamless take-over), MC_Stop, the refusals (0x4B01, 0x4B04) and the target position monitoring of
Position/PositionType.

Dynamics: the axis defaults (AxisVeloMax 1000, AxisAcc/AxisDec 5000, AxisJerk 50000); the fed
trajectories stay well inside them (at most 400 u/s, 2000 u/s^2, 50000 u/s^3). The simulated drive
has no lag (SimTimeConstant 0) where actual positions matter.
"""
from __future__ import annotations

import numpy as np
import pytest

from nc_schema import CmdState, ErrorCodes as E, MC_AxisStates, StateDWord
from nc_server.core.planning import Dynamics, StartState, plan_position, position_at
from znc_testing.nc_core import cmd, powered, run_until, snapshot, state

CT = 0.001
ACTIVE, DONE, ABORTED, ERROR = (int(CmdState.ACTIVE), int(CmdState.DONE), int(CmdState.ABORTED),
                                int(CmdState.ERROR))
EXT = int(StateDWord.ExtSetPointGenEnabled)
IN_TARGET = int(StateDWord.InTargetPosition)
SYNC_ENABLED, SYNC_FOLLOWING = 1, 2


# -- helpers ------------------------------------------------------------------------------------------
#: most tests feed a velocity from the first sample on (a velocity step): an axis whose AxisAcc allows
#: that in one cycle (the NC faults velocity steps beyond max(AxisAcc, AxisDec) x the feed period)
STEPS = dict(AxisAcc=1e6, AxisDec=1e6)


def feed(core, p, v=0.0, a=0.0, i=0):
    """MC_ExtSetPointGenFeed: the PLC's next PLCTONC with the set-point (applied from the next step)."""
    rec = core.plctonc[i].copy()
    rec["ExtSetPos"], rec["ExtSetVelo"], rec["ExtSetAcc"] = p, v, a
    rec["ExtSetDirection"] = 0 if v == 0 else (1 if v > 0 else -1)
    core.set_plctonc(i, rec)


def sp(core, i=0):
    r = core.nctoplc[i]
    return float(r["SetPos"]), float(r["SetVelo"]), float(r["SetAcc"])


def dword(core, i=0):
    return int(core.nctoplc[i]["StateDWord"])


def sync_flags(core, i=0):
    return int(core.ncjobs[i]["SyncFlags"])


def job(core, i=0):
    return int(core.nctoplc[i]["CmdNo"]), int(core.nctoplc[i]["CmdState"])


def ended(core, i=0):
    e = core.ncjobs[i]["Ended"][0]
    return int(e["CmdNo"]), int(e["CmdState"]), int(e["ErrorId"])


def enabled_at(x0=0.0, **params):
    """A standing axis at ``x0`` with the generator enabled and following (first feed: the SetPos)."""
    core = powered(1, SimTimeConstant=0.0, **{**STEPS, **params})
    if x0:
        assert cmd(core, "SetActualPosition", Position=x0)["error"] == 0
        core.step()
    feed(core, x0)
    r = cmd(core, "ExtSetPointGenEnable")
    assert r["error"] == 0, r
    core.step()
    assert sync_flags(core) == SYNC_ENABLED | SYNC_FOLLOWING
    return core, r["CmdNo"]


def assert_no_jump(rows, amax=10000.0):
    """Consecutive set positions agree with the set velocities (trapezoid rule, within amax)."""
    p = np.array([r[0] for r in rows])
    v = np.array([r[1] for r in rows])
    dp = np.diff(p)
    err = np.abs(dp - 0.5 * (v[1:] + v[:-1]) * CT)
    assert np.all(err <= amax * CT * CT + 1e-9), (np.argmax(err), np.max(err))
    assert np.all(np.abs(np.diff(v)) <= amax * CT * (1 + 1e-9) + 1e-9)


def accel_then_cruise(x0, acc=2000.0, vel=400.0):
    """Constant acceleration from rest until ``vel`` (0.2 s: a multiple of every PLC cycle here), then
    constant velocity. Returns x(t) -> (p, v, a)."""
    t1 = vel / acc

    def x(t):
        if t < t1:
            return x0 + 0.5 * acc * t * t, acc * t, acc
        return x0 + 0.5 * acc * t1 * t1 + vel * (t - t1), vel, 0.0
    return x


def run_feeds(core, x, ratio, n, x_feed=None):
    """Feed ``x`` every ``ratio`` NC cycles for ``n`` cycles (t = 0 in the first); returns per cycle
    (t, tau since the feed, SetPos, SetVelo, SetAcc)."""
    x_feed = x_feed or x
    out = []
    for k in range(n):
        t = k * CT
        if k % ratio == 0:
            feed(core, *x_feed(t))
        core.step()
        out.append((t, (k % ratio) * CT, *sp(core)))
    return out


# -- enable / disable at standstill -------------------------------------------------------------------
def test_enable_at_standstill_and_disable():
    core = powered(1)
    r = cmd(core, "ExtSetPointGenEnable")
    assert r["error"] == 0 and r["CmdNo"] > 0
    assert (int(core.ncjobs[0]["ActiveCmdNo"]), int(core.ncjobs[0]["ActiveState"])) == (r["CmdNo"], ACTIVE)
    assert sync_flags(core) & SYNC_ENABLED
    core.step()
    assert job(core) == (r["CmdNo"], ACTIVE)
    assert dword(core) & EXT and dword(core) & int(StateDWord.HasJob)
    assert sync_flags(core) == SYNC_ENABLED | SYNC_FOLLOWING  # PLCTONC holds 0 = the SetPos: following
    assert int(core.nctoplc[0]["ErrorCode"]) == 0
    for _ in range(5):
        core.step()
    assert sp(core) == (0.0, 0.0, 0.0)
    snap_pos = sp(core)
    assert cmd(core, "ExtSetPointGenDisable")["error"] == 0
    core.step()
    assert job(core) == (r["CmdNo"], DONE)
    assert not dword(core) & EXT and sync_flags(core) == 0
    assert sp(core) == snap_pos and not core.axes.traj_on[0]
    assert state(core) == MC_AxisStates.MC_AXISSTATE_STANDSTILL
    # not enabled: disabling again changes nothing
    snap = snapshot(core)
    assert cmd(core, "ExtSetPointGenDisable")["error"] == 0
    assert snapshot(core) == snap
    # fed values no longer move the axis
    feed(core, 0.5, 10.0)
    for _ in range(5):
        core.step()
    assert sp(core) == snap_pos


# -- exact application and extrapolation --------------------------------------------------------------
@pytest.mark.parametrize("ratio", [1, 4, 10])
def test_constant_acceleration_feeds_are_applied_exactly_and_extrapolated(ratio):
    """Acceleration 2000 u/s^2 from rest to 400 u/s, then constant: the NC's extrapolation is exact for
    such a generator: every cycle's set-point is the trajectory's; in a feed's cycle it is the fed
    set-point itself."""
    core, _ = enabled_at(25.0)
    x = accel_then_cruise(25.0)
    rows = run_feeds(core, x, ratio, 400)
    for t, tau, p, v, a in rows:
        xp, xv, xa = x(t)
        assert p == pytest.approx(xp, abs=1e-9) and v == pytest.approx(xv, abs=1e-9) and a == xa
        if tau == 0.0:  # the feed's cycle: exactly the fed values
            fp, fv, fa = x(t)
            assert (p, v, a) == (fp, fv, fa)
    assert rows[-1][3] == 400.0
    assert dword(core) & int(StateDWord.PositiveDirection) and not dword(core) & int(StateDWord.NotMoving)
    assert int(core.nctoplc[0]["ErrorCode"]) == 0 and sync_flags(core) == SYNC_ENABLED | SYNC_FOLLOWING
    assert_no_jump([(r[2], r[3]) for r in rows])


@pytest.mark.parametrize("ratio", [1, 4, 10])
def test_jerk_limited_feeds_deviate_at_most_by_the_taylor_bound(ratio):
    """A jerk-limited move (ruckig, 300 u at 400 u/s, 2000 u/s^2, 50000 u/s^3): between feeds the
    constant-acceleration extrapolation deviates by at most jerk tau^3 / 6 in position and
    jerk tau^2 / 2 in velocity (tau: time since the feed); at the feeds it is exact; it ends exactly
    at the target."""
    j = 50000.0
    plan = plan_position(StartState(-40.0), 260.0, Dynamics(400.0, 2000.0, 2000.0, j))
    core, _ = enabled_at(-40.0)
    n = int(plan.duration / CT) + 3 * ratio
    rows = run_feeds(core, lambda t: position_at(plan, t), ratio, n)
    worst = 0.0
    for t, tau, p, v, a in rows:
        xp, xv, xa = position_at(plan, t)
        assert abs(p - xp) <= j * tau ** 3 / 6 * (1 + 1e-6) + 1e-9
        assert abs(v - xv) <= j * tau ** 2 / 2 * (1 + 1e-6) + 1e-9
        if tau == 0.0:
            assert (p, v, a) == (xp, xv, xa)
        worst = max(worst, abs(p - xp))
    if ratio > 1:
        assert worst > 0.0  # (the jerk phases are really extrapolated, not fed)
    assert rows[-1][2] == pytest.approx(260.0, abs=1e-9) and rows[-1][3] == pytest.approx(0.0, abs=1e-9)
    assert int(core.nctoplc[0]["ErrorCode"]) == 0


# -- the no-jump rule -----------------------------------------------------------------------------------
def test_first_feed_far_away_is_not_applied_until_a_matching_one():
    core = powered(1, SimTimeConstant=0.0, **STEPS)
    assert cmd(core, "SetActualPosition", Position=50.0)["error"] == 0
    core.step()
    assert cmd(core, "ExtSetPointGenEnable")["error"] == 0  # PLCTONC still holds ExtSetPos 0: 50 away
    for k in range(20):
        if k == 10:
            feed(core, 0.0, 100.0)  # still far away, and a velocity: not applied either
        core.step()
        assert sp(core) == (50.0, 0.0, 0.0)
        assert sync_flags(core) == SYNC_ENABLED
        assert dword(core) & EXT and int(core.nctoplc[0]["ErrorCode"]) == 0
    feed(core, 50.0, 100.0)  # the current SetPos: taken up without a jump
    core.step()
    assert sp(core) == (50.0, 100.0, 0.0)
    assert sync_flags(core) == SYNC_ENABLED | SYNC_FOLLOWING
    core.step()
    assert sp(core)[0] == pytest.approx(50.1, abs=1e-12)


@pytest.mark.parametrize("bad", ["jump", "too_fast"])
def test_jumping_or_too_fast_feed_is_an_axis_error_and_a_stop(bad):
    """Following at 200 u/s; then a feed 5 u further than the extrapolation (beyond AxisVeloMax x 1.5
    cycles) or one with 1200 u/s (> AxisVeloMax 1000): axis error 0x4359, the generator's job ends
    ERROR, the axis brakes on its ramp to a standstill; later feeds do not move it."""
    core, no = enabled_at()
    x = lambda t: (200.0 * t, 200.0, 0.0)  # noqa: E731
    rows = run_feeds(core, x, 1, 100)
    t = 100 * CT
    if bad == "jump":
        feed(core, 200.0 * t + 5.0, 200.0)
    else:
        feed(core, 200.0 * t, 1200.0)
    core.step()
    rows.append((t, 0.0, *sp(core)))
    assert int(core.nctoplc[0]["ErrorCode"]) == int(E.NC_AXIS_SET_VELOCITY)
    assert ended(core) == (no, ERROR, int(E.NC_AXIS_SET_VELOCITY))
    assert not dword(core) & EXT and sync_flags(core) == 0
    assert state(core) == MC_AxisStates.MC_AXISSTATE_ERRORSTOP
    assert abs(sp(core)[1]) <= 1000.0  # the bad set-point itself is not applied
    while core.axes.traj_on[0] or sp(core)[1] != 0.0:
        feed(core, 0.0, 0.0)  # (ignored now)
        core.step()
        rows.append((0, 0, *sp(core)))
    for _ in range(5):
        core.step()
    assert sp(core)[1] == 0.0 and sp(core)[0] > 20.0
    assert all(r[3] >= -1e-9 for r in rows)  # braked, never reversed
    # the stop distance of 200 u/s (a^2/j = 500 > 200: v sqrt(v/j)) from the last good set-point (19.8)
    # (within a cycle's travel: the stall of test_bad_feed_stop_starts_without_a_stall)
    assert max(r[2] for r in rows) - 19.8 == pytest.approx(200.0 * (200.0 / 50000.0) ** 0.5, abs=0.21)


def test_bad_feed_stop_starts_without_a_stall():
    core, _ = enabled_at()
    rows = run_feeds(core, lambda t: (200.0 * t, 200.0, 0.0), 1, 100)
    feed(core, 200.0 * 100 * CT + 5.0, 200.0)
    for _ in range(20):
        core.step()
        rows.append((0, 0, *sp(core)))
    assert int(core.nctoplc[0]["ErrorCode"]) == int(E.NC_AXIS_SET_VELOCITY)
    assert_no_jump([(r[2], r[3]) for r in rows])


# -- disable while moving, take-overs -------------------------------------------------------------------
def test_disable_while_moving_brakes_from_the_set_point_state():
    core, no = enabled_at()
    x = accel_then_cruise(0.0)
    rows = run_feeds(core, x, 4, 301)  # (cycle 300: a feed)
    feed(core, *x(301 * CT))
    core.step()
    rows.append((0, 0, *sp(core)))
    assert cmd(core, "ExtSetPointGenDisable")["error"] == 0
    assert ended(core) == (no, DONE, 0)  # at once
    k = len(rows)
    while core.axes.traj_on[0]:
        feed(core, 0.0)  # ignored
        core.step()
        rows.append((0, 0, *sp(core)))
    core.step()
    rows.append((0, 0, *sp(core)))
    assert not dword(core) & EXT and sync_flags(core) == 0
    assert int(core.nctoplc[0]["ErrorCode"]) == 0 and sp(core)[1] == 0.0
    v = [r[3] for r in rows[k - 1:]]
    assert np.all(np.diff(v) <= 1e-9) and min(v) >= 0.0
    assert min(r[4] for r in rows[k:]) >= -5000.0 * (1 + 1e-9)  # AxisDec
    assert_no_jump([(r[2], r[3]) for r in rows])
    assert state(core) == MC_AxisStates.MC_AXISSTATE_STANDSTILL


@pytest.mark.parametrize("name,args", [
    ("MoveAbsolute", dict(Position=500.0, Velocity=100.0)),
    ("MoveRelative", dict(Distance=10.0, Velocity=100.0)),
    ("MoveVelocity", dict(Velocity=100.0)),
    ("Halt", {}),
    ("GearIn", dict(Master=2, RatioNumerator=1, RatioDenominator=1)),
])
def test_motion_commands_while_enabled_are_refused_protected(name, args):
    core = powered(2, SimTimeConstant=0.0, **STEPS)
    assert cmd(core, "ExtSetPointGenEnable")["error"] == 0
    run_feeds(core, lambda t: (50.0 * t, 50.0, 0.0), 2, 20)
    snap = snapshot(core)
    r = cmd(core, name, **args)
    assert r["error"] == int(E.MC_AXIS_PROTECTED), r
    assert snapshot(core) == snap
    # and a second enable too
    assert cmd(core, "ExtSetPointGenEnable")["error"] == int(E.MC_AXIS_PROTECTED)
    assert snapshot(core) == snap


def test_allowed_move_absolute_takes_over_seamlessly():
    """AxisAllowMotionCmdToExtSetAxis: a MoveAbsolute disables the generator (its job ABORTED) and
    plans from the set-point state of this cycle; it reaches its target; feeds are ignored."""
    core, no = enabled_at(AxisAllowMotionCmdToExtSetAxis=True)
    x = accel_then_cruise(0.0)
    rows = run_feeds(core, x, 10, 255)  # cruising at 400, 5 cycles after a feed
    assert cmd(core, "MoveAbsolute", Position=200.0, Velocity=300.0, BufferMode=1)["error"] == int(
        E.MC_BUFFERMODE_NOT_SUPPORTED)  # only Aborting
    r = cmd(core, "MoveAbsolute", Position=200.0, Velocity=300.0)
    assert r["error"] == 0, r
    assert ended(core) == (no, ABORTED, 0)
    while int(core.nctoplc[0]["CmdState"]) == ACTIVE:
        feed(core, 0.0)
        core.step()
        rows.append((0, 0, *sp(core)))
    assert job(core) == (r["CmdNo"], DONE)
    assert sp(core) == (200.0, 0.0, 0.0)
    assert not dword(core) & EXT and sync_flags(core) == 0
    assert_no_jump([(t[2], t[3]) for t in rows])


def test_stop_takes_over_from_the_generator():
    core, no = enabled_at()
    rows = run_feeds(core, lambda t: (300.0 * t, 300.0, 0.0), 4, 102)
    s = cmd(core, "Stop")
    assert s["error"] == 0
    assert ended(core) == (no, ABORTED, 0)
    while int(core.nctoplc[0]["CmdState"]) == ACTIVE or core.axes.traj_on[0]:
        feed(core, 0.0)
        core.step()
        rows.append((0, 0, *sp(core)))
    assert job(core) == (s["CmdNo"], DONE) and sp(core)[1] == 0.0
    assert not dword(core) & EXT
    assert_no_jump([(t[2], t[3]) for t in rows])
    assert cmd(core, "StopRelease")["error"] == 0


# -- refusals, target monitoring -----------------------------------------------------------------------
def test_enable_while_a_command_moves_the_axis_is_refused():
    core = powered(1)
    assert cmd(core, "MoveVelocity", Velocity=100.0)["error"] == 0
    for _ in range(10):
        core.step()
    snap = snapshot(core)
    assert cmd(core, "ExtSetPointGenEnable")["error"] == int(E.MC_AXIS_CANNOT_BE_STARTED)
    assert snapshot(core) == snap


@pytest.mark.parametrize("ptype", [0, 3, 4, 6])
def test_bad_position_type_is_refused(ptype):
    core = powered(1)
    snap = snapshot(core)
    assert cmd(core, "ExtSetPointGenEnable", Position=10.0, PositionType=ptype)["error"] == int(E.MC_INVALID_MODE)
    assert snapshot(core) == snap


@pytest.mark.parametrize("ptype,pos,want", [(1, 100.0, 100.0), (2, 10.0, 410.0), (5, 30.0, 390.0)])
def test_target_position_is_shown(ptype, pos, want):
    """Position / PositionType: absolute, relative to the set position (400), modulo (period 360)."""
    core = powered(1, SimTimeConstant=0.0, **STEPS)
    assert cmd(core, "SetActualPosition", Position=400.0)["error"] == 0
    core.step()
    feed(core, 400.0)
    assert cmd(core, "ExtSetPointGenEnable", Position=pos, PositionType=ptype)["error"] == 0
    core.step()
    assert float(core.nctoplc[0]["TargetPos"]) == pytest.approx(want, abs=1e-9)
    # the target does not move with the fed motion
    run_feeds(core, lambda t: (400.0 + 100.0 * t, 100.0, 0.0), 1, 20)
    assert float(core.nctoplc[0]["TargetPos"]) == pytest.approx(want, abs=1e-9)


@pytest.mark.parametrize("x0, want", [(-10.0, -5.0), (-370.0, -365.0), (-360.0, -5.0), (350.0, 355.0)])
def test_modulo_target_in_the_current_turn_also_below_zero(x0, want):
    """PositionType 5 (modulo, period 360): Position 355 in the turn the axis is in. TcMC 4.16: "the flag In target
    position becomes TRUE, as soon as this position is reached" - at -10 (modulo 350) that is -5, not +355."""
    core = powered(1, SimTimeConstant=0.0, **STEPS)
    assert cmd(core, "SetActualPosition", Position=x0)["error"] == 0
    core.step()
    feed(core, x0)
    assert cmd(core, "ExtSetPointGenEnable", Position=355.0, PositionType=5)["error"] == 0
    core.step()
    assert float(core.nctoplc[0]["TargetPos"]) == pytest.approx(want, abs=1e-9)


def test_in_target_position_when_the_fed_motion_reaches_position():
    core = powered(1, SimTimeConstant=0.0, **STEPS)
    feed(core, 0.0)
    assert cmd(core, "ExtSetPointGenEnable", Position=1.0)["error"] == 0
    run_feeds(core, lambda t: (min(100.0 * t, 1.0), 100.0 if t < 0.01 else 0.0, 0.0), 1, 11)
    assert sp(core)[:2] == (1.0, 0.0)
    run_until(core, lambda: bool(dword(core) & IN_TARGET), 200)
    assert dword(core) & EXT  # still enabled


def test_not_in_target_while_away_from_position():
    core = powered(1, SimTimeConstant=0.0, **STEPS)
    feed(core, 0.0)
    assert cmd(core, "ExtSetPointGenEnable", Position=5.0)["error"] == 0
    run_feeds(core, lambda t: (min(100.0 * t, 1.0), 100.0 if t < 0.01 else 0.0, 0.0), 1, 100)
    assert not dword(core) & IN_TARGET


# -- several axes, a superposition on top ----------------------------------------------------------------
def test_a_bad_feed_faults_only_its_axis():
    core = powered(2, SimTimeConstant=0.0, **STEPS)
    for i in (0, 1):
        feed(core, 0.0, i=i)
        assert cmd(core, "ExtSetPointGenEnable", axis=i + 1)["error"] == 0
    for k in range(50):
        for i, v in ((0, 100.0), (1, -50.0)):
            feed(core, v * k * CT, v, i=i)
        core.step()
    feed(core, 100.0, 100.0, i=0)  # axis 1 jumps
    feed(core, -50.0 * 50 * CT, -50.0, i=1)
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == int(E.NC_AXIS_SET_VELOCITY)
    assert int(core.nctoplc[1]["ErrorCode"]) == 0 and dword(core, 1) & EXT
    assert sp(core, 1) == (-2.5, -50.0, 0.0)


def test_superposition_on_top_of_fed_set_points():
    """MoveSuperImposed on an axis the PLC feeds: total = fed trajectory + offset profile; the finished
    offset stays folded into the fed positions (the PLC goes on feeding its own trajectory)."""
    core, _ = enabled_at()
    x = lambda t: (100.0 * t, 100.0, 0.0)  # noqa: E731
    run_feeds(core, x, 4, 100)
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=10.0, VelocityDiff=100.0, Length=1000.0, VelocityProcess=100.0)
    assert r["error"] == 0, r
    rows = []
    for k in range(100, 800):
        if k % 4 == 0:
            feed(core, *x(k * CT))
        core.step()
        rows.append((sp(core)[0], sp(core)[1]))
        assert sp(core)[0] - 100.0 * k * CT >= -1e-9
    assert int(core.ncjobs[0]["SuperState"]) == DONE and int(core.nctoplc[0]["ErrorCode"]) == 0
    assert sp(core)[0] - 100.0 * 799 * CT == pytest.approx(10.0, abs=1e-9)
    assert dword(core) & EXT and sync_flags(core) == SYNC_ENABLED | SYNC_FOLLOWING
    assert_no_jump(rows)


def test_disable_during_a_superposition_brakes_the_total_motion():
    """ExtSetPointGenDisable while a superposition runs on the fed motion: the halt ramp brakes the total
    (the superposition ends ABORTED), no jump."""
    core, _ = enabled_at()
    x = lambda t: (100.0 * t, 100.0, 0.0)  # noqa: E731
    rows = [(r[2], r[3]) for r in run_feeds(core, x, 4, 100)]
    assert cmd(core, "MoveSuperImposed", Mode=3, Distance=50.0, VelocityDiff=100.0, Length=1000.0, VelocityProcess=100.0)["error"] == 0
    for k in range(100, 300):
        if k % 4 == 0:
            feed(core, *x(k * CT))
        core.step()
        rows.append(sp(core)[:2])
    assert sp(core)[1] > 150.0  # fed 100 + the offset's
    assert cmd(core, "ExtSetPointGenDisable")["error"] == 0
    assert int(core.ncjobs[0]["SuperState"]) == ABORTED
    for _ in range(300):
        core.step()
        rows.append(sp(core)[:2])
    assert sp(core)[1] == 0.0 and not core.superposition.on[0]
    assert_no_jump(rows)


def test_enable_refused_on_an_axis_in_error_or_disabled():
    core = powered(2)
    core.fault(0, int(E.NC_POSITION_LAG))
    rec = core.default_plctonc()
    core.set_plctonc(1, rec)  # axis 2: no enable
    core.step()
    snap = snapshot(core)
    assert cmd(core, "ExtSetPointGenEnable", axis=1)["error"] == int(E.MC_AXIS_CANNOT_BE_STARTED)
    assert cmd(core, "ExtSetPointGenEnable", axis=2)["error"] == int(E.NC_NO_ENABLE)
    assert snapshot(core) == snap
