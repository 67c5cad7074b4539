"""Velocity reductions reach the new velocity from above (issue 17), cycle by cycle on the pure core.

The issue's numbers: AxisAcc = AxisDec 5000 u/s^2, AxisJerk 50000 u/s^3, moving at 2000 u/s, new velocity
1000 u/s. Before the fix an Aborting MC_MoveAbsolute with the lower Velocity, MC_NewPosAndVelo and the
Override lowered from 100 % to 50 % all dipped to 750 u/s (ruckig's brake pre-profile ends with a != 0:
a^2 / (2 * jerk) = 250 u/s below the limit). The rule: no SetVelo below the new velocity beyond float
noise, a = 0 on arrival, as fast as the dynamics allow (here 0.3 s: 0.1 s jerk, 0.1 s at -5000, 0.1 s
jerk). Every case runs under the per-cycle checker with its velocity floors (:meth:`Trace.learn`).
"""
import random

import numpy as np
import pytest

from nc_schema import CmdState, MC_BufferMode
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.core.planning import Dynamics, StartState, plan_position, plan_velocity, velocity_change
from nc_server.core.profile import integrate_segment, velocity_extrema
from plc_client.fb import MC_OverrideFilter
from znc_testing.engine_check import Trace, cycles_for
from znc_testing.nc_core import cmd, power, powered, run_until

DONE, ACTIVE = int(CmdState.DONE), int(CmdState.ACTIVE)
P = dict(AxisAcc=5000.0, AxisDec=5000.0, AxisJerk=50000.0, AxisVeloMax=3000.0)
NOISE = 1e-7 * 1000.0  # float noise at 1000 u/s


def cruising(target=20000.0, velo=2000.0, cycles=800, **extra):
    """A core cruising at ``velo`` (MoveAbsolute 0 -> ``target``) with the issue's dynamics."""
    core = powered(**{**P, **extra})
    tr = Trace(core)
    n = tr.cmd("MoveAbsolute", Position=target, Velocity=velo)["CmdNo"]
    tr.step(cycles)
    assert float(tr.rows[-1]["SetVelo"]) == velo
    return core, tr, n


def reached_from_above(tr, k0, v_new, t_red=0.3):
    """From sample ``k0`` on: SetVelo never below ``v_new`` until it arrives, it arrives within the
    time-optimal reduction ``t_red`` [s] (plus a cycle) with SetAcc 0 and then holds ``v_new``."""
    v, a = tr.col("SetVelo")[k0:], tr.col("SetAcc")[k0:]
    n = cycles_for(t_red, tr.dt) + 1
    assert v[:n + 50].min() >= v_new - NOISE, f"dipped to {v[:n + 50].min()}"
    assert v[n] == pytest.approx(v_new, abs=NOISE) and a[n] == pytest.approx(0.0, abs=1e-6)
    assert (abs(v[n:n + 50] - v_new) <= NOISE).all()


# -- the three cases and the override filter ------------------------------------------
def test_aborting_move_absolute_with_a_lower_velocity():
    core, tr, _ = cruising()
    k0 = len(tr.rows)
    n2 = tr.cmd("MoveAbsolute", Position=20000.0, Velocity=1000.0)["CmdNo"]
    tr.step(500)
    reached_from_above(tr, k0, 1000.0)
    tr.settle()
    assert tr.fate(n2) == (DONE, 0) and float(tr.rows[-1]["SetPos"]) == 20000.0


def test_new_pos_and_velo_lower_velocity():
    core, tr, n = cruising()
    k0 = len(tr.rows)
    assert tr.cmd("NewPosAndVelo", Mode=2, NewPos=0.0, NewVelo=1000.0, ActivationPos=0.0)["error"] == 0
    tr.step(500)
    reached_from_above(tr, k0, 1000.0)
    tr.settle()
    assert tr.fate(n) == (DONE, 0)


