"""The dynamics of stopping: an MC_Stop or a fault ramp never speeds an accelerating axis up, a Stop with a
lone deceleration still stops, a fault ramp at AxisVeloMax keeps the axis jerk; and the dynamics a
move may ask for: too weak ones are refused (changing nothing), SetOverride scales the velocity.
"""
import pytest

from nc_schema import CmdState, ErrorCodes as E, StateDWord
from znc_testing.nc_core import cmd, powered, run_until

CT = 0.001


def accelerating_axis():
    """An axis 8 ms into a MoveVelocity(100) with a very stiff profile: v ~32, a ~8000."""
    core = powered()
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=1, Acceleration=20000.0, Jerk=1e6)["error"] == 0
    for _ in range(8):
        core.step()
    assert core.nctoplc[0]["SetAcc"] > 5000
    return core


def peak_until_standstill(core, max_cycles=20_000):
    peak = [0.0]

    def standstill():
        peak[0] = max(peak[0], abs(float(core.nctoplc[0]["SetVelo"])))
        return core.nctoplc[0]["SetVelo"] == 0.0 and not core.axes.traj_on[0]

    run_until(core, standstill, max_cycles)
    return peak[0]


@pytest.mark.parametrize("stop", [dict(), dict(Deceleration=500.0, Jerk=5000.0)])
def test_stop_of_an_accelerating_axis_never_speeds_it_up(stop):
    core = accelerating_axis()
    assert cmd(core, "Stop", **stop)["error"] == 0
    assert peak_until_standstill(core) <= 100.0 + 1e-6  # the running command's velocity


def test_fault_ramp_of_an_accelerating_axis_never_speeds_it_up():
    core = accelerating_axis()
    core.fault(0, E.NC_AXIS_FEED_ENABLE_PLUS)
    assert peak_until_standstill(core) <= 100.0 + 1e-6


def test_move_with_too_weak_dynamics_is_refused_and_changes_nothing():
    core = accelerating_axis()
    rep = cmd(core, "MoveVelocity", Velocity=300.0, Direction=1, Jerk=5000.0)
    assert rep["error"] == E.NC_VELOCITY_OVERFLOW and "Jerk" in rep["text"]
    rep = cmd(core, "MoveAbsolute", Position=500.0, Velocity=300.0, Jerk=5000.0)
    assert rep["error"] == E.NC_VELOCITY_OVERFLOW
    run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.ConstantVelocity)
    assert core.nctoplc[0]["SetVelo"] == pytest.approx(100.0) and core.nctoplc[0]["CmdNo"] == 1


def test_set_override_command_takes_effect():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)
    assert cmd(core, "SetOverride", Override=10.0)["error"] == 0
    run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.ConstantVelocity)
    assert core.nctoplc[0]["SetVelo"] == pytest.approx(50.0)


def test_stop_with_a_lone_deceleration_still_stops():
    """A lone Deceleration is used with the stopped job's jerk (issue 17's decision; before: ignored)."""
    core = powered()
    cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)
    for _ in range(200):
        core.step()
    rep = cmd(core, "Stop", Deceleration=100.0)
    assert rep["error"] == 0
    run_until(core, lambda: core.nctoplc[0]["CmdState"] == CmdState.DONE, 7000)  # 500 u/s at 100 u/s^2: ~5 s
    assert core.nctoplc[0]["SetVelo"] == 0.0


@pytest.mark.parametrize("k", [2198, 2199, 2200])
def test_a_fault_ramp_at_axis_velo_max_keeps_the_axis_jerk(k: int) -> None:
    """Fourth review: an ordinary axis reaching AxisVeloMax with a rounding residue of acceleration
    got a whole fault ramp at 4 x AxisJerk (the jerk raise is only for an overshoot beyond rounding)."""
    core = powered(1, AxisVeloMax=1000.0, AxisAcc=1000.0, AxisDec=1000.0, AxisJerk=5000.0)
    assert not cmd(core, "MoveAbsolute", Position=1e5, Velocity=1000.0, Acceleration=500.0, Deceleration=1000.0,
                   Jerk=2500.0)["error"]
    for _ in range(k + 1):
        core.step()
    core.fault(0, E.NC_POSITION_LAG)
    prev, worst = float(core.axes.set_acc[0]), 0.0
    for _ in range(3000):
        core.step()
        acc = float(core.axes.set_acc[0])
        worst = max(worst, abs(acc - prev) / CT)
        prev = acc
    assert worst <= 5000.0 * (1 + 1e-6)
    assert float(core.axes.set_velo[0]) == 0.0
