"""Linear gearing cycle by cycle (TcMC 3.17-3.21: MC_GearIn, MC_GearInFloat, MC_GearInDyn, MC_GearOut,
MC_GearOutExt; nc_server/core/stages/coupling.py, nc_server/core/jobs/gearing.py).

Every cycle a coupled slave's NCTOPLC SetPos is checked against s_start + ratio * (master SetPos -
m_start) and its SetVelo/SetAcc against ratio x the master's (``Follow``); the motion of each axis
around couplings and decouplings goes through engine_check.Trace (limits, no set-point jump, job
records). A coupled slave's jerk is ratio x its master's: its Trace gets that as its jerk limit
(``slave_trace``). Refusals are checked to change nothing (znc_testing.nc_core.snapshot).
"""
from __future__ import annotations

import math
from typing import Any, Callable, Iterable

import numpy as np
import pytest
from ruckig import InputParameter, Result, Ruckig, Trajectory

from nc_schema import (AxisState, CmdState, CoupleState, E_DecoupleMode, ErrorCodes as E, MC_AxisStates, NcError,
                       NcJobsSyncFlags, StateDWord, make_request, parse_request)
from nc_server.core import AxisConfig, AxisParams, NcCore
from znc_testing.engine_check import Trace
from znc_testing.nc_core import cmd, power, snapshot, state

DT = 0.001
ACTIVE, DONE, ABORTED, ERROR = (int(CmdState.ACTIVE), int(CmdState.DONE), int(CmdState.ABORTED), int(CmdState.ERROR))
SYNCHRONIZING, SYNCHRON = int(AxisState.SLAVE_SYNCHRONIZING), int(AxisState.SLAVE_SYNCHRON)
SINGLE, MASTER, MASTERSLAVE, SLAVE = (int(CoupleState.SINGLE), int(CoupleState.MASTER), int(CoupleState.MASTERSLAVE),
                                      int(CoupleState.SLAVE))
PROTECTED, PTP = int(StateDWord.Protected), int(StateDWord.PTPmode)
POSITIVE, NEGATIVE, NOT_MOVING = (int(StateDWord.PositiveDirection), int(StateDWord.NegativeDirection),
                                  int(StateDWord.NotMoving))
CONTINUOUS, CONST_V, LOCKED = (int(StateDWord.ContinuousMotion), int(StateDWord.ConstantVelocity),
                               int(StateDWord.MotionCommandsLocked))
F_DYN, F_SYNC = int(NcJobsSyncFlags.GearInDyn), int(NcJobsSyncFlags.Synchronized)
#: master dynamics whose x3 stays within a slave's default AxisAcc/AxisDec (5000) and AxisJerk (50000)
M_DYN = dict(Acceleration=1000.0, Deceleration=1000.0, Jerk=10000.0)

RATIOS = [
    pytest.param("GearIn", dict(RatioNumerator=1, RatioDenominator=2), 0.5, id="1/2"),
    pytest.param("GearIn", dict(RatioNumerator=-3, RatioDenominator=1), -3.0, id="-3/1"),
    pytest.param("GearIn", dict(RatioNumerator=7, RatioDenominator=3), 7 / 3, id="7/3"),
    pytest.param("GearInFloat", dict(GearRatio=0.37), 0.37, id="float0.37"),
    pytest.param("GearInFloat", dict(GearRatio=-1.25), -1.25, id="float-1.25"),
]


# -- helpers ----------------------------------------------------------------------------------------
def rig(n: int = 2, params: dict[int, dict[str, Any]] | None = None) -> NcCore:
    """``n`` powered axes (AxisId = row + 1), stepped once; ``params``: AxisParams per row."""
    params = params or {}
    core = NcCore([AxisConfig(i + 1, f"A{i + 1}", AxisParams(**params.get(i, {}))) for i in range(n)], DT)
    for i in range(n):
        power(core, i)
    core.step()
    return core


def do(core: NcCore, row: int, name: str, **args: Any) -> dict[str, Any]:
    """A command to the axis of ``row``."""
    return cmd(core, name, axis=row + 1, **args)


def gear_in(core: NcCore, s: int, m: int, how: str = "GearIn", **args: Any) -> int:
    if how == "GearIn":
        args.setdefault("RatioNumerator", 1)
        args.setdefault("RatioDenominator", 1)
    rep = do(core, s, how, Master=m + 1, **args)
    assert rep["error"] == 0, rep
    return rep["CmdNo"]


def raw(core: NcCore, row: int, name: str, **args: Any) -> dict[str, Any]:
    """A request past the parser (which refuses NaN/inf itself): what reaches NcCore.execute."""
    req = parse_request(make_request(name, 1, "test", **{k: (0.0 if isinstance(v, float) else v) for k, v in args.items()}))
    req.update(args)
    return core.execute(req, row + 1)


def val(core: NcCore, row: int, name: str) -> float:
    return float(core.nctoplc[row][name])


def sp(core: NcCore, row: int) -> tuple[float, float, float]:
    r = core.nctoplc[row]
    return float(r["SetPos"]), float(r["SetVelo"]), float(r["SetAcc"])


def dw(core: NcCore, row: int) -> int:
    return int(core.nctoplc[row]["StateDWord"])


def ended(core: NcCore, row: int) -> dict[int, tuple[int, int]]:
    return {int(no): (int(st), int(err)) for no, st, err in core.ncjobs[row]["Ended"].tolist() if no}


def gear_ratio1(core: NcCore, row: int, value: float) -> None:
    """PLCTONC.GearRatio1 of the slave (MC_GearInDyn writes it every PLC cycle)."""
    rec = core.plctonc[row].copy()
    rec["GearRatio1"] = value
    core.set_plctonc(row, rec)


def slave_trace(core: NcCore, s: int, ratio: float, master_jerk: float, **kw: Any) -> Trace:
    """A Trace of a coupled slave: its jerk is ratio x the master's (may exceed its own AxisJerk)."""
    return Trace(core, s, jerk=max(core.params[s].AxisJerk, abs(ratio) * master_jerk), **kw)


class Follow:
    """Slave row ``s`` follows master row ``m`` at ``ratio``: SetPos == s0 + ratio (master SetPos - m0)
    within 1e-9 x the scale, SetVelo / SetAcc == ratio x the master's (bases: the set positions now)."""

    def __init__(self, core: NcCore, s: int, m: int, ratio: float) -> None:
        self.core, self.s, self.m, self.ratio = core, s, m, ratio
        self.s0, self.m0 = val(core, s, "SetPos"), val(core, m, "SetPos")

    def check(self) -> None:
        c, s, m, r = self.core, self.s, self.m, self.ratio
        ps, pm = val(c, s, "SetPos"), val(c, m, "SetPos")
        want = self.s0 + r * (pm - self.m0)
        tol = 1e-9 * max(1.0, abs(ps), abs(self.s0), abs(r * pm), abs(r * self.m0))
        assert abs(ps - want) <= tol, f"cycle {c.cycle}: slave {s} SetPos {ps} != {want} (ratio {r})"
        for f in ("SetVelo", "SetAcc"):
            x, y = val(c, s, f), r * val(c, m, f)
            assert abs(x - y) <= 1e-9 * max(1.0, abs(y)), f"cycle {c.cycle}: slave {s} {f} {x} != {r} x {val(c, m, f)}"
        v, bits = val(c, s, "SetVelo"), dw(c, s)
        want_bits = POSITIVE if v > 1e-9 else NEGATIVE if v < -1e-9 else NOT_MOVING
        assert bits & (POSITIVE | NEGATIVE | NOT_MOVING) == want_bits, f"cycle {c.cycle}: StateDWord {bits:#x} at SetVelo {v}"