def test_override_100_to_50_percent():
    core, tr, n = cruising()
    k0 = len(tr.rows)
    power(core, override=500_000)
    tr.learn("Override", {"Override": 0.5})
    tr.step(500)
    reached_from_above(tr, k0, 1000.0)
    tr.settle()
    assert tr.fate(n) == (DONE, 0) and float(tr.rows[-1]["SetPos"]) == 20000.0


def test_override_filter_output_lowered():
    """MC_OverrideFilter's output wired into PLCTONC.Override: the raw value halved (one filter step)."""
    core, tr, n = cruising()
    flt = MC_OverrideFilter()
    flt(OverrideValueRaw=32767, OverrideRecoveryTime=0.0)
    assert flt.OverrideValueFiltered == 1_000_000
    flt(OverrideValueRaw=16384)
    ov = flt.OverrideValueFiltered
    assert 0 < ov < 1_000_000 and not flt.Error
    k0 = len(tr.rows)
    power(core, override=ov)
    tr.learn("Override", {"Override": ov / 1e6})
    tr.step(500)
    reached_from_above(tr, k0, 2000.0 * ov / 1e6)


def test_override_filter_ramp_stays_above_each_level():
    """A raw value ramped down in many filter steps (one per 20 cycles): every level from above."""
    core, tr, n = cruising()
    flt = MC_OverrideFilter()
    flt(OverrideValueRaw=32767, OverrideRecoveryTime=0.0, OverrideSteps=200)
    for raw in range(32767, 16383, -1638):
        flt(OverrideValueRaw=raw)
        power(core, override=flt.OverrideValueFiltered)
        tr.learn("Override", {"Override": flt.OverrideValueFiltered / 1e6})
        tr.step(20)
    tr.step(400)
    assert float(tr.rows[-1]["SetVelo"]) == pytest.approx(2000.0 * flt.OverrideValueFiltered / 1e6, abs=NOISE)
    assert tr.col("SetVelo")[800:].min() >= 2000.0 * flt.OverrideValueFiltered / 1e6 - NOISE


# -- MC_ChangeDynParam ----------------------------------------------------------------------
@pytest.mark.parametrize("dyn", [dict(Acceleration=5000.0, Deceleration=2000.0, Jerk=50000.0),
                                 dict(Acceleration=5000.0, Deceleration=5000.0, Jerk=20000.0)])
def test_change_dyn_param_during_the_reduction(dyn):
    """Weaker dynamics in the middle of the reduction (braking at -5000): still from above, a = 0 on
    arrival (a lower Jerk: the least dip it allows is below 1000, the floor is that dip)."""
    core, tr, n = cruising()
    k0 = len(tr.rows)
    tr.cmd("MoveAbsolute", Position=20000.0, Velocity=1000.0)
    tr.step(150)  # in the hold at -5000 u/s^2
    assert float(tr.rows[-1]["SetAcc"]) == pytest.approx(-5000.0)
    v0, a0 = float(tr.rows[-1]["SetVelo"]), float(tr.rows[-1]["SetAcc"])
    assert tr.cmd("ChangeDynParam", **dyn)["error"] == 0
    tr.step(600)
    v = tr.col("SetVelo")[k0:]
    least = v0 - a0 * a0 / (2 * dyn["Jerk"])
    assert v.min() >= min(1000.0, least) - NOISE
    assert v[-1] == pytest.approx(1000.0, abs=NOISE) and float(tr.rows[-1]["SetAcc"]) == 0.0


# -- BufferMode hand-overs --------------------------------------------------------------------
@pytest.mark.parametrize("mode", [MC_BufferMode.MC_Buffered, MC_BufferMode.MC_BlendingLow,
                                  MC_BufferMode.MC_BlendingPrevious, MC_BufferMode.MC_BlendingNext,
                                  MC_BufferMode.MC_BlendingHigh])
