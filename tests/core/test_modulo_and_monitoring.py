"""Modulo starts (TcMC manual 3.5 tables) and monitoring (lag, limits, windows, PEH)."""
import itertools
import math

import pytest

from nc_schema import ErrorCodes as E, MC_AxisStates as S, StateDWord
from nc_server.core.jobs.position import modulo_target
from znc_testing.nc_core import cmd, make_core, power, powered, run_until, state

POS, SHORT, NEG = 1, 2, 3

# (direction, start, modulo target, relative travel) from TcMC 3.5, tolerance window 1 where marked
TABLE_NO_TW = [
    (POS, 90.0, 0.0, 270.0), (POS, 90.0, 360.0, 630.0), (POS, 90.0, 720.0, 990.0),
    (NEG, 90.0, 0.0, -90.0), (NEG, 90.0, 360.0, -450.0), (NEG, 90.0, 720.0, -810.0),
    (SHORT, 90.0, 0.0, -90.0),
]
TABLE_TW1 = [
    (POS, 90.00, 90.0, 0.00), (POS, 90.90, 90.0, -0.90), (POS, 91.10, 90.0, 358.90), (POS, 89.10, 90.0, 0.90),
    (POS, 88.90, 90.0, 1.10), (POS, 90.00, 450.0, 360.00), (POS, 90.90, 450.0, 359.10), (POS, 91.10, 450.0, 718.90),
    (POS, 89.10, 450.0, 360.90), (POS, 88.90, 450.0, 361.10), (POS, 90.00, 810.0, 720.00), (POS, 90.90, 810.0, 719.10),
    (POS, 91.10, 810.0, 1078.90), (POS, 89.10, 810.0, 720.90), (POS, 88.90, 810.0, 721.10),
    (NEG, 90.00, 90.0, 0.00), (NEG, 90.90, 90.0, -0.90), (NEG, 91.10, 90.0, -1.10), (NEG, 89.10, 90.0, 0.90),
    (NEG, 88.90, 90.0, -358.90), (NEG, 90.00, 450.0, -360.00), (NEG, 90.90, 450.0, -360.90),
    (NEG, 91.10, 450.0, -361.10), (NEG, 89.10, 450.0, -359.10), (NEG, 88.90, 450.0, -718.90),
    (NEG, 90.00, 810.0, -720.00), (NEG, 90.90, 810.0, -720.90), (NEG, 91.10, 810.0, -721.10),
    (NEG, 89.10, 810.0, -719.10), (NEG, 88.90, 810.0, -1078.90),
]


@pytest.mark.parametrize("direction,start,target,travel", TABLE_NO_TW)
def test_modulo_table_without_window(direction, start, target, travel):
    assert modulo_target(start, target, 360.0, 0.0, direction) - start == pytest.approx(travel, abs=1e-9)


@pytest.mark.parametrize("direction,start,target,travel", TABLE_TW1)
def test_modulo_table_with_tolerance_window(direction, start, target, travel):
    assert modulo_target(start, target, 360.0, 1.0, direction) - start == pytest.approx(travel, abs=1e-9)


# TcMC 3.5: "The modulo tolerance window defines a position window around the current modulo set position
# of the axis ... (set position +/- tolerance value)"; "If the set position exceeds 90 deg by less than 1 deg,
# the axis is re-positioned ... In both cases, a target position of 90 deg therefore leads to minimum movement".
# The same window around a set position next to the period's end reaches into the next period.
# These rows are not the manual's: they are this NC's reading of the window rule above (3.5 gives rows
# only around 90 deg), the window taken literally as set position +/- tolerance across the boundary.
TABLE_TW1_WRAP = [
    (NEG, 359.5, 0.0, 0.5), (NEG, -0.5, 0.0, 0.5), (NEG, 359.5, 360.0, -359.5), (NEG, 359.5, 720.0, -719.5),
    (POS, 0.5, 359.8, -0.7), (POS, 360.3, 359.9, -0.4), (POS, 0.5, 719.8, 359.3),
    # outside the window: unchanged
    (NEG, 358.5 - 1e-6, 0.0, -358.5 + 1e-6), (POS, 0.5, 359.0, 358.5), (POS, 359.5, 0.0, 0.5), (NEG, 0.5, 0.0, -0.5),
]


