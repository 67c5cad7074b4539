"""Superimposed motion through the NC (MoveSuperImposed / AbortSuperposition, TcMC 3.9-3.12, 6.5).

Cycle-stepped NcCore tests of the superposition stage: the three application examples of TcMC
3.11 run on real axes, the exact additivity of the offset profile (against a twin core running the
same basic motion without it), continuity at every start and end, the NCJOBS slot (SuperCmdNo,
SuperState, SuperErrorId, Super*), StateDWord.Compensating, the incomplete case (0x4243),
MC_AbortSuperposition, a re-trigger, MC_Stop, a standing axis, refusals and the velocity limit.

The process velocities and dynamics are not given by TcMC; they are chosen so that the examples
fit (the same as in test_superposition_plan.py):

* conveyor gap: belt 500 mm/s, AxisVeloMax 2000 mm/s (the 500 mm/s reserve fits), axis defaults
  5000 mm/s^2, 50000 mm/s^3 (at 1000 mm/s the 300 mm would not fit into 1000 mm of belt);
* print roller: 100 deg/s peripheral, AxisAcc/AxisDec 1000 deg/s^2, AxisJerk 10000 deg/s^3,
  AxisVeloMax 200 deg/s (the 30 deg/s reserve fits), a modulo axis of 360 deg;
* drilling unit: a 1:1 geared slave of the workpiece axis; workpiece 200 mm/s (reached with
  2000 mm/s^2, 20000 mm/s^3 so the slave never needs more than its AxisAcc), AxisVeloMax 2000 mm/s
  on both (200 + the 500 mm/s reserve fits), axis defaults 5000 mm/s^2 / 50000 mm/s^3 for the offset.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from nc_schema import CmdState, ErrorCodes as E, MC_AxisStates, StateDWord
from nc_server.core.planning import StartState, position_at
from nc_server.core.superposition import plan_superposition
from znc_testing import step_until
from znc_testing.nc_core import cmd, power, powered, run_until, snapshot, state

CT = 0.001
ACTIVE, DONE, ABORTED, ERROR = (int(CmdState.ACTIVE), int(CmdState.DONE), int(CmdState.ABORTED),
                                int(CmdState.ERROR))
COMP = int(StateDWord.Compensating)
NOT_MOVING = int(StateDWord.NotMoving)


# -- helpers ------------------------------------------------------------------------------------------
def sp_of(core, i=0):
    """SetPos, SetVelo, SetAcc of row ``i``."""
    r = core.nctoplc[i]
    return float(r["SetPos"]), float(r["SetVelo"]), float(r["SetAcc"])


def slot(core, i=0):
    j = core.ncjobs[i]
    return (int(j["SuperCmdNo"]), int(j["SuperState"]), int(j["SuperErrorId"]), float(j["SuperDistance"]),
            float(j["SuperVelocityDiff"]), float(j["SuperLength"]))


def dword(core, i=0):
    return int(core.nctoplc[i]["StateDWord"])


def cruising(v, n=1, axis=1, **params):
    """A core whose axis ``axis`` runs at constant velocity ``v`` (MoveVelocity, acceleration done)."""
    core = powered(n, **params)
    assert cmd(core, "MoveVelocity", axis=axis, Velocity=abs(v), Direction=1 if v > 0 else 3)["error"] == 0
    i = axis - 1
    run_until(core, lambda: abs(sp_of(core, i)[1] - v) < 1e-9 and abs(sp_of(core, i)[2]) < 1e-9)
    for _ in range(3):
        core.step()
    return core


def twins(make):
    """Two identical cores (``make()`` twice): one gets the superposition, the other runs on."""
    a, b = make(), make()
    assert sp_of(a) == sp_of(b)
    return a, b


class Rec:
    """Per cycle (p, v, a) of a core and of its twin, stepped together."""

    def __init__(self, core, twin=None, i=0):
        self.core, self.twin, self.i = core, twin, i
        self.rows = [sp_of(core, i)]
        self.twin_rows = [sp_of(twin, i)] if twin is not None else []

    def step(self, n=1):
        for _ in range(n):
            self.core.step()
            self.rows.append(sp_of(self.core, self.i))
            if self.twin is not None:
                self.twin.step()
                self.twin_rows.append(sp_of(self.twin, self.i))

    def until(self, pred, max_cycles=20000):
        return step_until(self.step, pred, max_cycles)

    @property
    def p(self):
        return np.array([r[0] for r in self.rows])

    @property
    def v(self):
        return np.array([r[1] for r in self.rows])

    @property
    def a(self):
        return np.array([r[2] for r in self.rows])

    @property
    def diff(self):
        """Total minus basic motion (the applied offset) per cycle."""
        return self.p - np.array([r[0] for r in self.twin_rows])


def assert_continuous(rec, vmax, amax):
    """No jump: consecutive set positions agree with the set velocities (trapezoid rule within the
    acceleration bound), and the velocity changes by at most amax per second."""
    p, v = rec.p, rec.v
    dp = np.diff(p)
    assert np.all(np.abs(dp) <= vmax * CT * (1 + 1e-9) + 1e-9)
    assert np.all(np.abs(dp - 0.5 * (v[1:] + v[:-1]) * CT) <= amax * CT * CT + 1e-9), np.max(
        np.abs(dp - 0.5 * (v[1:] + v[:-1]) * CT))
    assert np.all(np.abs(np.diff(v)) <= amax * CT * (1 + 1e-9) + 1e-9)


# -- TcMC 3.11: distance correction of products on a conveyor belt -------------------------------------
@pytest.mark.parametrize("distance", [300.0, -300.0])
def test_conveyor_gap_limited_motion_travels_length_and_gains_distance(distance):
    """Mode 2 (VELOREDUCTION_LIMITEDMOTION), Distance +-300, Length 1000, VelocityDiff 500 on a belt at
    500 mm/s: over the correction the belt travels exactly Length while it gains (belt 1 faster) or
    loses (belt 2 slower, VelocityDiff = its set velocity) 300 against the uncorrected motion."""
    core, twin = twins(lambda: cruising(500.0, AxisVeloMax=2000.0))
    r = cmd(core, "MoveSuperImposed", Mode=2, Distance=distance, VelocityDiff=500.0, Length=1000.0, VelocityProcess=500.0)
    assert r["error"] == 0, r
    val = r["Value"]
    assert val["ActualDistance"] == distance and val["Incomplete"] is False
    assert val["ActualLength"] == pytest.approx(1000.0, rel=1e-9)
    assert 0.0 < val["ActualVelocityDiff"] <= 500.0
    T = (1000.0 - distance) / 500.0  # the window: the belt's own travel is Length
    n = round(T / CT)
    rec = Rec(core, twin)
    p0 = rec.p[0]
    rec.step(n)
    assert rec.p[-1] - p0 == pytest.approx(1000.0, abs=1e-6)  # travel over the correction = Length
    assert rec.diff[-1] == pytest.approx(distance, abs=1e-6)  # gained/lost against the uncorrected motion
    assert np.all(np.abs(rec.diff[1:-1]) < abs(distance))
    # the velocity changes only in the direction of the correction, by at most ActualVelocityDiff
    dv = (rec.v - 500.0) * math.copysign(1.0, distance)
    assert np.all(dv >= -1e-9) and np.max(dv) == pytest.approx(val["ActualVelocityDiff"], rel=1e-3)
    assert np.all(rec.v > 0)  # belt 2 is slowed, never reversed
    rec.step(2)  # DONE in the cycle the profile ends (or the next: plan ends are noticed at or after)
    assert slot(core)[1] == DONE and slot(core)[2] == 0
    rec.step(20)
    assert np.allclose(rec.diff[n:], distance, atol=1e-9) and np.all(rec.v[n:] == 500.0)
    assert_continuous(rec, 2000.0, 10000.0)


@pytest.mark.parametrize("jerk", [0.0, 500.0, 1e6, -5.0])
def test_the_jerk_input_is_not_used(jerk):
    """TcMC 3.9/3.10 "Jerk: the jerk value is not used" (issue 17's case): a belt at 300 u/s, Mode 2,
    Distance 300, VelocityDiff 500, Length 1000: whatever Jerk (even a negative one: not checked), the
    correction is limited by AxisJerk and ends DONE with the full 300 (before: Jerk 500 ended at 247 with
    0x4243, a negative Jerk was refused)."""
    core, twin = twins(lambda: cruising(300.0))
    r = cmd(core, "MoveSuperImposed", Mode=2, Distance=300.0, VelocityDiff=500.0, Length=1000.0,
            VelocityProcess=300.0, Jerk=jerk)
    assert r["error"] == 0, r
    assert r["Value"]["ActualDistance"] == 300.0 and r["Value"]["Incomplete"] is False
    rec = Rec(core, twin)
    rec.until(lambda: slot(core)[1] != ACTIVE)
    assert slot(core)[1:3] == (DONE, 0)
    rec.step(2)
    assert rec.diff[-1] == pytest.approx(300.0, abs=1e-9)
    jerks = np.abs(np.diff([row[2] for row in rec.rows])) / CT
    assert np.max(jerks) <= 50000.0 * (1 + 1e-6) and np.max(jerks) > 1000.0  # AxisJerk, not the input


# -- TcMC 3.11: phase shift of a print roller ---------------------------------------------------------
ROLLER = dict(AxisVeloMax=200.0, AxisAcc=1000.0, AxisDec=1000.0, AxisJerk=10000.0, Modulo=True,
              AxisEncoderModuloValue=360.0)


def test_print_roller_fast_correction():
    """Mode 4 (LENGTHREDUCTION_LIMITEDMOTION), 7.1 deg within 360 deg at 30 deg/s: the time-optimal
    profile (30 deg/s reached, jerk-limited ramps), done long before a revolution."""
    core, twin = twins(lambda: cruising(100.0, **ROLLER))
    r = cmd(core, "MoveSuperImposed", Mode=4, Distance=7.1, VelocityDiff=30.0, Length=360.0, VelocityProcess=100.0)
    assert r["error"] == 0, r
    t_opt = 7.1 / 30.0 + 2.0 * math.sqrt(30.0 / 10000.0)
    val = r["Value"]
    assert val["ActualDistance"] == 7.1 and val["ActualVelocityDiff"] == pytest.approx(30.0, rel=1e-9)
    assert val["ActualLength"] == pytest.approx(100.0 * t_opt + 7.1, rel=1e-9)  # the roller's own travel
    rec = Rec(core, twin)
    k = rec.until(lambda: slot(core)[1] != ACTIVE)
    assert slot(core)[1] == DONE
    assert math.ceil(t_opt / CT - 1e-9) <= k <= math.ceil(t_opt / CT) + 1
    assert rec.diff[-1] == pytest.approx(7.1, abs=1e-9)
    assert np.max(rec.v) == pytest.approx(130.0, abs=1e-6)  # 30 deg/s on top of 100
    rec.step(10)
    assert np.allclose(rec.diff[k:], 7.1, atol=1e-9)
    # the modulo display follows the corrected position
    p = sp_of(core)[0]
    assert float(core.nctoplc[0]["ModuloSetPos"]) == pytest.approx(p % 360.0, abs=1e-9)
    assert_continuous(rec, 200.0, 2000.0)


def test_print_roller_slow_correction_uses_the_whole_revolution():
    """Mode 2 (VELOREDUCTION_LIMITEDMOTION): the roller travels exactly one revolution (360 deg) during
    the correction and its velocity rises as little as that allows."""
    core, twin = twins(lambda: cruising(100.0, **ROLLER))
    r = cmd(core, "MoveSuperImposed", Mode=2, Distance=7.1, VelocityDiff=30.0, Length=360.0, VelocityProcess=100.0)
    assert r["error"] == 0, r
    assert r["Value"]["ActualLength"] == pytest.approx(360.0, rel=1e-9)
    T = (360.0 - 7.1) / 100.0
    rec = Rec(core, twin)
    p0 = rec.p[0]
    n = round(T / CT)
    rec.step(n)
    assert rec.p[-1] - p0 == pytest.approx(360.0, abs=1e-6)
    assert rec.diff[-1] == pytest.approx(7.1, abs=1e-6)
    assert np.max(rec.v) - 100.0 == pytest.approx(r["Value"]["ActualVelocityDiff"], rel=1e-3)
    assert r["Value"]["ActualVelocityDiff"] < 3.0
    rec.step(2)
    assert slot(core)[1] == DONE


# -- TcMC 3.11: drilling unit, a geared slave of the workpiece ---------------------------------------
def drilling_pair():
    core = powered(2, AxisVeloMax=2000.0)
    assert cmd(core, "GearIn", axis=2, Master=1, RatioNumerator=1, RatioDenominator=1)["error"] == 0
    core.step()
    assert cmd(core, "MoveVelocity", axis=1, Velocity=200.0, Acceleration=2000.0, Jerk=20000.0)["error"] == 0
    run_until(core, lambda: sp_of(core, 0)[1] == 200.0 and sp_of(core, 0)[2] == 0.0)
    for _ in range(3):
        core.step()
    assert sp_of(core, 1)[1] == 200.0
    return core


@pytest.mark.parametrize("mode,T", [(3, 0.7), (1, 2.0)])
def test_drilling_unit_on_a_geared_slave(mode, T):
    """Distance 250 relative to the workpiece, Length 400 of workpiece travel, VelocityDiff 500.
    Mode 3 (fast, LENGTHREDUCTION_ADDITIVE): time-optimal, 0.7 s; mode 1 (slow, VELOREDUCTION_ADDITIVE):
    the whole 2 s, while the workpiece travels 400 the drilling unit travels 650. Afterwards the unit
    runs synchronous with the workpiece again, 250 further on."""
    core = drilling_pair()
    r = cmd(core, "MoveSuperImposed", axis=2, Mode=mode, Distance=250.0, VelocityDiff=500.0, Length=400.0, VelocityProcess=200.0)
    assert r["error"] == 0, r
    val = r["Value"]
    assert val["ActualDistance"] == 250.0
    assert val["ActualLength"] == pytest.approx(200.0 * T, rel=1e-9)  # the workpiece's travel meanwhile
    m0, s0 = sp_of(core, 0)[0], sp_of(core, 1)[0]
    n = round(T / CT)
    for _ in range(n):
        core.step()
    workpiece, unit = sp_of(core, 0)[0] - m0, sp_of(core, 1)[0] - s0
    assert workpiece == pytest.approx(200.0 * T, abs=1e-6)
    assert unit == pytest.approx(200.0 * T + 250.0, abs=1e-6)  # mode 1: 650 = Length + Distance
    for _ in range(3):
        core.step()
    assert slot(core, 1)[1] == DONE
    # synchronous again: same velocity, the gap grew by exactly the distance and stays
    gap = sp_of(core, 1)[0] - sp_of(core, 0)[0]
    for _ in range(20):
        core.step()
        assert sp_of(core, 1)[1] == sp_of(core, 0)[1] == 200.0
        assert sp_of(core, 1)[0] - sp_of(core, 0)[0] == pytest.approx(gap, abs=1e-9)
    assert gap == pytest.approx((s0 - m0) + 250.0, abs=1e-9)
    assert state(core, 1) == MC_AxisStates.MC_AXISSTATE_SYNCHRONIZEDMOTION


@pytest.mark.parametrize("mode,vp,D,T", [(1, 200.0, 250.0, 2.0), (1, 400.0, 250.0, 1.0),
                                         (2, 400.0, 50.0, (400.0 - 50.0) / 400.0)])
def test_velocity_process_of_a_geared_slave(mode, vp, D, T):
    """Ratio 2:1, workpiece at 200, the slave at 400, Distance D, Length 400. VelocityProcess is the
    reference's velocity: for ADDITIVE (mode 1) the workpiece's 200 (TcMC 6.5: Length is the travel of
    the reference without superimposed motion), a 2 s window in which the workpiece travels 400; the
    slave's 400: a 1 s window. LIMITED (mode 2) with the slave's own 400: the slave travels Length."""
    core = powered(2, AxisVeloMax=3000.0)
    assert cmd(core, "GearIn", axis=2, Master=1, RatioNumerator=2, RatioDenominator=1)["error"] == 0
    core.step()
    assert cmd(core, "MoveVelocity", axis=1, Velocity=200.0, Acceleration=2000.0, Jerk=20000.0)["error"] == 0
    run_until(core, lambda: sp_of(core, 0)[1] == 200.0 and sp_of(core, 0)[2] == 0.0)
    m0, s0 = sp_of(core, 0)[0], sp_of(core, 1)[0]
    r = cmd(core, "MoveSuperImposed", axis=2, Mode=mode, Distance=D, VelocityDiff=500.0, Length=400.0,
            VelocityProcess=vp)
    assert r["error"] == 0 and r["Value"]["Incomplete"] is False, r
    n = round(T / CT)
    for _ in range(n):
        core.step()
    master, slave = sp_of(core, 0)[0] - m0, sp_of(core, 1)[0] - s0
    assert master == pytest.approx(200.0 * T, abs=1e-6)
    assert slave == pytest.approx(2.0 * master + D, abs=1e-6)
    if mode == 1 and vp == 200.0:
        assert master == pytest.approx(400.0, abs=1e-6)
    if mode == 2:
        assert slave == pytest.approx(400.0, abs=1e-6)
    run_until(core, lambda: slot(core, 1)[1] != ACTIVE, 2)
    assert slot(core, 1)[1] == DONE
    assert sp_of(core, 1)[1] == 400.0 and sp_of(core, 1)[0] - s0 == pytest.approx(2.0 * (sp_of(core, 0)[0] - m0) + D)


# -- exact additivity and continuity ------------------------------------------------------------------
def offset_profile(mode, distance, vdiff, v_ref, length, n, acc=5000.0, dec=5000.0, jerk=50000.0):
    """The offset the NC must add in the n cycles after the command (plan_superposition, axis defaults)."""
    sp = plan_superposition(mode, distance, vdiff, acc, dec, jerk, v_ref, length, StartState(0.0))
    return sp, np.array([position_at(sp.plan, k * CT)[0] for k in range(n + 1)])


@pytest.mark.parametrize("mode", [1, 2, 3, 4])
def test_total_set_position_is_basic_motion_plus_offset_profile(mode):
    """A superposition started while the axis accelerates towards a MoveAbsolute target (VelocityProcess
    given): in every cycle total SetPos - twin SetPos == the planned offset profile; the finished offset
    is folded into the basic motion, so the move ends at its target + Distance (TargetPos shows it)."""
    def make():
        core = powered(1)
        assert cmd(core, "MoveAbsolute", Position=2000.0, Velocity=800.0)["error"] == 0
        for _ in range(60):
            core.step()
        return core

    core, twin = twins(make)
    assert 0 < sp_of(core)[1] < 800.0 and sp_of(core)[2] > 0  # mid-acceleration
    r = cmd(core, "MoveSuperImposed", Mode=mode, Distance=-150.0, VelocityDiff=300.0, Length=500.0,
            VelocityProcess=600.0)
    assert r["error"] == 0, r
    sp, want = offset_profile(mode, -150.0, 300.0, 600.0, 500.0, 2500)
    assert r["Value"]["ActualDistance"] == sp.distance == -150.0
    assert r["Value"]["ActualVelocityDiff"] == pytest.approx(sp.velocity_diff, rel=1e-12)
    assert r["Value"]["ActualLength"] == pytest.approx(sp.length, rel=1e-12)
    rec = Rec(core, twin)
    rec.step(round(sp.plan.duration / CT) + 2)
    m = len(rec.rows)
    assert np.allclose(rec.diff, want[:m], rtol=0, atol=1e-9)
    assert slot(core)[1] == DONE
    job_no = int(core.nctoplc[0]["CmdNo"])
    rec.until(lambda: int(core.nctoplc[0]["CmdState"]) == DONE and int(twin.nctoplc[0]["CmdState"]) == DONE)
    assert int(core.nctoplc[0]["CmdNo"]) == job_no  # the MoveAbsolute ran on, undisturbed
    assert rec.p[-1] == pytest.approx(1850.0, abs=1e-9) and rec.twin_rows[-1][0] == pytest.approx(2000.0, abs=1e-9)
    assert float(core.nctoplc[0]["TargetPos"]) == pytest.approx(1850.0, abs=1e-9)
    assert_continuous(rec, 1000.0, 10000.0)


def test_basic_motion_ending_first_superposition_goes_on():
    """The basic MoveRelative ends DONE at its target while the superposition still runs on the then
    standing axis; the axis ends at target + Distance without a jump; TargetPos follows."""
    def make():
        core = powered(1)
        assert cmd(core, "MoveRelative", Distance=20.0, Velocity=200.0)["error"] == 0
        core.step()
        return core

    core, twin = twins(make)
    r = cmd(core, "MoveSuperImposed", Mode=1, Distance=50.0, VelocityDiff=100.0, Length=100.0, VelocityProcess=50.0)
    assert r["error"] == 0, r
    sp, want = offset_profile(1, 50.0, 100.0, 50.0, 100.0, 2100)
    assert sp.plan.duration == pytest.approx(2.0)
    rec = Rec(core, twin)
    rec.until(lambda: int(core.nctoplc[0]["CmdState"]) == DONE)
    assert slot(core)[1] == ACTIVE
    rec.until(lambda: slot(core)[1] != ACTIVE)
    rec.step(5)
    assert slot(core)[1] == DONE
    assert np.allclose(rec.diff, want[:len(rec.rows)], atol=1e-9)
    assert rec.p[-1] == pytest.approx(sp_of(twin)[0] + 50.0, abs=1e-9)
    assert float(core.nctoplc[0]["TargetPos"]) == pytest.approx(rec.p[-1], abs=1e-9)
    assert dword(core) & NOT_MOVING
    assert_continuous(rec, 1000.0, 10000.0)


def test_slot_reply_and_compensating_bit():
    """SuperCmdNo/SuperState ACTIVE -> DONE; the Value of the reply is in the slot too;
    StateDWord.Compensating exactly while it runs; the MoveVelocity job is not touched."""
    core = cruising(500.0, AxisVeloMax=2000.0)
    job = (int(core.nctoplc[0]["CmdNo"]), int(core.nctoplc[0]["CmdState"]))
    assert not dword(core) & COMP and slot(core)[:2] == (0, 0)
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=100.0, VelocityDiff=200.0, Length=1000.0, VelocityProcess=500.0)
    assert r["error"] == 0 and r["CmdNo"] > job[0]
    no, st, err, d, vd, ln = slot(core)  # at once, with the reply
    assert (no, st, err) == (r["CmdNo"], ACTIVE, 0)
    v = r["Value"]
    assert (d, vd, ln) == (v["ActualDistance"], v["ActualVelocityDiff"], v["ActualLength"])
    core.step()
    assert dword(core) & COMP
    k = run_until(core, lambda: slot(core)[1] != ACTIVE)
    dur = 100.0 / 200.0 + 2.0 * math.sqrt(200.0 / 50000.0)  # (a^2/j = 500 > 200: triangular ramps)
    assert math.ceil(dur / CT) <= k + 1 <= math.ceil(dur / CT) + 1  # (one step before run_until)
    assert slot(core)[:3] == (r["CmdNo"], DONE, 0)
    assert not dword(core) & COMP
    assert (int(core.nctoplc[0]["CmdNo"]), int(core.nctoplc[0]["CmdState"])) == job
    assert state(core) == MC_AxisStates.MC_AXISSTATE_CONTINOUSMOTION


def test_newest_cmd_no_shows_the_superposition_number():
    core = cruising(200.0)
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=10.0, VelocityDiff=100.0, Length=1000.0, VelocityProcess=200.0)
    assert r["error"] == 0
    core.step()
    assert int(core.ncjobs[0]["NewestCmdNo"]) == r["CmdNo"] == int(core.ncjobs[0]["SuperCmdNo"])


def test_incomplete_compensation_applies_what_fits_and_ends_0x4243():
    """Mode 1 at 100 u/s, Length 100 (a 1 s window), VelocityDiff 10, Distance 100: only ~9.7 fit.
    The reply says so (ActualDistance < Distance), the slot ends ERROR 0x4243, and exactly
    ActualDistance was applied."""
    core, twin = twins(lambda: cruising(100.0))
    r = cmd(core, "MoveSuperImposed", Mode=1, Distance=100.0, VelocityDiff=10.0, Length=100.0, VelocityProcess=100.0)
    assert r["error"] == 0, r
    ad = r["Value"]["ActualDistance"]
    assert r["Value"]["Incomplete"] is True and 0.0 < ad < 100.0
    assert ad == pytest.approx(10.0 * (1.0 - 2.0 * math.sqrt(10.0 / 50000.0)), rel=1e-9)
    assert slot(core)[1:3] == (ACTIVE, 0) and slot(core)[3] == ad
    rec = Rec(core, twin)
    rec.until(lambda: slot(core)[1] != ACTIVE)
    assert slot(core)[1:3] == (ERROR, int(E.NC_COMPENSATION_INCOMPLETE))
    rec.step(5)
    assert rec.diff[-1] == pytest.approx(ad, abs=1e-9)
    assert int(core.nctoplc[0]["ErrorCode"]) == 0  # no axis error: the basic motion goes on
    assert sp_of(core)[1] == 100.0
    assert_continuous(rec, 1000.0, 10000.0)


# -- MC_AbortSuperposition ----------------------------------------------------------------------------
def test_abort_superposition_brakes_the_offset_and_the_basic_motion_goes_on():
    core, twin = twins(lambda: cruising(500.0, AxisVeloMax=2000.0))
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=1000.0, VelocityDiff=400.0, Length=5000.0, VelocityProcess=500.0)
    assert r["error"] == 0
    rec = Rec(core, twin)
    rec.until(lambda: sp_of(core)[1] == pytest.approx(900.0))
    rec.step(50)
    before = rec.diff[-1]
    assert cmd(core, "AbortSuperposition")["error"] == 0
    assert slot(core)[:2] == (r["CmdNo"], ABORTED)  # at once
    rec.until(lambda: not core.superposition.on[0])
    rec.step(10)
    d = rec.diff
    assert d[-1] > before and d[-1] < 1000.0  # braked on, not back, not to the full distance
    # stop distance of 400 u/s with 50000 u/s^3 (a^2/j = 500 > 400: triangular, a peaks below 5000):
    # v * sqrt(v/j)
    assert d[-1] - before == pytest.approx(400.0 * math.sqrt(400.0 / 50000.0), rel=1e-6)
    assert np.all(np.diff(d) >= -1e-12)
    assert np.allclose(d[-10:], d[-1], atol=1e-12)
    assert sp_of(core)[1] == 500.0 and int(core.nctoplc[0]["CmdState"]) == ACTIVE  # MoveVelocity goes on
    assert slot(core)[1] == ABORTED and not dword(core) & COMP
    assert_continuous(rec, 2000.0, 10000.0)
    # nothing running: AbortSuperposition changes nothing
    snap = snapshot(core)
    assert cmd(core, "AbortSuperposition")["error"] == 0
    assert snapshot(core) == snap


def test_abort_superposition_brakes_with_its_deceleration():
    core = cruising(500.0, AxisVeloMax=2000.0)
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=1000.0, VelocityDiff=400.0, Length=5000.0, VelocityProcess=500.0,
            Acceleration=1000.0, Deceleration=1000.0)
    assert r["error"] == 0
    run_until(core, lambda: sp_of(core)[1] == pytest.approx(900.0))
    cmd(core, "AbortSuperposition")
    acc = []
    while core.superposition.on[0]:
        core.step()
        acc.append(sp_of(core)[2])
    assert min(acc) >= -1000.0 * (1 + 1e-9)


# -- a second superposition, MC_Stop -------------------------------------------------------------------
def test_second_superposition_takes_over_from_the_running_one():
    core, twin = twins(lambda: cruising(500.0, AxisVeloMax=2000.0))
    first = cmd(core, "MoveSuperImposed", Mode=3, Distance=300.0, VelocityDiff=300.0, Length=5000.0, VelocityProcess=500.0)
    rec = Rec(core, twin)
    rec.step(400)  # mid-cruise of the first (1.2 s long)
    applied = rec.diff[-1]
    assert 50.0 < applied < 250.0 and slot(core)[1] == ACTIVE
    second = cmd(core, "MoveSuperImposed", Mode=3, Distance=100.0, VelocityDiff=300.0, Length=5000.0, VelocityProcess=500.0)
    assert second["error"] == 0 and second["CmdNo"] != first["CmdNo"]
    assert slot(core)[:2] == (second["CmdNo"], ACTIVE)  # the slot shows the new one (the first: ABORTED)
    assert second["Value"]["ActualDistance"] == 100.0
    rec.until(lambda: slot(core)[1] != ACTIVE)
    rec.step(5)
    assert slot(core)[1] == DONE
    assert rec.diff[-1] == pytest.approx(applied + 100.0, abs=1e-9)
    assert_continuous(rec, 2000.0, 10000.0)


def test_stop_during_a_superposition_brakes_the_total_motion():
    core = cruising(500.0, AxisVeloMax=2000.0)
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=500.0, VelocityDiff=300.0, Length=5000.0, VelocityProcess=500.0)
    rec = Rec(core)
    rec.step(300)
    v_total = sp_of(core)[1]
    assert v_total == pytest.approx(800.0)
    stop = cmd(core, "Stop")
    assert stop["error"] == 0
    assert slot(core)[:2] == (r["CmdNo"], ABORTED)
    rec.until(lambda: int(core.nctoplc[0]["CmdState"]) == DONE)
    rec.step(5)
    assert rec.v[-1] == 0.0 and not dword(core) & COMP
    assert not core.superposition.on[0] and np.all(np.diff(rec.v[300:]) <= 1e-9)  # braking from 800
    assert_continuous(rec, 2000.0, 10000.0)
    # the stop braked from the total state: its distance is that of 800 u/s
    v, a, j = 800.0, 5000.0, 50000.0
    assert rec.p[-1] - rec.p[300] == pytest.approx(v * v / (2 * a) + v * a / (2 * j), rel=2e-3)


# -- a standing axis ------------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", [3, 4])
def test_superposition_on_a_standing_axis_is_a_relative_move(mode):
    """The axis stands (no basic motion), LENGTHREDUCTION with a window that fits (|Length| /
    VelocityProcess = 50 s): the fastest move of Distance at VelocityDiff, cycle by cycle the same
    set-points as MoveRelative(Distance, Velocity=VelocityDiff)."""
    core, twin = twins(lambda: powered(1))
    assert cmd(core, "MoveSuperImposed", Mode=mode, Distance=-120.0, VelocityDiff=300.0, Length=50.0,
               VelocityProcess=1.0)["error"] == 0
    assert cmd(twin, "MoveRelative", Distance=-120.0, Velocity=300.0)["error"] == 0
    rec = Rec(core, twin)
    rec.step(3)
    assert not dword(core) & NOT_MOVING and dword(core) & int(StateDWord.NegativeDirection)
    assert dword(core) & COMP
    rec.until(lambda: slot(core)[1] != ACTIVE)
    rec.step(3)
    assert slot(core)[1] == DONE
    assert np.allclose(rec.p, [r[0] for r in rec.twin_rows], atol=1e-9)
    assert np.allclose(rec.v, [r[1] for r in rec.twin_rows], atol=1e-9)
    assert rec.p[-1] == pytest.approx(-120.0, abs=1e-9)
    assert float(core.nctoplc[0]["TargetPos"]) == pytest.approx(-120.0, abs=1e-9)
    assert dword(core) & NOT_MOVING


@pytest.mark.parametrize("mode", [1, 2])
def test_velo_reduction_on_a_standing_axis_uses_the_window_of_velocity_process(mode):
    """Decision (issue 17): VelocityProcess is never 0, so a standing axis gets the finite window
    |Length| / |VelocityProcess| in every Mode (LIMITEDMOTION too: the axis has no process travel of its
    own): Distance 120, Length 600, VelocityProcess 100 -> the correction takes exactly 6 s (before: the
    fastest move, ~0.5 s). ActualLength of LIMITEDMOTION is the axis's own travel, |Distance|."""
    core = powered(1)
    r = cmd(core, "MoveSuperImposed", Mode=mode, Distance=120.0, VelocityDiff=300.0, Length=600.0,
            VelocityProcess=100.0)
    assert r["error"] == 0 and r["Value"]["Incomplete"] is False, r
    assert r["Value"]["ActualLength"] == pytest.approx(120.0 if mode == 2 else 600.0, rel=1e-9)
    k = run_until(core, lambda: slot(core)[1] != ACTIVE, 10_000)
    assert slot(core)[1] == DONE
    assert k * CT == pytest.approx(6.0, abs=2 * CT)
    assert sp_of(core)[0] == pytest.approx(120.0, abs=1e-9)


def test_velocity_process_0_is_refused_with_0x4b06_and_changes_nothing():
    """TcMC 3.9/3.10: "VelocityProcess: ... (absolute value > 0)" (before: 0 = the reference's set velocity)."""
    for core in (powered(1), cruising(200.0)):
        snap = snapshot(core)
        r = cmd(core, "MoveSuperImposed", Mode=3, Distance=10.0, VelocityDiff=100.0, Length=100.0, VelocityProcess=0.0)
        assert r["error"] == int(E.MC_PARAMETER_NOT_CORRECT), r
        assert snapshot(core) == snap


def test_superposition_on_a_standing_axis_is_not_standstill():
    core = powered(1)
    assert cmd(core, "MoveSuperImposed", Mode=3, Distance=100.0, VelocityDiff=300.0, Length=50.0, VelocityProcess=1.0)["error"] == 0
    for _ in range(50):
        core.step()
    assert sp_of(core)[1] > 0
    assert state(core) != MC_AxisStates.MC_AXISSTATE_STANDSTILL
    assert cmd(core, "SetActualPosition", Position=0.0)["error"] == int(E.MC_AXIS_CANNOT_BE_STARTED)


# -- refusals -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("args,code", [
    (dict(Distance=0.0, VelocityDiff=100.0, Length=100.0, VelocityProcess=100.0), E.MC_PARAMETER_NOT_CORRECT),
    (dict(Distance=10.0, VelocityDiff=0.0, Length=100.0, VelocityProcess=100.0), E.MC_PARAMETER_NOT_CORRECT),
    (dict(Distance=10.0, VelocityDiff=100.0, Length=0.0, VelocityProcess=100.0), E.MC_PARAMETER_NOT_CORRECT),
    (dict(Distance=10.0, VelocityDiff=100.0, Length=100.0, VelocityProcess=0.0), E.MC_PARAMETER_NOT_CORRECT),
    (dict(Distance=10.0, VelocityDiff=100.0, Length=100.0, VelocityProcess=100.0, Mode=9), E.MC_INVALID_MODE),
    (dict(Distance=10.0, VelocityDiff=100.0, Length=100.0, VelocityProcess=100.0, Mode=0), E.MC_INVALID_MODE),
])
@pytest.mark.parametrize("moving", [False, True])
def test_refused_superposition_changes_nothing(args, code, moving):
    core = cruising(200.0) if moving else powered(1)
    if moving:  # also with one running
        assert cmd(core, "MoveSuperImposed", Mode=3, Distance=10.0, VelocityDiff=100.0, Length=1000.0, VelocityProcess=200.0)["error"] == 0
        core.step()
    snap = snapshot(core)
    r = cmd(core, "MoveSuperImposed", **args)
    assert r["error"] == int(code), r
    assert snapshot(core) == snap


