"""Regressions found by review: each test failed before its fix."""
import pytest

from nc_schema import CmdState, ControlDWord, ErrorCodes as E, MC_AxisStates as S, StateDWord
from znc_testing.nc_core import cmd, power, powered, run_until, state


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


def test_enable_off_after_fault_and_stop_disables():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)
    for _ in range(100):
        core.step()
    core.fault(0, E.ZNC_CLIENT_LOST)     # watchdog: fault ...
    power(core, ctrl=0)                   # ... and enables off
    assert cmd(core, "Stop")["error"] == 0  # another client stops it during the fault ramp
    run_until(core, lambda: not core.axes.traj_on[0], 5000)
    core.step()
    assert not core.nctoplc[0]["StateDWord"] & StateDWord.ControlLoopClosed
    power(core)
    for _ in range(50):  # after the ramp, reset, move; then enable off must disable at once
        core.step()
    assert cmd(core, "Reset")["error"] == 0
    core.step()
    assert cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)["error"] == 0
    for _ in range(50):
        core.step()
    power(core, ctrl=int(ControlDWord.FeedEnablePlus | ControlDWord.FeedEnableMinus))  # Enable off only
    core.step()
    assert state(core) == S.MC_AXISSTATE_DISABLED and core.nctoplc[0]["SetVelo"] == 0.0


def test_reset_during_a_fault_ramp_keeps_stopping_until_standstill():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=800.0, Direction=1)
    run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.ConstantVelocity)
    core.fault(0, E.NC_AXIS_FEED_ENABLE_PLUS)
    core.step()
    rep = cmd(core, "Reset")
    assert rep["error"] == 0
    core.step()
    r = core.nctoplc[0]
    assert r["ErrorCode"] == 0 and r["CmdNo"] == 2 and r["CmdState"] == CmdState.ACTIVE
    assert state(core) == S.MC_AXISSTATE_STOPPING  # never StandStill while still braking
    v_prev = abs(float(r["SetVelo"]))
    while core.axes.traj_on[0]:
        core.step()
        v = abs(float(core.nctoplc[0]["SetVelo"]))
        assert v <= v_prev + 1e-9  # the ramp goes on, it does not speed up
        assert core.axes.traj_on[0] or state(core) == S.MC_AXISSTATE_STANDSTILL
        v_prev = v
    assert core.nctoplc[0]["CmdState"] == CmdState.DONE and state(core) == S.MC_AXISSTATE_STANDSTILL


def test_enable_off_during_stop_releases_the_lock():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=300.0, Direction=1)
    for _ in range(100):
        core.step()
    cmd(core, "Stop")
    core.step()
    power(core, ctrl=0)
    core.step()
    assert state(core) == S.MC_AXISSTATE_DISABLED
    power(core)
    core.step()
    assert state(core) == S.MC_AXISSTATE_STANDSTILL
    assert cmd(core, "MoveRelative", Distance=1.0, Velocity=10.0)["error"] == 0


def test_set_override_command_takes_effect():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)
    assert cmd(core, "SetOverride", Override=10.0)["error"] == 0
    run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.ConstantVelocity)
    assert core.nctoplc[0]["SetVelo"] == pytest.approx(50.0)


def test_stop_with_a_lone_deceleration_still_stops():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)
    for _ in range(200):
        core.step()
    rep = cmd(core, "Stop", Deceleration=100.0)
    assert rep["error"] == 0
    run_until(core, lambda: core.nctoplc[0]["CmdState"] == CmdState.DONE, 2000)  # axis defaults: fast
    assert core.nctoplc[0]["SetVelo"] == 0.0