@pytest.mark.parametrize("direction,start,target,travel", TABLE_TW1_WRAP)
def test_modulo_tolerance_window_across_the_period_boundary(direction, start, target, travel):
    assert modulo_target(start, target, 360.0, 1.0, direction) - start == pytest.approx(travel, abs=1e-9)


@pytest.mark.parametrize("period", [0.1, 3.6, 2 * math.pi, 100.1])
@pytest.mark.parametrize("tolerance", [0.0, 0.01])
@pytest.mark.parametrize("direction", [POS, NEG])
def test_modulo_target_of_k_periods_plus_a_rest_makes_k_turns(period, tolerance, direction):
    """TcMC 3.5: "Target positions of more than 360 degrees lead to one or more full turns before the
    axis travels to the required target position": Position = k * period + r makes k turns, also where
    floor(Position / period) rounds down (0.3 / 0.1 = 2.9999999999999996) -- from a set position with
    the modulo value r (then exactly k turns) and from 0; for r = 0 also the decimal a user types
    (46.8 for 13 turns of 3.6, not 13 * 3.6 = 46.800000000000004)."""
    sense = 1.0 if direction == POS else -1.0
    bad = []
    for frac in (0.0, 0.3, 0.85):
        r = frac * period
        for k in range(1, 301):
            decimal = frac == 0.0 and period == round(period, 9)  # (not 2 * pi)
            targets = {k * period + r, round(k * period, 9)} if decimal else {k * period + r}
            for target, start in itertools.product(targets, (r, r + 4 * period, r - 7 * period, 0.0)):
                travel = modulo_target(start, target, period, tolerance, direction) - start
                if start == 0.0 and frac:  # (then k turns and the way to r)
                    want = k + (frac if direction == POS else 1.0 - frac)
                else:
                    want = k
                if abs(sense * travel / period - want) > 1e-9:
                    bad.append((frac, k, start, travel / period))
    assert not bad, f"{len(bad)} wrong, e.g. (rest/period, k, start, turns): {bad[:4]}"


@pytest.mark.parametrize("direction", [POS, NEG])
@pytest.mark.parametrize("period", [360.0, 2 * math.pi, 100.1])
@pytest.mark.parametrize("k", [1, 7, 1000, 1_000_000])
def test_many_turns_from_the_target_modulo_value(direction, period, k):
    """From the target's modulo value (54.4 at 360), Position = k * period + that value makes exactly k
    turns (the rounding margin scales with the target too: 360e6 + 54.4 from 54.4 is 1e6 turns)."""
    start = 54.4 % period
    travel = modulo_target(start, k * period + start, period, 0.0, direction) - start
    assert travel / period == pytest.approx(k if direction == POS else -k, abs=1e-6)


@pytest.mark.parametrize("direction", [POS, NEG])
@pytest.mark.parametrize("modulo_start,offset", [
    (90.0, 1e-7), (90.0, 1e-10), (99_999_810.0, 1e-5), (999_999_450.0, 1e-4),
])
def test_without_a_window_slightly_past_the_target_is_a_full_turn(direction, modulo_start, offset):
    """TcMC 3.5, window 0: "if the set position ... is slightly more than 90 deg, the same travel command
    leads to a full turn" (slightly less: a minimum positioning), mirrored in the negative direction. The
    rounding margin is a few LSBs of the positions (at 1e9 some 2e-6), not a hidden backward window."""
    sense = 1.0 if direction == POS else -1.0
    past = modulo_start + sense * offset
    target = modulo_start % 360.0
    assert modulo_target(past, target, 360.0, 0.0, direction) - past == pytest.approx(sense * (360.0 - offset),
                                                                                      abs=1e-6)
    short = modulo_start - sense * offset
    assert modulo_target(short, target, 360.0, 0.0, direction) - short == pytest.approx(sense * offset, rel=0.01)