def run(core: NcCore, n: int | None = None, until: Callable[[], Any] | None = None, traces: Iterable[Trace] = (),
        follows: Iterable[Follow] = (), max_cycles: int = 20_000) -> int:
    """Step ``n`` cycles (or until ``until()``), checking the traces and couplings every cycle."""
    traces, follows = list(traces), list(follows)
    for k in range(1, (n or max_cycles) + 1):
        core.step()
        for t in traces:
            t.take()
        for f in follows:
            f.check()
        if until is not None and until():
            return k
    if until is not None and n is None:
        raise AssertionError(f"condition not reached within {max_cycles} cycles")
    return n or 0


def done(core: NcCore, row: int, cmd_no: int) -> Callable[[], bool]:
    return lambda: int(core.nctoplc[row]["CmdNo"]) == cmd_no and int(core.nctoplc[row]["CmdState"]) == DONE


def standing(core: NcCore, row: int) -> Callable[[], bool]:
    return lambda: val(core, row, "SetVelo") == 0.0 and val(core, row, "SetAcc") == 0.0 and not core.axes.traj_on[row]


def constant(core: NcCore, row: int) -> Callable[[], bool]:
    return lambda: val(core, row, "SetAcc") == 0.0 and bool(dw(core, row) & CONST_V)


def assert_coupled(core: NcCore, s: int, m: int, ratio: float, cmd_no: int) -> None:
    assert int(core.nctoplc[s]["CmdNo"]) == cmd_no and int(core.nctoplc[s]["CmdState"]) == ACTIVE  # InGear
    assert int(core.nctoplc[s]["CoupleState"]) in (SLAVE, MASTERSLAVE)
    assert int(core.nctoplc[m]["CoupleState"]) in (MASTER, MASTERSLAVE)
    assert int(core.ncjobs[s]["MasterId"]) == m + 1 and float(core.ncjobs[s]["GearRatio"]) == ratio
    assert dw(core, s) & PROTECTED and not dw(core, s) & PTP
    assert state(core, s) == MC_AxisStates.MC_AXISSTATE_SYNCHRONIZEDMOTION
    assert int(core.nctoplc[s]["ErrorCode"]) == 0


def assert_single(core: NcCore, row: int) -> None:
    assert int(core.nctoplc[row]["CoupleState"]) == SINGLE
    assert int(core.ncjobs[row]["MasterId"]) == 0 and float(core.ncjobs[row]["GearRatio"]) == 0.0
    assert int(core.ncjobs[row]["SyncFlags"]) == 0
    assert not dw(core, row) & PROTECTED and dw(core, row) & PTP
    assert int(core.nctoplc[row]["AxisState"]) not in (SYNCHRONIZING, SYNCHRON)


def braking_velocity(v: float, a: float, jerk: float) -> float:
    """The velocity reached when the acceleration ``a`` is brought to zero with ``jerk``."""
    return v + a * abs(a) / (2.0 * jerk)