def test_refused_on_an_axis_in_error_or_disabled():
    core = powered(2)
    core.fault(0, int(E.NC_POSITION_LAG))
    power(core, 1, ctrl=0)
    core.step()
    snap = snapshot(core)
    r = cmd(core, "MoveSuperImposed", axis=1, Mode=3, Distance=10.0, VelocityDiff=100.0, Length=100.0, VelocityProcess=100.0)
    assert r["error"] == int(E.MC_AXIS_CANNOT_BE_STARTED)
    r = cmd(core, "MoveSuperImposed", axis=2, Mode=3, Distance=10.0, VelocityDiff=100.0, Length=100.0,
            VelocityProcess=100.0)
    assert r["error"] == int(E.NC_NO_ENABLE)
    assert snapshot(core) == snap


def test_total_velocity_above_axis_velo_max_is_an_axis_error_and_a_stop():
    """AxisVeloMax 600, basic 400 with a superposition of up to +150 u/s (fits: 550), then the basic
    motion is raised to 550: the total passes 600 -> axis error 0x4359 (set velocity not allowed),
    the superposition ends ABORTED, the axis brakes from the total state to a standstill, no jump."""
    core = cruising(400.0, AxisVeloMax=600.0)
    assert cmd(core, "MoveSuperImposed", Mode=3, Distance=300.0, VelocityDiff=150.0, Length=5000.0, VelocityProcess=400.0)["error"] == 0
    rec = Rec(core)
    rec.step(20)
    assert cmd(core, "MoveVelocity", Velocity=550.0, Direction=1)["error"] == 0
    rec.until(lambda: int(core.nctoplc[0]["ErrorCode"]) != 0)
    assert int(core.nctoplc[0]["ErrorCode"]) == int(E.NC_AXIS_SET_VELOCITY)
    assert slot(core)[1] == ABORTED
    rec.until(lambda: sp_of(core)[1] == 0.0 and not core.axes.traj_on[0])
    rec.step(3)
    assert state(core) == MC_AxisStates.MC_AXISSTATE_ERRORSTOP
    assert not dword(core) & COMP
    assert_continuous(rec, 800.0, 10000.0)