def test_hand_over_to_a_slower_job(mode):
    """MoveAbsolute at 2000 to 3000, then one at 1000 to 6000 waiting with ``mode``: the second job
    (or the first's blend) reaches 1000 from above; Buffered stops in between."""
    core = powered(**P)
    tr = Trace(core)
    n1 = tr.cmd("MoveAbsolute", Position=3000.0, Velocity=2000.0)["CmdNo"]
    tr.step(10)
    n2 = tr.cmd("MoveAbsolute", Position=6000.0, Velocity=1000.0, BufferMode=int(mode))["CmdNo"]
    tr.settle()
    assert tr.fate(n1) == (DONE, 0) and tr.fate(n2) == (DONE, 0)
    assert float(tr.rows[-1]["SetPos"]) == 6000.0
    v, no = tr.col("SetVelo"), tr.col("CmdNo")
    k2 = int((no == n2).argmax())
    if mode != MC_BufferMode.MC_Buffered:  # blended: the second job moves at 1000 after its reduction
        assert v[k2] >= 1000.0 - NOISE
        cruise = v[k2:][(v[k2:] >= 1000.0 - NOISE)]
        k_end = k2 + len(cruise)
        assert (v[k2:k_end] >= 1000.0 - NOISE).all() and v[k_end - 1] == pytest.approx(1000.0, abs=NOISE)


# -- decisions where the manual is silent ----------------------------------------------------
def test_too_little_way_one_even_deceleration_to_the_target():
    """The reduction (0.3 s at 1500 u/s on average: 450 u) and a brake from 1000 (150 u) need 600 u; a
    target 550 u ahead (a full brake from 2000 needs 500) is reached by one even deceleration: SetVelo
    never rises, at rest there."""
    core, tr, _ = cruising()
    p0 = float(tr.rows[-1]["SetPos"])
    k0 = len(tr.rows)
    n2 = tr.cmd("MoveAbsolute", Position=p0 + 550.0, Velocity=1000.0)["CmdNo"]
    tr.settle()
    v = tr.col("SetVelo")[k0:]
    assert (v[1:] <= v[:-1] + 1e-9).all() and v.min() >= 0.0
    assert tr.fate(n2) == (DONE, 0) and float(tr.rows[-1]["SetPos"]) == pytest.approx(p0 + 550.0, abs=1e-9)
    # even: it starts braking at once (not cruising at 2000 first, then a full brake)
    assert v[20] < 2000.0 - 1.0


def test_full_brake_passing_the_target_goes_past_and_back():
    core, tr, _ = cruising()
    p0 = float(tr.rows[-1]["SetPos"])
    n2 = tr.cmd("MoveAbsolute", Position=p0 + 200.0, Velocity=1000.0)["CmdNo"]
    tr.settle()
    assert tr.fate(n2) == (DONE, 0) and float(tr.rows[-1]["SetPos"]) == pytest.approx(p0 + 200.0, abs=1e-9)
    assert tr.col("SetPos").max() > p0 + 200.0 + 1.0 and tr.col("SetVelo").min() < 0


def test_already_braking_harder_least_dip_then_back_up_with_a_zero():
    core, tr, _ = cruising()
    tr.cmd("MoveAbsolute", Position=20000.0, Velocity=1000.0)
    tr.step(150)
    v0, a0 = float(tr.rows[-1]["SetVelo"]), float(tr.rows[-1]["SetAcc"])
    least = v0 - a0 * a0 / (2 * 50000.0)  # 1500 - 250
    k0 = len(tr.rows)
    tr.cmd("MoveAbsolute", Position=20000.0, Velocity=1400.0)
    tr.step(400)
    v = tr.col("SetVelo")[k0:]
    assert v.min() == pytest.approx(least, abs=1.0) and least < 1400.0
    assert v[-1] == pytest.approx(1400.0, abs=NOISE) and float(tr.rows[-1]["SetAcc"]) == 0.0
    k = int(v.argmin())
    assert (v[k + 1:] >= v[k:-1] - 1e-9).all()  # the dip once, then up


