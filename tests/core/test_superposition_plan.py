"""plan_superposition: the time window of each E_SuperpositionMode, the profile it plans, incomplete corrections.

The numbers are those of the application examples of TcMC section 3.11 (MC_MoveSuperImposedExt);
the process velocities and axis dynamics are not given there and are chosen here:

* conveyor gap: belt 500 mm/s, acc = dec = 5000 mm/s^2, jerk 50000 mm/s^3 (at 1000 mm/s the
  correction of 300 mm at +500 mm/s would not fit in the 1000 mm of belt: 0.8 s > 0.7 s);
* print roller: 100 deg/s peripheral, 1000 deg/s^2, 10000 deg/s^3;
* drilling unit: workpiece 200 mm/s, 5000 mm/s^2, 50000 mm/s^3.
"""
import math

import numpy as np
import pytest

from nc_server.core.planning import Dynamics, StartState, plan_position, position_at
from nc_server.core.profile import N_SEGMENTS, evaluate
from nc_server.core.superposition import (MODE_LENGTH_ADDITIVE, MODE_LENGTH_LIMITED, MODE_VELO_ADDITIVE,
                                          MODE_VELO_LIMITED, SuperPlan, plan_superposition)

REL = 1e-9


def sample(plan, n=4001):
    """(t, p, v, a, j) of ``plan`` from 0 to past its end, densely."""
    t = np.linspace(0.0, plan.duration * 1.05 + 1e-3, n)
    seg = np.repeat(plan.seg[:, None, :], n, axis=1)
    return (t, *evaluate(seg, t, None))


def check(sp: SuperPlan, start, acc, dec, jerk, vdiff):
    """What every superposition plan must satisfy; returns the samples."""
    plan = sp.plan
    assert plan.seg.shape == (5, N_SEGMENTS)
    p0, v0, a0 = position_at(plan, 0.0)
    assert (p0, v0, a0) == pytest.approx((start.p, start.v, start.a), abs=1e-12)  # continuous
    goal = start.p + sp.distance
    assert plan.end.p == pytest.approx(goal, rel=REL, abs=1e-9) and plan.end.v == 0 and plan.end.a == 0
    t, p, v, a, j = sample(plan)
    after = t >= plan.duration
    assert np.allclose(p[after], goal, rtol=REL, atol=1e-9) and np.all(v[after] == 0) and np.all(a[after] == 0)
    assert np.all(np.abs(a) <= max(acc, dec) * (1 + REL))
    assert np.all(np.abs(j) <= jerk * (1 + REL))
    if abs(start.v) <= vdiff:
        assert np.all(np.abs(v) <= vdiff * (1 + REL))
    # ActualVelocityDiff is the profile's peak |v| (not the requested VelocityDiff)
    assert np.max(np.abs(v)) <= sp.velocity_diff * (1 + REL)
    assert np.max(np.abs(v)) == pytest.approx(sp.velocity_diff, rel=1e-3)
    if sp.window > 0:  # 0: nothing fitted (a running superposition stopped)
        assert plan.duration <= sp.window * (1 + REL)
    assert plan.p_min == pytest.approx(min(p), abs=1e-9) and plan.p_max == pytest.approx(max(p), abs=1e-9)
    return t, p, v, a, j


def fastest_duration(d, vdiff, acc, dec, jerk, start=StartState(0.0)):
    return plan_position(start, start.p + d, Dynamics(vdiff, acc, dec, jerk)).duration


# --- conveyor gap: Distance 300, Length 1000, VELOREDUCTION_LIMITEDMOTION, VelocityDiff 500

def test_conveyor_gap_uses_the_whole_belt():
    v = 500.0
    sp = plan_superposition(MODE_VELO_LIMITED, 300.0, 500.0, 5000.0, 5000.0, 50000.0, v, 1000.0)
    check(sp, StartState(0.0), 5000.0, 5000.0, 50000.0, 500.0)
    T = (1000.0 - 300.0) / v
    assert sp.distance == 300.0 and not sp.incomplete
    assert sp.window == pytest.approx(T, rel=1e-12)
    assert sp.plan.duration == pytest.approx(T, rel=1e-9)
    assert v * sp.plan.duration + sp.plan.end.p == pytest.approx(1000.0, rel=1e-9)  # axis travel = Length
    assert sp.length == pytest.approx(1000.0, rel=1e-9)
    # reduced: the fastest profile (0.8 s) would need the full 500; the window asks for less
    assert sp.velocity_diff < 0.5 * 500.0