def optimal_duration(p0: float, v0: float, a0: float, p1: float, vmax: float, amax: float, jerk: float) -> float:
    """Time-optimal jerk-limited move from (p0, v0, a0) to rest at p1 (ruckig called directly)."""
    otg, inp, traj = Ruckig(1), InputParameter(1), Trajectory(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [p0], [v0], [a0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [p1], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [vmax], [amax], [jerk]
    assert otg.calculate(inp, traj) in (Result.Working, Result.Finished)
    return float(traj.duration)


# -- fixed ratios ----------------------------------------------------------------------------------
@pytest.mark.parametrize("how,args,ratio", RATIOS)
def test_the_slave_follows_a_positioning_master_exactly(how, args, ratio):
    """Master moved by MoveAbsolute (there and back, override changes on the way): every cycle the slave
    is s_start + ratio x the master's travel; the slave's own override does nothing while it is coupled."""
    core = rig(2)
    assert do(core, 0, "SetActualPosition", Position=-3.0)["error"] == 0
    assert do(core, 1, "SetActualPosition", Position=12.5)["error"] == 0
    core.step()
    n = gear_in(core, 1, 0, how, **args)
    trs, trm = slave_trace(core, 1, ratio, M_DYN["Jerk"]), Trace(core, 0)
    fol = Follow(core, 1, 0, ratio)
    run(core, 1, traces=(trs, trm), follows=(fol,))
    assert int(core.nctoplc[1]["AxisState"]) == SYNCHRON and int(core.ncjobs[1]["SyncFlags"]) == F_SYNC
    assert_coupled(core, 1, 0, ratio, n)
    assert int(core.nctoplc[0]["CoupleState"]) == MASTER and dw(core, 0) & PTP and not dw(core, 0) & PROTECTED

    m1 = do(core, 0, "MoveAbsolute", Position=15.0, Velocity=150.0, **M_DYN)["CmdNo"]
    run(core, until=done(core, 0, m1), traces=(trs, trm), follows=(fol,))
    power(core, 1, override=300_000)  # the slave's own override: ignored while coupled
    m2 = do(core, 0, "MoveAbsolute", Position=-10.0, Velocity=150.0, **M_DYN)["CmdNo"]
    run(core, 80, traces=(trs, trm), follows=(fol,))
    power(core, 0, override=400_000)  # the master's override moves the slave
    run(core, 100, traces=(trs, trm), follows=(fol,))
    power(core, 0)
    run(core, until=done(core, 0, m2), traces=(trs, trm), follows=(fol,))
    assert abs(val(core, 1, "SetPos") - (12.5 + ratio * (-10.0 + 3.0))) <= 1e-9 * 50
    assert val(core, 1, "SetVelo") == 0.0 and trs.col("SetVelo").max() > 0 > trs.col("SetVelo").min()
    assert_coupled(core, 1, 0, ratio, n)
    assert int(core.nctoplc[1]["AxisState"]) == SYNCHRON


@pytest.mark.parametrize("how,args,ratio", RATIOS)
def test_the_slave_follows_an_endless_master_and_gears_out_seamlessly(how, args, ratio):
    """Master MoveVelocity with override changes; MC_GearOut while the master accelerates: the slave
    brings its acceleration to zero with its AxisJerk and goes on at the velocity it then has (a
    numbered MoveVelocity-like job, ContinuousMotion); no jump of position, velocity or acceleration."""
    core = rig(2)
    n = gear_in(core, 1, 0, how, **args)
    trs, trm = slave_trace(core, 1, ratio, M_DYN["Jerk"]), Trace(core, 0)
    fol = Follow(core, 1, 0, ratio)
    do(core, 0, "MoveVelocity", Velocity=100.0, Direction=1, **M_DYN)
    run(core, 160, traces=(trs, trm), follows=(fol,))
    power(core, 0, override=400_000)
    run(core, 200, traces=(trs, trm), follows=(fol,))
    power(core, 0)
    run(core, 60, traces=(trs, trm), follows=(fol,))
    _, v0, a0 = sp(core, 1)
    assert abs(a0) > 300 * abs(ratio)  # the master (and so the slave) accelerates
    rep = do(core, 1, "GearOut")
    assert rep["error"] == 0 and rep["CmdNo"] != n, rep
    v_end = braking_velocity(v0, a0, core.params[1].AxisJerk)
    run(core, until=constant(core, 1), traces=(trs, trm), max_cycles=500)
    assert abs(val(core, 1, "SetVelo") - v_end) <= 1e-9 * abs(v_end)
    run(core, 20, traces=(trs, trm))
    assert abs(val(core, 1, "SetVelo") - v_end) <= 1e-9 * abs(v_end) and val(core, 1, "SetAcc") == 0.0
    assert int(core.nctoplc[1]["CmdNo"]) == rep["CmdNo"] and int(core.nctoplc[1]["CmdState"]) == ACTIVE
    assert dw(core, 1) & CONTINUOUS and state(core, 1) == MC_AxisStates.MC_AXISSTATE_CONTINOUSMOTION
    assert ended(core, 1)[n] == (DONE, 0)
    assert_single(core, 1)
    assert_single(core, 0)
    assert val(core, 0, "SetVelo") > 0  # the master goes on


def test_set_actual_position_on_the_fly_moves_no_slave():
    """MC_SetActualPositionOnTheFly of a moving master (and of a slave in the middle of a chain): the
    shifted axis's positions jump by the shift, its slaves' do not."""
    core = rig(3)
    gear_in(core, 1, 0, RatioNumerator=7, RatioDenominator=3)
    gear_in(core, 2, 1, RatioNumerator=-3, RatioDenominator=1)
    jm = 5000.0
    tra, trb, trc = Trace(core, 0), slave_trace(core, 1, 7 / 3, jm), slave_trace(core, 2, 7.0, jm)
    fab, fbc, fac = Follow(core, 1, 0, 7 / 3), Follow(core, 2, 1, -3.0), Follow(core, 2, 0, -7.0)
    do(core, 0, "MoveVelocity", Velocity=50.0, Direction=1, Acceleration=500.0, Deceleration=500.0, Jerk=jm)
    kw = dict(traces=(tra, trb, trc), follows=(fab, fbc, fac))
    run(core, 100, **kw)
    prev = val(core, 0, "SetPos")
    assert do(core, 0, "SetActualPositionOnTheFly", ActualPosition=1000.0, PreviousPosition=prev)["error"] == 0
    tra.shift(1000.0 - prev)
    fab.m0 += 1000.0 - prev
    fac.m0 += 1000.0 - prev
    run(core, 60, **kw)
    prev = val(core, 1, "SetPos")
    assert do(core, 1, "SetActualPositionOnTheFly", ActualPosition=prev - 250.0, PreviousPosition=prev)["error"] == 0
    trb.shift(-250.0)
    fab.s0 -= 250.0
    fbc.m0 -= 250.0
    run(core, 60, **kw)
    assert val(core, 0, "SetPos") > 1000.0 and int(core.nctoplc[2]["ErrorCode"]) == 0


def test_set_actual_position_of_a_standing_master_moves_no_slave():
    core = rig(2)
    n = gear_in(core, 1, 0, RatioNumerator=-3, RatioDenominator=1)
    core.step()
    s = val(core, 1, "SetPos")
    assert do(core, 0, "SetActualPosition", Position=500.0)["error"] == 0
    core.step()
    assert val(core, 0, "SetPos") == 500.0 and val(core, 1, "SetPos") == s
    fol = Follow(core, 1, 0, -3.0)
    before = snapshot(core)
    rep = do(core, 1, "SetActualPosition", Position=5.0)  # a coupled slave has a job: refused
    assert rep["error"] == E.MC_AXIS_CANNOT_BE_STARTED == 0x4B01, rep
    assert snapshot(core) == before
    m = do(core, 0, "MoveRelative", Distance=2.0, Velocity=100.0, **M_DYN)["CmdNo"]
    trs = slave_trace(core, 1, -3.0, M_DYN["Jerk"])
    run(core, until=done(core, 0, m), traces=(trs,), follows=(fol,))
    assert abs(val(core, 1, "SetPos") - (s - 6.0)) < 1e-9 * 10
    assert_coupled(core, 1, 0, -3.0, n)


# -- chains, several slaves, states ------------------------------------------------------------------
def test_a_chain_and_several_slaves_follow_in_the_same_cycle():
    """A -> B (7/3) -> C (-3/1), A -> D (1/4): C follows A's travel x both ratios in the same cycle (no
    lag per link); CoupleState MASTER / MASTERSLAVE / SLAVE, AxisState 13, NCJOBS MasterId / GearRatio."""
    core = rig(4)
    nc = gear_in(core, 2, 1, RatioNumerator=-3, RatioDenominator=1)  # (the lower link first)
    nb = gear_in(core, 1, 0, RatioNumerator=7, RatioDenominator=3)
    nd = gear_in(core, 3, 0, "GearInFloat", GearRatio=0.25)
    core.step()
    assert core.nctoplc["CoupleState"].tolist() == [MASTER, MASTERSLAVE, SLAVE, SLAVE]
    assert core.nctoplc["AxisState"].tolist() == [0, SYNCHRON, SYNCHRON, SYNCHRON]
    assert core.ncjobs["MasterId"].tolist() == [0, 1, 2, 1]
    assert core.ncjobs["GearRatio"].tolist() == [0.0, 7 / 3, -3.0, 0.25]
    assert core.ncjobs["SyncFlags"].tolist() == [0, F_SYNC, F_SYNC, F_SYNC]
    assert [int(core.ncjobs[i]["ActiveCmdNo"]) for i in (1, 2, 3)] == [nb, nc, nd]
    assert [state(core, i) for i in range(4)] == [MC_AxisStates.MC_AXISSTATE_STANDSTILL] + [
        MC_AxisStates.MC_AXISSTATE_SYNCHRONIZEDMOTION] * 3
    for i in (1, 2, 3):
        assert dw(core, i) & PROTECTED and not dw(core, i) & PTP
    assert dw(core, 0) & PTP and not dw(core, 0) & PROTECTED
    jm = 5000.0
    fols = (Follow(core, 1, 0, 7 / 3), Follow(core, 2, 1, -3.0), Follow(core, 2, 0, -7.0), Follow(core, 3, 0, 0.25))
    trs = (Trace(core, 0), slave_trace(core, 1, 7 / 3, jm), slave_trace(core, 2, 7.0, jm), Trace(core, 3))
    m = do(core, 0, "MoveAbsolute", Position=10.0, Velocity=100.0, Acceleration=500.0, Deceleration=500.0, Jerk=jm)["CmdNo"]
    run(core, until=done(core, 0, m), traces=trs, follows=fols)
    assert abs(val(core, 2, "SetPos") + 70.0) < 1e-9 * 100 and abs(val(core, 3, "SetPos") - 2.5) < 1e-12
    assert core.nctoplc["ErrorCode"].tolist() == [0, 0, 0, 0]
    # the middle link decoupled at standstill: B is a master only, A still D's
    assert do(core, 1, "GearOut")["error"] == 0
    core.step()
    assert core.nctoplc["CoupleState"].tolist() == [MASTER, MASTER, SLAVE, SLAVE]
    assert core.ncjobs["MasterId"].tolist() == [0, 0, 2, 1] and ended(core, 1)[nb] == (DONE, 0)
    assert dw(core, 1) & PTP and not dw(core, 1) & PROTECTED and int(core.nctoplc[1]["AxisState"]) == 0
    m = do(core, 1, "MoveRelative", Distance=-1.0, Velocity=50.0, **M_DYN)["CmdNo"]  # B moves on its own: C follows
    fbc = Follow(core, 2, 1, -3.0)
    run(core, until=done(core, 1, m), follows=(fbc,))
    assert abs(val(core, 2, "SetPos") + 70.0 - 3.0) < 1e-9 * 100


# -- refusals ---------------------------------------------------------------------------------------
def refusal_rig() -> NcCore:
    """A(0) -> B(1) -> C(2); D(3) single, standing; E(4) single, moving; F(5) in ErrorStop."""
    core = rig(6)
    gear_in(core, 1, 0)
    gear_in(core, 2, 1)
    do(core, 4, "MoveVelocity", Velocity=10.0, Direction=1)
    core.step()
    core.fault(5, E.NC_POSITION_LAG)
    run(core, 5)
    return core


@pytest.mark.parametrize("row,name,args,code", [
    (3, "GearIn", dict(Master=1, RatioNumerator=1, RatioDenominator=0), 0x4B06),
    (3, "GearIn", dict(Master=1, RatioNumerator=1, RatioDenominator=-1), 0x4B06),
    (3, "GearIn", dict(Master=1, RatioNumerator=1, RatioDenominator=70000), 0x4B06),
    (3, "GearIn", dict(Master=1, RatioNumerator=40000, RatioDenominator=1), 0x4B06),
    (3, "GearIn", dict(Master=4, RatioNumerator=1, RatioDenominator=1), 0x4B06),   # its own master
    (0, "GearIn", dict(Master=3, RatioNumerator=1, RatioDenominator=1), 0x4B06),   # A <- C: a cycle
    (0, "GearInFloat", dict(Master=2, GearRatio=1.0), 0x4B06),                     # A <- B: a cycle
    (3, "GearIn", dict(Master=9, RatioNumerator=1, RatioDenominator=1), 0x4012),
    (3, "GearInFloat", dict(Master=0, GearRatio=1.0), 0x4012),
    (1, "GearIn", dict(Master=1, RatioNumerator=1, RatioDenominator=1), 0x4B08),   # already coupled (same master)
    (1, "GearInFloat", dict(Master=4, GearRatio=2.0), 0x4B08),                     # ... to another one
    (2, "GearInDyn", dict(Master=4, GearRatio=2.0), 0x4B08),
    (4, "GearIn", dict(Master=5, RatioNumerator=1, RatioDenominator=1), 0x4B06),   # (before 'moving')
    (4, "GearIn", dict(Master=1, RatioNumerator=1, RatioDenominator=1), 0x4B01),   # a moving slave
    (5, "GearIn", dict(Master=1, RatioNumerator=1, RatioDenominator=1), 0x4B01),   # in ErrorStop
    (3, "GearInFloat", dict(Master=1, GearRatio=1e7), 0x4B06),
    (3, "GearInFloat", dict(Master=1, GearRatio=-1.000001e6), 0x4B06),
    (3, "GearInDyn", dict(Master=1, GearRatio=2e6), 0x4B06),
    (3, "GearInDyn", dict(Master=1, GearRatio=1.0, Acceleration=-1.0), 0x422F),
    (3, "GearOut", {}, 0x4B05),
    (0, "GearOut", {}, 0x4B05),                                                    # a master is no slave
    (4, "GearOutExt", dict(Mode=2), 0x4B05),
])
def test_refused_couplings_change_nothing(row, name, args, code):
    core = refusal_rig()
    before = snapshot(core)
    rep = do(core, row, name, **args)
    assert rep["error"] == code, rep
    assert "CmdNo" not in rep
    assert snapshot(core) == before


@pytest.mark.parametrize("name", ["GearInFloat", "GearInDyn"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_gear_ratio_is_refused(name, bad):
    """The parser refuses NaN/inf itself (0x706); a request that gets past it: 0x4B06, nothing changes."""
    core = refusal_rig()
    with pytest.raises(NcError) as exc:
        parse_request(make_request(name, 1, "test", Master=1, GearRatio=bad))
    assert exc.value.code == E.ADSERR_DEVICE_INVALIDDATA == 0x706
    before = snapshot(core)
    rep = raw(core, 3, name, Master=1, GearRatio=bad)
    assert rep["error"] == E.MC_PARAMETER_NOT_CORRECT == 0x4B06, rep
    assert snapshot(core) == before


# -- motion commands to a slave ---------------------------------------------------------------------------
def moving_pair(**slave_params: Any) -> tuple[NcCore, int]:
    """Slave B(1) of master A(0) at 1/2, A at MoveVelocity 200 (B at 100 u/s)."""
    core = rig(2, {1: slave_params})
    n = gear_in(core, 1, 0, RatioNumerator=1, RatioDenominator=2)
    do(core, 0, "MoveVelocity", Velocity=200.0, Direction=1)
    run(core, until=constant(core, 0), max_cycles=500)
    return core, n


@pytest.mark.parametrize("name,args", [
    ("MoveAbsolute", dict(Position=100.0, Velocity=50.0)),
    ("MoveAbsolute", dict(Position=100.0, Velocity=50.0, BufferMode=1)),
    ("MoveRelative", dict(Distance=10.0, Velocity=50.0)),
    ("MoveAdditive", dict(Distance=10.0, Velocity=50.0)),
    ("MoveModulo", dict(Position=10.0, Velocity=50.0)),
    ("MoveVelocity", dict(Velocity=50.0, Direction=1)),
    ("MoveContinuousAbsolute", dict(Position=100.0, Velocity=50.0, EndVelocity=10.0)),
    ("Halt", {}),
    ("OrientedStop", dict(Position=10.0)),
    ("Jog", dict(Mode=0, Direction=1)),
    ("Home", {}),
])
def test_motion_commands_to_a_coupled_slave_are_refused_by_default(name, args):
    core, n = moving_pair()
    before = snapshot(core)
    rep = do(core, 1, name, **args)
    assert rep["error"] == E.NC_SLAVE_COMMAND_NOT_ALLOWED == 0x4266, rep
    assert snapshot(core) == before
    fol = Follow(core, 1, 0, 0.5)
    run(core, 20, follows=(fol,))
    assert_coupled(core, 1, 0, 0.5, n)


@pytest.mark.parametrize("mode", [1, 2, 3, 4, 5])
def test_with_allow_motion_cmd_to_slave_only_aborting_is_accepted(mode):
    core, n = moving_pair(AxisAllowMotionCmdToSlave=True)
    before = snapshot(core)
    rep = do(core, 1, "MoveAbsolute", Position=100.0, Velocity=50.0, BufferMode=mode)
    assert rep["error"] == E.MC_BUFFERMODE_NOT_SUPPORTED == 0x4B64, rep
    assert snapshot(core) == before


@pytest.mark.parametrize("name,args", [
    ("MoveAbsolute", dict(Position=60.0, Velocity=300.0)),
    ("MoveVelocity", dict(Velocity=40.0, Direction=1)),
    ("Halt", {}),
])
def test_with_allow_motion_cmd_to_slave_a_command_decouples_and_takes_over_seamlessly(name, args):
    core, n = moving_pair(AxisAllowMotionCmdToSlave=True)
    trs, trm = Trace(core, 1), Trace(core, 0)
    rep = do(core, 1, name, **args)
    assert rep["error"] == 0 and rep["CmdNo"] != n, rep
    end = constant(core, 1) if name == "MoveVelocity" else done(core, 1, rep["CmdNo"])
    run(core, until=end, traces=(trs, trm), max_cycles=2000)  # Trace: no jump at the take-over
    if name == "MoveAbsolute":
        assert val(core, 1, "SetPos") == 60.0
    elif name == "MoveVelocity":
        assert abs(val(core, 1, "SetVelo") - 40.0) < 1e-9
    assert ended(core, 1)[n] == (ABORTED, 0)
    assert_single(core, 1)
    assert_single(core, 0)
    assert abs(val(core, 0, "SetVelo") - 200.0) < 1e-9 and np.ptp(trm.col("SetVelo")) == 0.0


def test_mc_stop_on_a_slave_decouples_stops_and_locks():
    core, n = moving_pair()
    trs, trm = Trace(core, 1), Trace(core, 0)
    rep = do(core, 1, "Stop")
    assert rep["error"] == 0, rep
    run(core, until=done(core, 1, rep["CmdNo"]), traces=(trs, trm), max_cycles=500)
    assert val(core, 1, "SetVelo") == 0.0 and ended(core, 1)[n] == (ABORTED, 0)
    assert_single(core, 1)
    assert_single(core, 0)
    assert dw(core, 1) & LOCKED
    assert do(core, 1, "GearIn", Master=1, RatioNumerator=1, RatioDenominator=2)["error"] == E.NC_AXIS_LOCKED_BY_STOP
    assert abs(val(core, 0, "SetVelo") - 200.0) < 1e-9


def test_mc_stop_on_a_master_stops_it_and_its_slaves_follow_still_coupled():
    core, n = moving_pair()
    trs, trm = Trace(core, 1), Trace(core, 0)
    fol = Follow(core, 1, 0, 0.5)
    rep = do(core, 0, "Stop")
    run(core, until=done(core, 0, rep["CmdNo"]), traces=(trs, trm), follows=(fol,), max_cycles=500)
    assert val(core, 0, "SetVelo") == 0.0 and val(core, 1, "SetVelo") == 0.0
    assert_coupled(core, 1, 0, 0.5, n)
    assert state(core, 0) == MC_AxisStates.MC_AXISSTATE_STOPPING  # (locked until Execute falls)
    assert not dw(core, 1) & LOCKED


# -- errors and enables --------------------------------------------------------------------------------
@pytest.mark.parametrize("how", ["fault", "lag", "softlimit"])
def test_a_master_error_stops_the_master_and_the_slaves_follow_without_errors(how):
    """core.fault; a lag error from the monitoring; MoveVelocity stopped exactly at an enabled soft limit
    (then 0x4462): the master's error, its own ramp; the slaves follow it still coupled, no error."""
    master = dict(AxisAcc=2000.0, AxisDec=2000.0, AxisJerk=20000.0)  # x 1.5 within the slaves' limits
    master.update({"lag": dict(AxisMaxPosLagValue=0.05),
                   "softlimit": dict(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=20.0)}.get(how, {}))
    code = E.NC_SOFT_LIMIT_MAX_POSITIONING if how == "softlimit" else E.NC_POSITION_LAG
    core = rig(3, {0: master})
    n1 = gear_in(core, 1, 0, RatioNumerator=1, RatioDenominator=2)
    n2 = gear_in(core, 2, 0, RatioNumerator=-3, RatioDenominator=2)
    fols = (Follow(core, 1, 0, 0.5), Follow(core, 2, 0, -1.5))
    trs = (Trace(core, 0), Trace(core, 1), Trace(core, 2))
    m = do(core, 0, "MoveVelocity", Velocity=150.0, Direction=1)["CmdNo"]
    if how == "fault":
        run(core, 100, traces=trs, follows=fols)
        core.fault(0, E.NC_POSITION_LAG)
        run(core, 1, traces=trs, follows=fols)
    else:  # lag: the SimDrive's lag (velocity x 1 ms) exceeds 0.05 for 20 ms: 0x4550 from the monitoring
        run(core, until=lambda: val(core, 0, "ErrorCode") != 0, traces=trs, follows=fols, max_cycles=1000)
    assert int(core.nctoplc[0]["ErrorCode"]) == code
    if how != "softlimit":
        assert val(core, 0, "SetVelo") > 10.0  # it was moving: a ramp follows
    run(core, until=standing(core, 0), traces=trs, follows=fols, max_cycles=500)
    if how == "softlimit":
        assert val(core, 0, "SetPos") == 20.0 and val(core, 1, "SetPos") == 10.0
    assert ended(core, 0)[m] == (ERROR, code)
    assert state(core, 0) == MC_AxisStates.MC_AXISSTATE_ERRORSTOP
    run(core, 5, traces=trs, follows=fols)
    assert_coupled(core, 1, 0, 0.5, n1)
    assert_coupled(core, 2, 0, -1.5, n2)
    assert val(core, 1, "SetVelo") == 0.0 and val(core, 2, "SetVelo") == 0.0


def test_a_slave_error_decouples_it_and_ramps_it_down_its_master_is_unaffected():
    """B faults: B decoupled, its own stop ramp (its limits); A goes on; C (B's slave) follows B's ramp."""
    core = rig(3, {1: dict(AxisDec=2000.0)})  # (B's ramp x 2 within C's AxisDec)
    nb = gear_in(core, 1, 0, RatioNumerator=1, RatioDenominator=2)
    nc = gear_in(core, 2, 1, RatioNumerator=2, RatioDenominator=1)
    do(core, 0, "MoveVelocity", Velocity=300.0, Direction=1)
    trs = (Trace(core, 0), Trace(core, 1), slave_trace(core, 2, 2.0, 50000.0))
    fbc = Follow(core, 2, 1, 2.0)
    run(core, 150, traces=trs, follows=(fbc, Follow(core, 1, 0, 0.5)))
    core.fault(1, E.NC_POSITION_LAG)
    run(core, until=standing(core, 1), traces=trs, follows=(fbc,), max_cycles=500)
    assert int(core.nctoplc[1]["ErrorCode"]) == E.NC_POSITION_LAG and ended(core, 1)[nb] == (ERROR, E.NC_POSITION_LAG)
    assert int(core.nctoplc[1]["CoupleState"]) == MASTER and int(core.ncjobs[1]["MasterId"]) == 0
    assert int(core.nctoplc[0]["CoupleState"]) == SINGLE
    assert val(core, 0, "SetVelo") == 300.0 and int(core.nctoplc[0]["ErrorCode"]) == 0
    assert_coupled(core, 2, 1, 2.0, nc)
    assert val(core, 2, "SetVelo") == 0.0


def test_enable_off_on_a_slave_aborts_the_coupling():
    core, n = moving_pair()
    power(core, 1, ctrl=0)
    trm = Trace(core, 0)
    run(core, 5, traces=(trm,))
    assert ended(core, 1)[n] == (ABORTED, 0)
    assert_single(core, 1)
    assert_single(core, 0)
    assert state(core, 1) == MC_AxisStates.MC_AXISSTATE_DISABLED
    assert val(core, 1, "SetPos") == val(core, 1, "ActPos") and val(core, 1, "SetVelo") == 0.0
    assert abs(val(core, 0, "SetVelo") - 200.0) < 1e-9


def test_enable_off_on_a_master_decouples_its_slaves_and_they_brake_alone():
    """The master's set position follows its actual position while disabled, which a slave cannot
    follow without a jump: its slaves are decoupled (the coupling job ABORTED) and brake on their own
    ramps from their set-point state, continuously, without an error."""
    core, n = moving_pair()
    v0 = val(core, 1, "SetVelo")
    assert v0 > 0
    p_prev, v_prev = val(core, 1, "SetPos"), v0
    power(core, 0, ctrl=0)
    for _ in range(400):
        core.step()
        p, v = val(core, 1, "SetPos"), val(core, 1, "SetVelo")
        assert abs(p - p_prev - 0.5 * (v + v_prev) * core.cycle_time) < 1e-5  # no jump (jerk dt^3 / 6)
        assert v <= v_prev + 1e-9  # braking, never faster
        p_prev, v_prev = p, v
    assert val(core, 0, "SetPos") == val(core, 0, "ActPos") and val(core, 0, "SetVelo") == 0.0
    assert ended(core, 1)[n][0] == ABORTED
    assert_single(core, 1)
    assert val(core, 1, "SetVelo") == 0.0 and int(core.nctoplc[1]["ErrorCode"]) == 0


def overspeeding(ratio: int = 3, **slave: Any) -> tuple[NcCore, int, Trace]:
    core = rig(2, {1: slave})
    n = gear_in(core, 1, 0, RatioNumerator=ratio, RatioDenominator=1)
    do(core, 0, "MoveVelocity", Velocity=1000.0, Direction=1, Acceleration=1000.0, Deceleration=1000.0)
    return core, n, Trace(core, 1, vmax=math.inf, amax=math.inf,
                          jerk=max(ratio * core.params[0].AxisJerk, 4 * core.params[1].AxisJerk))  # (a fault ramp: 4x)


@pytest.mark.parametrize("limit,code", [("velocity", 0x4359), ("acceleration", 0x422F)])
def test_a_slave_beyond_its_limits_faults_and_stops(limit, code):
    """Master fast, ratio 3: the slave beyond its AxisVeloMax (600) -> 0x4359; beyond its AxisAcc
    (2000 < 3 x 1000) -> 0x422F: an axis error, decoupled, a controlled stop to rest."""
    core, n, tr = overspeeding(**(dict(AxisVeloMax=600.0) if limit == "velocity" else dict(AxisAcc=2000.0, AxisDec=2000.0)))
    tr.until(lambda r: int(r["ErrorCode"]) != 0, 1000)
    k = len(tr.rows) - 1
    assert int(core.nctoplc[1]["ErrorCode"]) == code and ended(core, 1)[n] == (ERROR, code)
    v_f, a_f = sp(core, 1)[1:]
    if limit == "velocity":  # the first cycle beyond AxisVeloMax
        assert 600.0 < abs(v_f) <= 600.0 + abs(a_f) * core.cycle_time + 1e-9
    else:
        assert abs(a_f) > 2000.0
        assert abs(tr.col("SetAcc")[k - 1]) <= 2000.0 * (1 + 1e-6)
    tr.settle(2000)
    assert_single(core, 1)
    assert_single(core, 0)
    assert state(core, 1) == MC_AxisStates.MC_AXISSTATE_ERRORSTOP
    p = core.params[1]
    acc = np.abs(tr.col("SetAcc")[k + 1:])
    assert acc.max() <= max(p.AxisAcc, p.AxisDec, abs(a_f)) * (1 + 1e-9)   # never stronger than at the fault ...
    assert np.all(np.diff(np.abs(tr.col("SetVelo")[np.argmax(tr.col("SetVelo")):])) <= 1e-9)  # ... then braking to rest
    assert int(core.nctoplc[0]["ErrorCode"]) == 0 and val(core, 0, "SetVelo") > 0


def test_a_slave_beyond_its_velocity_limit_is_never_faster_after_the_fault():
    core, n, tr = overspeeding(AxisVeloMax=600.0)
    tr.until(lambda r: int(r["ErrorCode"]) != 0, 1000)
    v_fault = abs(float(tr.rows[-1]["SetVelo"]))
    tr.settle(2000)
    k = next(i for i, r in enumerate(tr.rows) if int(r["ErrorCode"]))
    # faulted in the first cycle beyond AxisVeloMax (judging ahead faulted legitimate motion); the fault
    # ramp takes the acceleration down with up to 4 x AxisJerk: beyond by at most a^2 / (8 AxisJerk)
    a_fault = abs(float(tr.rows[k]["SetAcc"]))
    jerk = core.params[1].AxisJerk
    assert np.abs(tr.col("SetVelo")[k:]).max() <= max(600.0, v_fault) + a_fault ** 2 / (8 * jerk) + 1e-9


# -- MC_GearInDyn ------------------------------------------------------------------------------------------
def gear_ratio(core: NcCore, row: int) -> float:
    return float(core.ncjobs[row]["GearRatio"])


def dyn_run(core: NcCore, s: int, m: int, n: int | None = None, until: Callable[[], Any] | None = None,
            rate: float | None = None, max_cycles: int = 5000, jerk: float = M_DYN["Jerk"]) -> list[float]:
    """Step a GearInDyn slave, checking every cycle: |dRatio| <= rate x dt (rate given), SetPos moved by
    ratio x the master's travel (re-based where the ratio changed: continuous), SetVelo == ratio x the
    master's, SetAcc == ratio x the master's + dRatio/dt x its velocity, no jump. Returns the ratios."""
    ratios = []
    for k in range(1, (n or max_cycles) + 1):
        (ps0, vs0, _), (pm0, _, _), r0 = sp(core, s), sp(core, m), gear_ratio(core, s)
        core.step()
        (ps, vs, as_), (pm, vm, am), r = sp(core, s), sp(core, m), gear_ratio(core, s)
        ratios.append(r)
        c = core.cycle
        if rate is not None:
            assert abs(r - r0) <= rate * DT * (1 + 1e-9) + 1e-15, f"cycle {c}: ratio {r0} -> {r}"
        tol = 1e-9 * max(1.0, abs(ps), abs(pm))
        assert abs((ps - ps0) - r * (pm - pm0)) <= tol, f"cycle {c}: the slave moved {ps - ps0}, ratio x master {r * (pm - pm0)}"
        assert abs(vs - r * vm) <= 1e-9 * max(1.0, abs(vs)), f"cycle {c}: SetVelo {vs} != {r} x {vm}"
        assert abs(as_ - (r * am + (r - r0) / DT * vm)) <= 1e-6 * max(1.0, abs(as_)), f"cycle {c}: SetAcc {as_}"
        # no jump: the move agrees with the velocities up to the ratio step of this cycle
        jump = (ps - ps0) - 0.5 * (vs0 + vs) * DT
        assert abs(jump) <= 0.5 * abs(r - r0) * abs(vm) * DT + abs(r) * jerk * DT ** 3 / 6 + 1e-9, f"cycle {c}: jump {jump}"
        assert int(core.nctoplc[s]["ErrorCode"]) == 0
        if until is not None and until():
            return ratios
    if until is not None and n is None:
        raise AssertionError("condition not reached")
    return ratios


def dyn_pair(gr1: float, acc: float = 5000.0, ratio: float = 1.0,
             params: dict[int, dict[str, Any]] | None = None) -> tuple[NcCore, int]:
    """GearInDyn slave B(1) of A(0) with PLCTONC.GearRatio1 ``gr1`` at the command; A at 500 u/s."""
    core = rig(2, params)
    gear_ratio1(core, 1, gr1)
    n = gear_in(core, 1, 0, "GearInDyn", GearRatio=ratio, Acceleration=acc)
    do(core, 0, "MoveVelocity", Velocity=500.0, Direction=1, **M_DYN)
    dyn_run(core, 1, 0, until=constant(core, 0), rate=0.0, max_cycles=1000)
    return core, n


def test_gear_in_dyn_ratio_follows_gear_ratio1_within_its_rate():
    """|dRatio/dt| <= Acceleration / master AxisVeloMax (5000 / 1000); position continuous across the ratio
    changes; after the ramp the slave runs at exactly ratio x the master; GearRatio1 unchanged: it stays."""
    core, n = dyn_pair(1.0)
    assert int(core.ncjobs[1]["SyncFlags"]) == F_DYN | F_SYNC and gear_ratio(core, 1) == 1.0
    gear_ratio1(core, 1, 1.4)
    ratios = dyn_run(core, 1, 0, until=lambda: gear_ratio(core, 1) == 1.4, rate=5.0)
    assert 80 <= len(ratios) <= 81 and np.all(np.diff(ratios) > 0)  # (0.4 / 0.005 steps; rounding: maybe a last tiny one)
    dyn_run(core, 1, 0, 50, rate=0.0)  # ('falling edge': GearRatio1 keeps its value, so does the ratio)
    assert gear_ratio(core, 1) == 1.4 and val(core, 1, "SetVelo") == 1.4 * 500.0 and val(core, 1, "SetAcc") == 0.0
    gear_ratio1(core, 1, 0.6)
    ratios = dyn_run(core, 1, 0, until=lambda: gear_ratio(core, 1) == 0.6, rate=5.0)
    assert 160 <= len(ratios) <= 161 and np.all(np.diff(ratios) < 0)
    dyn_run(core, 1, 0, 20, rate=0.0)
    assert abs(val(core, 1, "SetVelo") - 0.6 * 500.0) < 1e-9
    assert_coupled(core, 1, 0, 0.6, n)


def test_gear_in_dyn_default_rate_is_the_slave_acc_over_the_master_velo_max():
    core, n = dyn_pair(1.0, acc=0.0, params={0: dict(AxisVeloMax=800.0), 1: dict(AxisAcc=2000.0)})
    gear_ratio1(core, 1, 1.1)
    ratios = dyn_run(core, 1, 0, until=lambda: gear_ratio(core, 1) == 1.1, rate=2000.0 / 800.0)
    assert 40 <= len(ratios) <= 41
    assert abs(ratios[1] - ratios[0] - 2.5 * DT) < 1e-12


@pytest.mark.parametrize("then", ["changes", "equals"])
def test_a_stale_gear_ratio1_is_not_applied(then):
    """GearRatio1 left at 0.7 by an earlier block: the coupling keeps the command's ratio (1.0) until
    GearRatio1 equals it or changes; from then on it follows GearRatio1."""
    core, n = dyn_pair(0.7)
    dyn_run(core, 1, 0, 100, rate=0.0)
    assert gear_ratio(core, 1) == 1.0 and val(core, 1, "SetVelo") == 500.0
    if then == "changes":
        gear_ratio1(core, 1, 1.2)
        dyn_run(core, 1, 0, until=lambda: gear_ratio(core, 1) == 1.2, rate=5.0)
    else:
        gear_ratio1(core, 1, 1.0)
        dyn_run(core, 1, 0, 20, rate=0.0)
        gear_ratio1(core, 1, 0.7)  # the block's own value now
        dyn_run(core, 1, 0, until=lambda: gear_ratio(core, 1) == 0.7, rate=5.0)
    assert_coupled(core, 1, 0, gear_ratio(core, 1), n)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e7, -2e6])
def test_gear_in_dyn_ignores_a_non_finite_or_huge_gear_ratio1(bad):
    core, n = dyn_pair(1.0)
    gear_ratio1(core, 1, 1.2)
    dyn_run(core, 1, 0, until=lambda: gear_ratio(core, 1) == 1.2, rate=5.0)
    count = core.coupling.ignored_ratios
    gear_ratio1(core, 1, bad)
    dyn_run(core, 1, 0, 30, rate=0.0)
    assert gear_ratio(core, 1) == 1.2 and core.coupling.ignored_ratios == count + 30
    gear_ratio1(core, 1, 0.9)
    dyn_run(core, 1, 0, until=lambda: gear_ratio(core, 1) == 0.9, rate=5.0)
    assert core.coupling.ignored_ratios == count + 30
    assert_coupled(core, 1, 0, 0.9, n)


# -- coupling to a moving master ----------------------------------------------------------------------------
@pytest.mark.parametrize("ratio,velocity,how", [
    (2.0, 200.0, "constant"),
    (-1.0, 300.0, "constant"),
    (0.5, 400.0, "accelerating"),
    (2.0, 400.0, "accelerating"),   # 2 x the master's acceleration is beyond the slave's: it catches up later
    (1.0, 400.0, "braking"),
])
def test_coupling_to_a_moving_master_synchronizes_then_follows_exactly(ratio, velocity, how):
    core = rig(2)
    do(core, 0, "MoveVelocity", Velocity=velocity, Direction=1)
    if how == "constant":
        run(core, until=constant(core, 0), max_cycles=1000)
    elif how == "accelerating":
        run(core, 30)
    else:
        run(core, until=constant(core, 0), max_cycles=1000)
        do(core, 0, "Halt")
        run(core, 15)
    rep = do(core, 1, "GearInFloat", Master=1, GearRatio=ratio)
    assert rep["error"] == 0, rep
    tr = Trace(core, 1)  # its own limits while synchronizing
    k = tr.until(lambda r: int(r["AxisState"]) != SYNCHRONIZING, 1000)
    assert k > 1 and int(core.nctoplc[1]["AxisState"]) == SYNCHRON
    assert int(core.ncjobs[1]["SyncFlags"]) == F_SYNC
    assert {int(j["SyncFlags"]) for j in tr.jobs[:-1]} == {0}
    assert {state(core, 1)} == {MC_AxisStates.MC_AXISSTATE_SYNCHRONIZEDMOTION}
    # (locked on ruckig's end state of this cycle: off by at most a cycle of the master's acceleration)
    assert abs(val(core, 1, "SetVelo") - ratio * val(core, 0, "SetVelo")) <= abs(ratio * val(core, 0, "SetAcc")) * DT + 1e-9
    run(core, 1, traces=(tr,))
    fol = Follow(core, 1, 0, ratio)
    trm = Trace(core, 0)
    run(core, 150, traces=(tr, trm), follows=(fol,))
    assert int(core.nctoplc[1]["AxisState"]) == SYNCHRON and int(core.nctoplc[1]["ErrorCode"]) == 0
    assert_coupled(core, 1, 0, ratio, rep["CmdNo"])


def test_coupling_to_a_master_too_fast_for_the_slave_never_exceeds_its_velocity_limit():
    core = rig(2)
    do(core, 0, "MoveVelocity", Velocity=500.0, Direction=1)
    run(core, until=constant(core, 0), max_cycles=1000)
    rep = do(core, 1, "GearIn", Master=1, RatioNumerator=3, RatioDenominator=1)  # 1500 > AxisVeloMax 1000
    if rep["error"]:
        return  # refused: fine
    tr = Trace(core, 1, check_jumps=False, vmax=math.inf, amax=math.inf, jerk=math.inf)
    tr.step(600)
    assert np.abs(tr.col("SetVelo")).max() <= 1000.0 * (1 + 1e-9)


def test_mc_reset_of_a_synchronizing_slave_does_not_move_it():
    core = rig(2)
    do(core, 0, "MoveVelocity", Velocity=200.0, Direction=1)
    run(core, until=constant(core, 0), max_cycles=1000)
    gear_in(core, 1, 0, RatioNumerator=2, RatioDenominator=1)
    tr = Trace(core, 1)
    tr.step(60)
    assert int(core.nctoplc[1]["AxisState"]) == SYNCHRONIZING
    assert do(core, 1, "Reset")["error"] == 0
    tr.step(5)  # Trace: SetPos advances by the trapezoid of its velocities


# -- MC_GearOut / MC_GearOutExt ---------------------------------------------------------------------------
def test_gear_out_while_the_master_brakes_harder_than_the_slave_jerk():
    core = rig(2, {1: dict(AxisJerk=10000.0)})
    n = gear_in(core, 1, 0)
    do(core, 0, "MoveAbsolute", Position=50.0, Velocity=300.0)
    run(core, until=lambda: val(core, 0, "SetAcc") < 0 and val(core, 0, "SetVelo") < 20.0, max_cycles=1000)
    _, v0, a0 = sp(core, 1)
    v_end = braking_velocity(v0, a0, 10000.0)
    assert v_end < 0 < v0
    tr = Trace(core, 1, jerk=50000.0)
    rep = do(core, 1, "GearOut")
    assert rep["error"] == 0, rep
    tr.until(lambda r: float(r["SetAcc"]) == 0.0, 500)
    assert abs(val(core, 1, "SetVelo") - v_end) < 1e-9 * abs(v_end) and ended(core, 1)[n] == (DONE, 0)


def accelerating_slave() -> tuple[NcCore, int]:
    """Slave B(1) of A(0) at 1/2; A accelerating at 1000 u/s^2 (B at ~50 u/s, ~500 u/s^2)."""
    core = rig(2)
    n = gear_in(core, 1, 0, RatioNumerator=1, RatioDenominator=2)
    do(core, 0, "MoveVelocity", Velocity=400.0, Direction=1, **M_DYN)
    run(core, 150)
    assert abs(val(core, 1, "SetAcc") - 500.0) < 1e-6
    return core, n


@pytest.mark.parametrize("mode", range(7))
def test_gear_out_ext_continues_seamlessly_with_the_command_of_its_mode(mode):
    core, n = accelerating_slave()
    p0, v0, a0 = sp(core, 1)
    v_end = braking_velocity(v0, a0, core.params[1].AxisJerk)
    args = {1: dict(Position=(p0 + 10.0) % 360.0), 3: dict(Velocity=120.0), 4: dict(Position=p0 + 20.0),
            5: dict(Position=p0 + 20.0, Velocity=150.0)}.get(mode, {})
    trm = Trace(core, 0)
    tr = Trace(core, 1) if mode != 6 else None
    rep = do(core, 1, "GearOutExt", Mode=mode, **args)
    assert rep["error"] == 0, rep
    if mode == 6:  # INSTANTANEOUSSTOP: velocity 0 at once, the position holds, no follow-on
        assert "CmdNo" not in rep
        run(core, 1, traces=(trm,))
        assert sp(core, 1) == (p0, 0.0, 0.0)
        run(core, 20, traces=(Trace(core, 1), trm))
        assert sp(core, 1) == (p0, 0.0, 0.0) and int(core.nctoplc[1]["CmdNo"]) == n
        assert int(core.nctoplc[1]["CmdState"]) == DONE
    else:
        no = rep["CmdNo"]
        assert no != n
        if mode in (2, 3):
            run(core, until=constant(core, 1), traces=(tr, trm), max_cycles=500)
            assert abs(val(core, 1, "SetVelo") - (v_end if mode == 2 else 120.0)) < 1e-9
            assert int(core.nctoplc[1]["CmdState"]) == ACTIVE and dw(core, 1) & CONTINUOUS
        else:
            run(core, until=done(core, 1, no), traces=(tr, trm), max_cycles=3000)
            p = val(core, 1, "SetPos")
            assert val(core, 1, "SetVelo") == 0.0
            if mode == 0:
                assert tr.col("SetVelo").min() >= 0 and p > p0
            elif mode == 1:
                assert abs((p - args["Position"]) % 360.0) < 1e-9 or abs((p - args["Position"]) % 360.0 - 360.0) < 1e-9
            else:
                assert p == args["Position"]
                if mode == 5:
                    assert abs(tr.col("SetVelo").max() - 150.0) < 1e-9
        assert int(core.nctoplc[1]["CmdNo"]) == no
    assert ended(core, 1)[n] == (DONE, 0)
    assert_single(core, 1)
    assert_single(core, 0)
    assert val(core, 0, "SetVelo") > 0


def test_gear_out_ext_newpos_goes_to_its_position_time_optimally():
    core = rig(2)
    gear_in(core, 1, 0, RatioNumerator=1, RatioDenominator=2)
    core.step()
    do(core, 0, "MoveVelocity", Velocity=400.0, Direction=1)
    run(core, 60)
    p0, v0, a0 = sp(core, 1)  # (45 u/s, 1500 u/s^2 up to rounding: the rounding that trips ruckig)
    v_end = braking_velocity(v0, a0, core.params[1].AxisJerk)
    best = optimal_duration(p0, v0, a0, p0 + 50.0, v_end * (1 + 1e-9), 5000.0, 50000.0)
    rep = do(core, 1, "GearOutExt", Mode=4, Position=p0 + 50.0)
    k = run(core, until=done(core, 1, rep["CmdNo"]), max_cycles=3 * round(best / DT))
    assert k * DT <= best * 1.01 + 2 * DT, (k * DT, best)


@pytest.mark.parametrize("mode", range(7))
def test_gear_out_ext_at_standstill_just_decouples(mode):
    core = rig(2)
    n = gear_in(core, 1, 0, RatioNumerator=1, RatioDenominator=2)
    core.step()
    p = val(core, 1, "SetPos")
    rep = do(core, 1, "GearOutExt", Mode=mode, Position=10.0, Velocity=50.0)
    assert rep["error"] == 0 and "CmdNo" not in rep, rep
    run(core, 5)
    assert int(core.nctoplc[1]["CmdNo"]) == n and int(core.nctoplc[1]["CmdState"]) == DONE
    assert ended(core, 1)[n] == (DONE, 0) and not dw(core, 1) & StateDWord.HasJob
    assert val(core, 1, "SetPos") == p
    assert_single(core, 1)
    assert_single(core, 0)


def test_gear_out_ext_orientedstop_beyond_a_soft_limit_decouples_stops_and_ends_with_the_error():
    """GearOutExt Mode ORIENTEDSTOP whose oriented position lies beyond the enabled AxisMaxSoftPosLimit: as
    MC_OrientedStop (TcMC 3.16 "for all fault conditions, the axis is stopped safely"): accepted, the slave
    is decoupled (the coupling DONE) and makes the standard stop; the follow-on job ends ERROR 0x4222."""
    core, n = moving_pair(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0,
                          AxisEnMinSoftPosLimit=True, AxisMinSoftPosLimit=-100.0)
    p0, v0, a0 = sp(core, 1)
    assert a0 == 0.0 and 0.0 < p0 < 80.0 and v0 == pytest.approx(100.0)
    tr = Trace(core, 1)
    rep = do(core, 1, "GearOutExt", Mode=int(E_DecoupleMode.MC_DECOUPLEMODE_ORIENTEDSTOP), Position=350.0)
    assert rep["error"] == 0, rep
    no = rep["CmdNo"]
    assert ended(core, 1)[n] == (DONE, 0)
    run(core, until=standing(core, 1), traces=(tr,), max_cycles=500)
    run(core, 5, traces=(tr,))
    p = val(core, 1, "SetPos")
    # the standard stop from 100 u/s with AxisJerk 50000 (AxisDec 5000 not reached): v sqrt(v / jerk)
    assert p == pytest.approx(p0 + 100.0 * math.sqrt(100.0 / 50000.0), abs=0.2) and p < 100.0 and tr.col("SetVelo").min() >= 0
    assert ended(core, 1)[no] == (ERROR, int(E.NC_TARGET_POSITION_NOT_ALLOWED))
    assert int(core.nctoplc[1]["CmdNo"]) == no and int(core.nctoplc[1]["CmdState"]) == ERROR
    assert not dw(core, 1) & StateDWord.Error and not dw(core, 1) & StateDWord.HasJob
    assert_single(core, 1)
    assert_single(core, 0)
    assert val(core, 0, "SetVelo") == pytest.approx(200.0)  # (the master goes on)


@pytest.mark.parametrize("args,code", [
    (dict(Mode=7), 0x4B04),
    (dict(Mode=-1), 0x4B04),
    (dict(Mode=255), 0x4B04),
    (dict(Mode=4, Position=200.0), 0x4222),               # NEWPOS beyond the enabled AxisMaxSoftPosLimit (100)
    (dict(Mode=5, Position=-200.0, Velocity=50.0), 0x4222),
    (dict(Mode=5, Position=50.0, Velocity=5000.0), 0x4221),  # Velocity beyond AxisVeloMax
    (dict(Mode=3, Velocity=0.0), 0x4221),
    (dict(Mode=1, Position=400.0), 0x4281),               # an oriented position outside [0, 360)
])
def test_gear_out_ext_refused_the_slave_stays_coupled(args, code):
    core, n = moving_pair(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0,
                          AxisEnMinSoftPosLimit=True, AxisMinSoftPosLimit=-100.0)
    before = snapshot(core)
    rep = do(core, 1, "GearOutExt", **args)
    assert rep["error"] == code, rep
    assert snapshot(core) == before
    fol = Follow(core, 1, 0, 0.5)
    run(core, 20, follows=(fol,), traces=(Trace(core, 1),))
    assert_coupled(core, 1, 0, 0.5, n)