def test_acceleration_carrying_past_the_new_velocity_comes_down_from_above():
    """Accelerating at +5000 through 1500 (towards 2000); a new velocity 1600 is passed anyway (to
    1750): it comes back down to 1600 from above with a = 0."""
    core = powered(**P)
    tr = Trace(core)
    tr.cmd("MoveAbsolute", Position=20000.0, Velocity=2000.0)
    tr.until(lambda r: r["SetVelo"] >= 1500.0)
    assert float(tr.rows[-1]["SetAcc"]) == pytest.approx(5000.0)
    k0 = len(tr.rows)
    tr.cmd("MoveAbsolute", Position=20000.0, Velocity=1600.0)
    tr.step(400)
    v = tr.col("SetVelo")[k0:]
    assert v.max() <= 1500.0 + 5000.0 ** 2 / (2 * 50000.0) + 30.0
    assert v.min() >= 1500.0 - 5.0 and v[v.argmax():].min() >= 1600.0 - NOISE
    assert v[-1] == pytest.approx(1600.0, abs=NOISE)


# -- the planner itself --------------------------------------------------------------------
def test_plan_position_reduction_shape_and_extrema():
    dyn = Dynamics(1000.0, 5000.0, 5000.0, 50000.0)
    plan = plan_position(StartState(0.0, 2000.0, 0.0), 5000.0, dyn)
    lo, hi = velocity_extrema(plan.seg)
    assert lo >= -1e-9 and hi == 2000.0
    # the first 0.3 s: the closed-form velocity change, ending exactly at 1000 with a = 0
    t0 = plan.seg[0].tolist()
    assert t0[:4] == pytest.approx([0.0, 0.1, 0.2, 0.3])
    p, v, a = integrate_segment(0.1, *plan.seg[1:, 2].tolist())
    assert v == pytest.approx(1000.0, abs=1e-9) and a == pytest.approx(0.0, abs=1e-9)
    assert plan.p_min == 0.0 and plan.p_max == pytest.approx(5000.0) and plan.end.p == pytest.approx(5000.0)


@pytest.mark.parametrize("v0,a0,v1", [(2000.0, 0.0, 1000.0), (1500.0, -5000.0, 1400.0), (1500.0, 5000.0, 1600.0),
                                      (0.0, 0.0, 1000.0), (1000.0, 0.0, 1000.0), (1900.0, -8000.0, 1000.0)])
def test_velocity_change_closed_form_agrees_with_ruckig(v0, a0, v1):
    """The closed form ends at ``v1`` with a = 0 within limits, as fast as ruckig's velocity interface."""
    acc, dec, jerk = 5000.0, 5000.0, 50000.0
    segs = velocity_change(v0, a0, v1, acc, dec, jerk)
    v, a, t = v0, a0, 0.0
    for dur, j in segs:
        assert dur > 0 and abs(j) in (0.0, jerk)
        _, v, a = integrate_segment(dur, 0.0, v, a, j)
        t += dur
    assert v == pytest.approx(v1, abs=1e-9) and a == pytest.approx(0.0, abs=1e-9)
    wide = max(acc, abs(a0))
    ref = plan_velocity(StartState(0.0, v0, a0), v1, Dynamics(3000.0, wide, wide, jerk))
    if abs(a0) <= acc:
        assert t == pytest.approx(ref.duration, abs=1e-9)


def test_plan_velocity_extrema_are_its_own():
    """ruckig's position_extrema of a velocity plan kept an earlier position plan's target."""
    dyn = Dynamics(1000.0, 5000.0, 5000.0, 50000.0)
    plan_position(StartState(0.0), 5000.0, dyn)
    stop = plan_velocity(StartState(10.0, 0.0, 0.0), 0.0, dyn)
    assert stop.p_min == 10.0 and stop.p_max == 10.0
    brake = plan_velocity(StartState(0.0, 2000.0, 0.0), 0.0, dyn)
    assert brake.p_min == 0.0 and brake.p_max == pytest.approx(brake.end.p) and brake.end.p > 0