def test_conveyor_gap_belt2_slowed_never_reverses():
    """Belt 2 slowed: Distance -300, VelocityDiff = the set velocity; the belt decelerates, never reverses."""
    v = 500.0
    sp = plan_superposition(MODE_VELO_LIMITED, -300.0, v, 5000.0, 5000.0, 50000.0, v, 1000.0)
    _, _, vs, _, _ = check(sp, StartState(0.0), 5000.0, 5000.0, 50000.0, v)
    T = (1000.0 + 300.0) / v  # the belt's own travel over the correction is Length
    assert sp.distance == -300.0 and not sp.incomplete
    assert sp.plan.duration == pytest.approx(T, rel=1e-9)
    assert sp.length == pytest.approx(1000.0, rel=1e-9)
    assert np.all(vs <= 1e-12)  # one way: slowed only
    assert np.all(v + vs >= 0.0)
    assert np.min(v + vs) > 0.5 * v  # and well above standstill with this window


# --- print roller: Distance 7.1 deg, Length 360 deg, VelocityDiff 30 deg/s

ROLLER = dict(velocity_diff=30.0, dyn_acc=1000.0, dyn_dec=1000.0, jerk=10000.0, v_process=100.0, length=360.0)


def test_print_roller_fast_correction():
    fast = plan_superposition(MODE_LENGTH_LIMITED, 7.1, **ROLLER)
    check(fast, StartState(0.0), 1000.0, 1000.0, 10000.0, 30.0)
    # time-optimal: 30 deg/s is reached (a^2/j = 100 > 30: triangular acceleration ramps)
    t_opt = 7.1 / 30.0 + 2.0 * math.sqrt(30.0 / 10000.0)
    assert fast.plan.duration == pytest.approx(t_opt, rel=1e-9)
    assert fast.velocity_diff == pytest.approx(30.0, rel=1e-9)
    assert fast.window == pytest.approx((360.0 - 7.1) / 100.0)
    assert fast.plan.duration < 0.15 * fast.window and not fast.incomplete
    assert fast.length == pytest.approx(100.0 * t_opt + 7.1, rel=1e-9)  # the roller's own travel
    # LENGTHREDUCTION_ADDITIVE: the same profile (the window is not used up either way)
    add = plan_superposition(MODE_LENGTH_ADDITIVE, 7.1, **ROLLER)
    assert np.array_equal(add.plan.seg, fast.plan.seg)
    assert add.window == pytest.approx(3.6) and add.length == pytest.approx(100.0 * t_opt, rel=1e-9)


def test_print_roller_slow_correction():
    slow = plan_superposition(MODE_VELO_LIMITED, 7.1, **ROLLER)
    check(slow, StartState(0.0), 1000.0, 1000.0, 10000.0, 30.0)
    T = (360.0 - 7.1) / 100.0
    assert slow.plan.duration == pytest.approx(T, rel=1e-9) and not slow.incomplete
    assert slow.length == pytest.approx(360.0, rel=1e-9)
    assert slow.velocity_diff < 0.1 * 30.0
    # as low as the window allows: cruise v with jerk-limited ramps of 2*sqrt(v/j) each
    vc = slow.velocity_diff
    assert vc * (T - 2.0 * math.sqrt(vc / 10000.0)) == pytest.approx(7.1, rel=1e-6)


# --- drilling unit: Distance 250, Length 400, VelocityDiff 500

DRILL = dict(velocity_diff=500.0, dyn_acc=5000.0, dyn_dec=5000.0, jerk=50000.0, v_process=200.0, length=400.0)


def test_drilling_unit_fast():
    sp = plan_superposition(MODE_LENGTH_ADDITIVE, 250.0, **DRILL)
    check(sp, StartState(0.0), 5000.0, 5000.0, 50000.0, 500.0)
    assert sp.plan.duration == pytest.approx(250.0 / 500.0 + 0.2, rel=1e-9)  # a^2/j = 500 = VelocityDiff
    assert sp.velocity_diff == pytest.approx(500.0, rel=1e-9)
    assert sp.window == pytest.approx(2.0) and not sp.incomplete
    assert sp.length == pytest.approx(200.0 * 0.7, rel=1e-9)  # the workpiece's travel meanwhile


def test_drilling_unit_slow_travels_length_plus_distance():
    sp = plan_superposition(MODE_VELO_ADDITIVE, 250.0, **DRILL)
    check(sp, StartState(0.0), 5000.0, 5000.0, 50000.0, 500.0)
    T = 400.0 / 200.0
    assert sp.plan.duration == pytest.approx(T, rel=1e-9) and not sp.incomplete
    assert sp.length == pytest.approx(400.0, rel=1e-9)
    unit = 200.0 * T + position_at(sp.plan, T)[0]
    assert unit == pytest.approx(650.0, rel=1e-9)  # Length + Distance
    assert sp.velocity_diff < 0.3 * 500.0


