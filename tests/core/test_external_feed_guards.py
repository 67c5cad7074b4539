"""External set-point feeds (ExtSetPointGenEnable) that the NC must guard against: enabling does not jump to a
stale feed, feeds that jump or accelerate too hard (or a velocity step) are axis errors, while feeds at
the axis acceleration, a pause of the feeds, a generator stopping exactly at the limit and a feed
arriving a cycle late are no fault.
"""
from __future__ import annotations

import pytest

from nc_schema import ErrorCodes as E
from nc_server.core import NcCore
from znc_testing.nc_core import cmd, powered

CT = 0.001


def _feed(core: NcCore, p: float, v: float = 0.0, acc: float = 0.0) -> None:
    rec = core.plctonc[0].copy()
    rec["ExtSetPos"], rec["ExtSetVelo"], rec["ExtSetAcc"] = p, v, acc
    core.set_plctonc(0, rec)


def test_external_enable_does_not_jump_to_a_stale_feed() -> None:
    core = powered(1)
    _feed(core, 1.4)  # stale: 1.4 u from the set position (less than 1.5 cycles at AxisVeloMax)
    core.step()
    assert not cmd(core, "ExtSetPointGenEnable")["error"]
    for _ in range(5):
        core.step()
        assert float(core.nctoplc[0]["SetPos"]) == 0.0 and int(core.nctoplc[0]["ErrorCode"]) == 0


def test_external_feeds_that_jump_or_accelerate_too_hard_are_axis_errors() -> None:
    core = powered(1)
    _feed(core, 0.0)
    assert not cmd(core, "ExtSetPointGenEnable")["error"]
    core.step()
    _feed(core, 1.4)  # a jump with velocity 0, within 1.5 cycles at AxisVeloMax
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_AXIS_SET_VELOCITY
    core = powered(1)
    _feed(core, 0.0)
    assert not cmd(core, "ExtSetPointGenEnable")["error"]
    core.step()
    _feed(core, 0.0, 0.0, 1e9)
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_ACCELERATION_NOT_ALLOWED
    assert abs(float(core.nctoplc[0]["SetAcc"])) <= 5000.0


@pytest.mark.parametrize("acc,vmax,ratio", [(5000.0, 1000.0, 10), (20000.0, 1000.0, 4), (50000.0, 1000.0, 10),
                                            (1000.0, 10.0, 10), (200000.0, 500.0, 10)])
def test_external_feeds_without_acceleration_at_the_axis_acceleration_are_no_fault(acc: float, vmax: float,
                                                                                   ratio: int) -> None:
    """A PLC generator that feeds position and velocity only (ExtSetAcc 0), once per PLC cycle, ramping
    at AxisAcc: the feeds' extrapolation errors (a T^2 / 2, a T) stay inside what AxisAcc allows."""
    core = powered(1, AxisAcc=acc, AxisDec=acc, AxisVeloMax=vmax, AxisJerk=1e9)
    _feed(core, 0.0)
    assert not cmd(core, "ExtSetPointGenEnable")["error"]
    t_ramp = vmax / acc
    for k in range(1, 400):
        if k % ratio == 0:
            t = k * CT
            v = acc * t if t < t_ramp else vmax
            p = 0.5 * acc * t * t if t < t_ramp else 0.5 * acc * t_ramp ** 2 + vmax * (t - t_ramp)
            _feed(core, p, v)
        core.step()
        assert int(core.nctoplc[0]["ErrorCode"]) == 0, (k, float(core.nctoplc[0]["SetVelo"]))
    assert t_ramp < 390 * CT and float(core.nctoplc[0]["SetVelo"]) == pytest.approx(vmax, rel=1e-9)


def test_an_external_velocity_step_is_an_axis_error() -> None:
    core = powered(1)
    _feed(core, 0.0)
    assert not cmd(core, "ExtSetPointGenEnable")["error"]
    core.step()
    _feed(core, 0.0, 999.0)  # from standstill to 999 u/s in one cycle
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_AXIS_SET_VELOCITY
    assert abs(float(core.nctoplc[0]["SetVelo"])) < 1e-9


# -- third review --------------------------------------------------------------------------------------
def test_a_pause_of_the_feeds_earns_no_jump() -> None:
    """The feed interval is measured from PLCTONC frames (also ones repeating a standing feed) and
    capped at 50 ms: after 200 ms without frames a velocity step of 1000 u/s is still a jump."""
    core = powered(1)
    _feed(core, 0.0)
    assert not cmd(core, "ExtSetPointGenEnable")["error"]
    for _ in range(200):
        core.step()  # (no frames)
    _feed(core, 20.0, 1000.0)
    core.step()
    assert int(core.nctoplc[0]["ErrorCode"]) == E.NC_AXIS_SET_VELOCITY
    assert float(core.nctoplc[0]["SetPos"]) < 1.0


@pytest.mark.parametrize("ratio,feed_acc", [(2, True), (2, False), (10, True), (10, False)])
def test_an_external_generator_stopping_exactly_at_the_limit_is_no_fault(ratio: int, feed_acc: bool) -> None:
    from nc_server.core.planning import Dynamics, StartState, plan_position, position_at
    core = powered(1, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0)
    assert not cmd(core, "ExtSetPointGenEnable")["error"]
    plan = plan_position(StartState(0.0), 100.0, Dynamics(1000.0, 5000.0, 5000.0, 25000.0))
    for n in range(int(plan.duration / CT) + 10 * ratio + 5):
        if n % ratio == 0:
            p, v, a = position_at(plan, n * CT)
            _feed(core, p, v, a if feed_acc else 0.0)
        core.step()
        assert int(core.nctoplc[0]["ErrorCode"]) == 0, n
    assert float(core.nctoplc[0]["SetPos"]) == pytest.approx(100.0, abs=1e-9)


def test_a_feed_arriving_a_cycle_late_is_no_fault() -> None:
    core = powered(1, AxisAcc=1e6, AxisDec=1e6)
    _feed(core, 0.0)
    assert not cmd(core, "ExtSetPointGenEnable")["error"]
    late = False
    for k in range(1, 300):
        t = k * CT
        if k == 150:
            late = True  # from here every feed arrives one cycle after its time
        _feed(core, 50.0 * (t - (CT if late else 0.0)), 50.0)
        core.step()
        assert int(core.nctoplc[0]["ErrorCode"]) == 0, k