def test_move_at_override_zero_not_refused_for_another_axis_target():
    """Axis 2 with AxisMaxSoftPosLimit 100 at override 0: MoveAbsolute 50 is accepted (it was refused
    0x4222: its hold plan's p_max was axis 1's target 5000, from ruckig's stale position_extrema)."""
    core = NcCore([AxisConfig(1, "A1", AxisParams(**P)),
                   AxisConfig(2, "A2", AxisParams(**P, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0))], 0.001)
    power(core, 0)
    power(core, 1, override=0)
    core.step()
    assert cmd(core, "MoveAbsolute", axis=1, Position=5000.0, Velocity=1000.0)["error"] == 0
    core.step()
    rep = cmd(core, "MoveAbsolute", axis=2, Position=50.0, Velocity=1000.0)
    assert rep["error"] == 0, rep
    power(core, 1)
    run_until(core, lambda: float(core.nctoplc[1]["SetPos"]) == 50.0 and not core.nctoplc[1]["SetVelo"])


def _sampled(plan, n=4000):
    """(times, positions, velocities) of ``plan`` sampled from 0 to its end."""
    ts = np.linspace(0.0, plan.duration, n)
    t0, p, v, a, j = plan.seg
    k = np.searchsorted(t0, ts, side="right") - 1
    tau = ts - t0[k]
    return (ts, p[k] + tau * (v[k] + tau * (a[k] / 2 + tau * j[k] / 6)),
            v[k] + tau * (a[k] + tau * j[k] / 2))


@pytest.mark.parametrize("seed", range(3))
def test_random_reductions_never_dip_and_rise(seed):
    """Random start states faster than (or carried past) a random limit, random dynamics and targets
    ahead: the plan ends at the target, its extrema bound the path, and below the floor (the limit, or
    the least dip the jerk allows) the velocity never rises again while it moves forward."""
    rng = random.Random(seed)
    checked = 0
    for _ in range(300):
        jerk = rng.choice([20000.0, 50000.0, 100000.0])
        acc, dec = rng.choice([1000.0, 5000.0, 8000.0]), rng.choice([1000.0, 5000.0, 8000.0])
        v0, a0, vl = rng.uniform(10, 3000), rng.uniform(-8000, 8000), rng.uniform(10, 3000)
        target, ve = rng.uniform(1, 5000), rng.choice([0.0, rng.uniform(0, vl)])
        if v0 + max(a0, 0.0) ** 2 / (2 * jerk) <= vl:
            continue
        plan = plan_position(StartState(0.0, v0, a0), target, Dynamics(vl, acc, dec, jerk), ve)
        assert plan.seg[0, -1] == np.inf  # the sentinel
        ts, p, v = _sampled(plan)
        assert plan.end.p == pytest.approx(target, abs=1e-6) and p[-1] == pytest.approx(target, abs=1e-6)
        tol = dec * (plan.duration / len(ts)) ** 2 + 1e-6  # a turning point between two samples
        assert plan.p_min - tol <= p.min() and p.max() <= plan.p_max + tol
        assert p.min() <= plan.p_min + tol and plan.p_max - tol <= p.max()
        if v.min() < 0:  # a full brake passing the target: past it and back, as before
            continue
        floor = min(vl, v0 - min(a0, 0.0) ** 2 / (2 * jerk))
        below = np.nonzero(v < floor - 1e-7 * vl)[0]
        if len(below):
            rest = v[below[0]:]
            assert (rest - np.minimum.accumulate(rest) <= 1e-7 * vl).all(), (v0, a0, vl, target, ve)
        checked += 1
    assert checked > 100