def test_a_superposition_that_would_exceed_axis_velo_max_is_refused():
    """The peak of the total velocity is known when the command is planned: basic 500 + up to 500 on a
    600 u/s axis is refused with 0x4221 (velocity not allowed) and nothing changes."""
    core = cruising(500.0, AxisVeloMax=600.0)
    snap = snapshot(core)
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=300.0, VelocityDiff=500.0, Length=5000.0, VelocityProcess=500.0)
    assert r["error"] == int(E.NC_VELOCITY_NOT_ALLOWED)
    assert snapshot(core) == snap


# -- the basic motion replanned, Enable FALSE -------------------------------------------------------------
def test_move_absolute_during_a_superposition_leaves_it_running():
    """A MoveAbsolute replaces the basic motion (planned from the basic state): the superposition runs on
    and ends DONE; the move ends at its target + the superimposed distance, without a jump."""
    core = cruising(300.0)
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=100.0, VelocityDiff=200.0, Length=5000.0, VelocityProcess=300.0)
    rec = Rec(core)
    rec.step(200)
    m = cmd(core, "MoveAbsolute", Position=400.0, Velocity=300.0)
    assert m["error"] == 0
    assert slot(core)[:2] == (r["CmdNo"], ACTIVE)
    rec.until(lambda: int(core.nctoplc[0]["CmdState"]) != ACTIVE)
    rec.step(5)
    assert (int(core.nctoplc[0]["CmdNo"]), int(core.nctoplc[0]["CmdState"])) == (m["CmdNo"], DONE)
    assert slot(core)[:3] == (r["CmdNo"], DONE, 0)
    assert sp_of(core) == (pytest.approx(500.0, abs=1e-9), 0.0, 0.0)
    assert float(core.nctoplc[0]["TargetPos"]) == pytest.approx(500.0, abs=1e-9)
    assert_continuous(rec, 1000.0, 10000.0)


def test_enable_false_aborts_the_superposition():
    core = cruising(300.0)
    r = cmd(core, "MoveSuperImposed", Mode=3, Distance=100.0, VelocityDiff=200.0, Length=5000.0, VelocityProcess=300.0)
    for _ in range(100):
        core.step()
    power(core, ctrl=0)
    core.step()
    assert slot(core)[:2] == (r["CmdNo"], ABORTED)
    assert not dword(core) & COMP and not core.superposition.on[0]
    assert state(core) == MC_AxisStates.MC_AXISSTATE_DISABLED
    power(core)
    core.step()
    core.step()
    assert sp_of(core) == (float(core.nctoplc[0]["ActPos"]), 0.0, 0.0)  # set position := actual position
    assert slot(core)[1] == ABORTED