def test_move_modulo_on_a_modulo_axis_turns():
    core = powered(Modulo=True, AxisVeloMax=720.0, AxisAcc=3600.0, AxisDec=3600.0, AxisJerk=36000.0)
    assert core.nctoplc[0]["OpModeDWord"] & (1 << 7)  # OpModeModulo
    rep = cmd(core, "MoveModulo", Position=810.0, Velocity=720.0, Direction=POS)
    assert rep["error"] == 0
    run_until(core, lambda: state(core) == S.MC_AXISSTATE_STANDSTILL, 10_000)
    r = core.nctoplc[0]
    assert r["SetPos"] == pytest.approx(810.0) and r["ModuloSetPos"] == pytest.approx(90.0) and r["ModuloSetTurns"] == 2


def test_following_error():
    core = powered(SimTimeConstant=0.05, AxisMaxPosLagValue=1.0, AxisMaxPosLagFilterTime=0.01)
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)  # lag -> 100 * 0.05 = 5 > 1
    run_until(core, lambda: core.nctoplc[0]["ErrorCode"] != 0, 3000)
    r = core.nctoplc[0]
    assert r["ErrorCode"] == E.NC_POSITION_LAG and r["PosDiff"] > 1.0
    assert state(core) == S.MC_AXISSTATE_ERRORSTOP


def test_no_following_error_when_monitoring_disabled():
    core = powered(SimTimeConstant=0.05, AxisMaxPosLagValue=1.0, AxisEnPositionLagMonitoring=False)
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    for _ in range(1000):
        core.step()
    assert core.nctoplc[0]["ErrorCode"] == 0 and core.nctoplc[0]["PosDiff"] > 1.0


def test_continuous_motion_stops_at_soft_limit_then_error():
    core = powered(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0)
    cmd(core, "MoveVelocity", Velocity=800.0, Direction=1)
    run_until(core, lambda: core.nctoplc[0]["ErrorCode"] != 0, 5000)
    r = core.nctoplc[0]
    assert r["ErrorCode"] == E.NC_SOFT_LIMIT_MAX_POSITIONING
    assert r["SetPos"] == pytest.approx(100.0) and r["SetVelo"] == 0.0
    for _ in range(200):  # let the drive settle: after Reset, SetPos := ActPos
        core.step()
        assert core.nctoplc[0]["ActPos"] <= 100.0 + 1e-9
    cmd(core, "Reset")
    core.step()
    assert cmd(core, "MoveVelocity", Velocity=10.0, Direction=1)["error"] == E.NC_SOFT_LIMIT_MAX_START
    assert cmd(core, "MoveVelocity", Velocity=10.0, Direction=3)["error"] == 0


def test_target_window_and_position_area_timing():
    core = make_core(SimTimeConstant=0.01, AxisTargetPositionWindow=0.01, AxisTargetPositionMonitoringTime=0.05,
                     AxisPositionRangeWindow=1.0)
    power(core)
    core.step()
    cmd(core, "MoveAbsolute", Position=10.0, Velocity=100.0)
    run_until(core, lambda: not core.nctoplc[0]["StateDWord"] & StateDWord.HasJob)
    sd = core.nctoplc[0]["StateDWord"]
    assert sd & StateDWord.InPositionArea and not sd & StateDWord.InTargetPosition  # still lagging
    n = run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.InTargetPosition)
    assert n >= 50  # window reached, then held for the monitoring time


def test_peh_timeout():
    core = make_core(SimTimeConstant=0.5, AxisEnInTargetTimeout=True, AxisInTargetTimeout=0.1,
                     AxisTargetPositionWindow=0.001, AxisEnPositionLagMonitoring=False)
    power(core)
    core.step()
    cmd(core, "MoveAbsolute", Position=10.0, Velocity=100.0)
    run_until(core, lambda: core.nctoplc[0]["ErrorCode"] != 0, 3000)
    assert core.nctoplc[0]["ErrorCode"] == E.NC_AXIS_PEH_TIMEOUT