def test_asymmetric_acc_dec_respected_in_the_direction_of_the_offset():
    for d in (250.0, -250.0):
        sp = plan_superposition(MODE_LENGTH_ADDITIVE, d, 500.0, 5000.0, 2000.0, 50000.0, 200.0, 400.0)
        _, _, v, a, _ = check(sp, StartState(0.0), 5000.0, 2000.0, 50000.0, 500.0)
        a_along = a * math.copysign(1.0, d)
        assert np.max(a_along) <= 5000.0 * (1 + REL) and np.min(a_along) >= -2000.0 * (1 + REL)
        seg_a = sp.plan.seg[3] * math.copysign(1.0, d)  # the extremes lie on segment boundaries here
        assert np.max(seg_a) == pytest.approx(5000.0, rel=1e-9) and np.min(seg_a) == pytest.approx(-2000.0, rel=1e-9)
        assert np.all(v * d >= 0)


# --- incomplete

@pytest.mark.parametrize("mode", [MODE_VELO_ADDITIVE, MODE_VELO_LIMITED, MODE_LENGTH_ADDITIVE, MODE_LENGTH_LIMITED])
def test_incomplete_applies_the_largest_distance_that_fits(mode):
    """VelocityDiff 10, process 100 u/s, Length 100 (ADDITIVE: a 1 s window), Distance 100: ~10 fit."""
    dyn = (10.0, 5000.0, 5000.0, 50000.0)
    sp = plan_superposition(mode, 100.0, *dyn, 100.0, 100.0)
    check(sp, StartState(0.0), 5000.0, 5000.0, 50000.0, 10.0)
    assert sp.incomplete and 0.0 < sp.distance < 100.0
    limited = mode in (MODE_VELO_LIMITED, MODE_LENGTH_LIMITED)

    def window(d):
        return (100.0 - d) / 100.0 if limited else 1.0

    assert sp.window == pytest.approx(window(sp.distance), rel=1e-12)
    assert fastest_duration(sp.distance, *dyn) <= window(sp.distance)
    bigger = sp.distance * (1 + 1e-8)
    assert fastest_duration(bigger, *dyn) > window(bigger)  # maximal
    assert sp.plan.duration == pytest.approx(window(sp.distance), rel=1e-6)  # both families fill the window
    if not limited:  # closed form: cruise at 10 with triangular ramps of 2*sqrt(10/j)
        assert sp.distance == pytest.approx(10.0 * (1.0 - 2.0 * math.sqrt(10.0 / 50000.0)), rel=1e-9)
        assert sp.length == pytest.approx(100.0, rel=1e-6)
    else:  # the axis's own travel is Length
        assert sp.length == pytest.approx(100.0, rel=1e-6)
    # negative distance / negative process velocity: mirrored
    neg = plan_superposition(mode, -100.0, *dyn, -100.0, 100.0)
    assert neg.incomplete and neg.distance == pytest.approx(-sp.distance, rel=1e-9)


def test_limited_distance_beyond_length_does_not_raise():
    """LIMITED with Distance > Length (T = (Length - Distance)/v < 0): the most that fits, incomplete."""
    sp = plan_superposition(MODE_VELO_LIMITED, 500.0, **DRILL)
    check(sp, StartState(0.0), 5000.0, 5000.0, 50000.0, 500.0)
    assert sp.incomplete and 0.0 < sp.distance < 400.0
    assert 200.0 * sp.plan.duration + sp.distance == pytest.approx(400.0, rel=1e-6)
    assert sp.length == pytest.approx(400.0, rel=1e-6) and sp.window > 0
    # against the direction of travel the same Distance shrinks the axis's travel and fits
    back = plan_superposition(MODE_VELO_LIMITED, -500.0, **DRILL)
    assert not back.incomplete and back.window == pytest.approx(900.0 / 200.0)


def test_a_standing_axis_gets_the_window_of_velocity_process():
    """Issue 17: VelocityProcess is never 0 (TcMC: |value| > 0), so there is always a finite window; on a
    standing axis (``standing``) it is |Length| / |VelocityProcess| in every mode: the LENGTHREDUCTION modes
    fit the fastest move into it, the VELOREDUCTION modes stretch the move over all of it. LIMITEDMOTION's
    ActualLength is the axis's own travel, |Distance|."""
    for mode in (MODE_VELO_ADDITIVE, MODE_VELO_LIMITED, MODE_LENGTH_ADDITIVE, MODE_LENGTH_LIMITED):
        sp = plan_superposition(mode, -300.0, 500.0, 5000.0, 5000.0, 50000.0, 100.0, 1000.0, standing=True)
        check(sp, StartState(0.0), 5000.0, 5000.0, 50000.0, 500.0)
        assert sp.window == pytest.approx(10.0, rel=1e-12) and not sp.incomplete and sp.distance == -300.0
        velo = mode in (MODE_VELO_ADDITIVE, MODE_VELO_LIMITED)
        want = 10.0 if velo else 300.0 / 500.0 + 0.2
        assert sp.plan.duration == pytest.approx(want, rel=1e-9)
        limited = mode in (MODE_VELO_LIMITED, MODE_LENGTH_LIMITED)
        assert sp.length == pytest.approx(300.0 if limited else 100.0 * want, rel=1e-9)


