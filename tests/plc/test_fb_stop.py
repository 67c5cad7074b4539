"""MC_Stop: the lock (PLCopen exception to the output rules) against a real NcCore."""
from __future__ import annotations

from nc_schema import ErrorCodes
from plc_client import MC_MoveAbsolute, MC_MoveVelocity, MC_Stop
from znc_testing.plc_rig import Rig, powered


def test_stop_locks_until_execute_falls(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, stop, mv2 = rig.watch(MC_MoveVelocity(), MC_Stop(), MC_MoveAbsolute())
    st = {"stop": False, "mv2": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=50.0)
        stop(Axis=ax, Execute=st["stop"])
        mv2(Axis=ax, Execute=st["mv2"], Position=0.0, Velocity=50.0)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 50)
    st["stop"] = True
    rig.run(2)
    assert stop.Busy and stop.Active and not stop.Done
    assert ax.Status.Stopping and ax.Status.MotionCommandsLocked
    rig.run_until(lambda: stop.Done, 100)
    assert stop.Busy and stop.Active, "MC_Stop keeps Busy/Active while Execute is TRUE (axis locked)"
    assert ax.Status.NotMoving and ax.Status.Stopping
    rig.run(20)
    assert all(o["Done"] and o["Busy"] for o in rig.outputs(stop)[-20:])
    # any other motion command is refused while locked
    st["mv2"] = True
    rig.run_until(lambda: not mv2.Busy, 5)
    assert mv2.Error and mv2.ErrorID == ErrorCodes.NC_AXIS_LOCKED_BY_STOP == 0x42EF
    # Execute falls: outputs reset at once, the lock is released
    st["stop"], st["mv2"] = False, False
    rig.run(1)
    assert not any((stop.Done, stop.Busy, stop.Active, stop.Error))
    rig.run(1)
    assert not ax.Status.MotionCommandsLocked and ax.Status.StandStill
    st["mv2"] = True
    rig.run_until(lambda: mv2.Done, 300)
    assert abs(ax.ActPos) < 0.02


def test_stop_execute_falls_during_the_ramp(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, stop = rig.watch(MC_MoveVelocity(), MC_Stop())
    st = {"stop": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=200.0, Deceleration=200.0)
        stop(Axis=ax, Execute=st["stop"], Deceleration=200.0, Jerk=2000.0)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 200)
    st["stop"] = True
    rig.run(2)
    st["stop"] = False
    rig.run(1)
    assert stop.Busy and ax.Status.Stopping  # the stop goes on
    rig.run(200)
    dones = [o["Done"] for o in rig.outputs(stop)]
    assert dones.count(True) == 1
    i = dones.index(True)
    assert not rig.outputs(stop)[i]["Busy"], "Execute already fell: Done for one cycle, not locked"
    assert not ax.Status.MotionCommandsLocked and ax.Status.StandStill


def test_stop_at_standstill_and_second_stop(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    s1, s2 = rig.watch(MC_Stop(), MC_Stop())
    st = {"s2": False}

    def body(p):
        s1(Axis=ax, Execute=True)
        s2(Axis=ax, Execute=st["s2"])

    calls["body"] = body
    rig.run_until(lambda: s1.Done, 5)
    assert s1.Busy and ax.Status.MotionCommandsLocked
    st["s2"] = True
    rig.run_until(lambda: s1.CommandAborted, 5)
    assert not s1.Busy and not s1.Done
    rig.run_until(lambda: s2.Done, 5)
    # s1's Execute falling does not release the newer stop's lock
    calls["body"] = lambda p: (s1(Axis=ax, Execute=False), s2(Axis=ax, Execute=True))
    rig.run(3)
    assert ax.Status.MotionCommandsLocked
    calls["body"] = lambda p: (s1(Axis=ax, Execute=False), s2(Axis=ax, Execute=False))
    rig.run(2)
    assert not ax.Status.MotionCommandsLocked


def test_stop_rejected_dynamics(rig: Rig) -> None:
    """Out-of-range stop dynamics are refused with their NC code; a lone Deceleration is not (issue 17's
    decision: it is used with the stopped job's jerk; here the axis stands, so the stop is Done at once)."""
    ax, _, calls = powered(rig)
    stop = rig.watch(MC_Stop())
    calls["body"] = lambda p: stop(Axis=ax, Execute=True, Deceleration=1e11, Jerk=1e13)
    rig.run_until(lambda: not stop.Busy, 5)
    assert stop.Error and stop.ErrorID == ErrorCodes.NC_DECELERATION_NOT_ALLOWED
    assert not ax.Status.MotionCommandsLocked
    calls["body"] = lambda p: stop(Axis=ax, Execute=False)
    rig.run(2)
    calls["body"] = lambda p: stop(Axis=ax, Execute=True, Deceleration=100.0, Jerk=0.0)  # Jerk missing
    rig.run_until(lambda: stop.Done or stop.Error, 20)
    assert stop.Done and ax.Status.MotionCommandsLocked


def test_stop_clears_the_waiting_command(rig: Rig) -> None:
    from plc_client import MC_MoveRelative

    ax, _, calls = powered(rig)
    mv1, mv2, stop = rig.watch(MC_MoveAbsolute(), MC_MoveRelative(), MC_Stop())
    st = {"go2": False, "stop": False}

    def body(p):
        mv1(Axis=ax, Execute=True, Position=80.0, Velocity=50.0)
        mv2(Axis=ax, Execute=st["go2"], Distance=10.0, Velocity=50.0, BufferMode=1)
        stop(Axis=ax, Execute=st["stop"])

    calls["body"] = body
    rig.run_until(lambda: mv1.Active, 5)
    st["go2"] = True
    rig.run(3)
    assert mv2.Busy and not mv2.Active
    st["stop"] = True
    rig.run_until(lambda: mv2.CommandAborted, 5)
    assert mv1.CommandAborted and not mv2.Error
    assert not ax.Status.CmdBuffered
    rig.run_until(lambda: stop.Done, 200)
    assert ax.Status.NotMoving and ax.ActPos < 80.0