def test_the_window_is_not_left_in_the_shared_planner():
    plan_superposition(MODE_VELO_ADDITIVE, 250.0, **DRILL)  # planned with minimum_duration = 2 s
    assert fastest_duration(250.0, 500.0, 5000.0, 5000.0, 50000.0) == pytest.approx(0.7, rel=1e-9)


# --- re-trigger from a running superposition

@pytest.mark.parametrize("mode", [MODE_VELO_ADDITIVE, MODE_LENGTH_ADDITIVE, MODE_VELO_LIMITED])
def test_retrigger_from_a_moving_state(mode):
    first = plan_superposition(MODE_LENGTH_ADDITIVE, 250.0, **DRILL)
    st = StartState(*position_at(first.plan, 0.27))  # mid-acceleration/cruise: v and a != 0
    assert st.v > 100 and st.p > 0
    sp = plan_superposition(mode, 100.0, **{**DRILL, "length": 600.0}, start=st)
    check(sp, st, 5000.0, 5000.0, 50000.0, 500.0)
    assert sp.distance == 100.0 and not sp.incomplete
    if mode == MODE_VELO_ADDITIVE:
        assert sp.plan.duration == pytest.approx(600.0 / 200.0, rel=1e-9)  # the window starts now
    if mode == MODE_VELO_LIMITED:
        assert sp.length == pytest.approx(600.0, rel=1e-9)


def test_retrigger_incomplete_from_a_moving_state():
    """Offset moving at +400: a bracket from where its fastest stop ends (0 offset needs stop-and-return)."""
    st = StartState(3.0, 400.0, 0.0)
    dyn = (500.0, 5000.0, 5000.0, 50000.0)
    sp = plan_superposition(MODE_LENGTH_LIMITED, 100.0, *dyn, 1000.0, 300.0, start=st)
    check(sp, st, 5000.0, 5000.0, 50000.0, 500.0)
    assert sp.incomplete and 0.0 < sp.distance < 100.0
    assert 1000.0 * sp.plan.duration + sp.distance == pytest.approx(300.0, rel=1e-6)
    # nothing fits at all (the stop alone takes longer than the window): the fastest stop
    stop = plan_superposition(MODE_VELO_LIMITED, -1.0, *dyn, 1000.0, 1.0, start=st)
    check(stop, st, 5000.0, 5000.0, 50000.0, 500.0)
    assert stop.incomplete and stop.distance > 0 and stop.window == 0.0
    assert stop.plan.duration == pytest.approx(2 * math.sqrt(400.0 / 50000.0), rel=1e-9)


# --- invalid input

@pytest.mark.parametrize("kw", [
    {"mode": 0}, {"mode": 5}, {"distance": 0.0}, {"distance": math.inf}, {"distance": math.nan},
    {"velocity_diff": 0.0}, {"velocity_diff": math.nan}, {"length": 0.0}, {"length": math.inf},
    {"dyn_acc": 0.0}, {"dyn_dec": -1.0}, {"jerk": 0.0}, {"jerk": math.nan}, {"v_process": math.inf},
    {"v_process": 0.0}, {"v_process": math.nan},
])
def test_invalid_input_raises_value_error(kw):
    args = dict(mode=MODE_VELO_LIMITED, distance=300.0, velocity_diff=500.0, dyn_acc=5000.0, dyn_dec=5000.0,
                jerk=50000.0, v_process=500.0, length=1000.0)
    with pytest.raises(ValueError):
        plan_superposition(**{**args, **kw})


def test_signs_of_velocity_diff_and_length_are_ignored():
    a = plan_superposition(MODE_VELO_LIMITED, 300.0, 500.0, 5000.0, 5000.0, 50000.0, 500.0, 1000.0)
    b = plan_superposition(MODE_VELO_LIMITED, 300.0, -500.0, 5000.0, 5000.0, 50000.0, 500.0, -1000.0)
    assert np.array_equal(a.plan.seg, b.plan.seg) and a.length == b.length
