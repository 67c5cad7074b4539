"""PLCopen state transitions as seen through the cyclic interface."""
import numpy as np

from nc_schema import CmdState, ControlDWord, ErrorCodes, ErrorCodes as E, MC_AxisStates as S, StateDWord
from znc_testing.nc_core import ALL_ENABLES, cmd, make_core, power, powered, run_until, state


def test_disabled_standstill_discrete_standstill():
    core = make_core()
    core.step()
    assert state(core) == S.MC_AXISSTATE_DISABLED
    assert not core.nctoplc[0]["StateDWord"] & StateDWord.ControlLoopClosed
    power(core)
    core.step()
    assert state(core) == S.MC_AXISSTATE_STANDSTILL
    assert core.nctoplc[0]["StateDWord"] & StateDWord.Operational
    cmd(core, "MoveRelative", Distance=10.0, Velocity=100.0)
    core.step()
    assert state(core) == S.MC_AXISSTATE_DISCRETEMOTION
    run_until(core, lambda: state(core) == S.MC_AXISSTATE_STANDSTILL)
    assert core.nctoplc[0]["SetPos"] == 10.0


def test_enable_off_while_moving_disables_and_aborts_the_job():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    for _ in range(50):
        core.step()
    power(core, ctrl=0)
    core.step()
    r = core.nctoplc[0]
    assert state(core) == S.MC_AXISSTATE_DISABLED
    assert r["CmdState"] == CmdState.ABORTED and not r["StateDWord"] & StateDWord.HasJob
    assert r["SetVelo"] == 0.0 and r["SetPos"] == r["ActPos"]


def test_stop_locks_until_released_and_reset_also_releases():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=300.0, Direction=1)
    for _ in range(100):
        core.step()
    rep = cmd(core, "Stop")
    assert rep["error"] == 0 and rep["CmdNo"] == 2
    core.step()
    assert state(core) == S.MC_AXISSTATE_STOPPING
    run_until(core, lambda: core.nctoplc[0]["CmdState"] == CmdState.DONE)
    r = core.nctoplc[0]
    assert r["SetVelo"] == 0.0 and r["StateDWord"] & StateDWord.MotionCommandsLocked
    assert state(core) == S.MC_AXISSTATE_STOPPING  # stays locked after standstill
    assert cmd(core, "MoveAbsolute", Position=0.0, Velocity=10.0)["error"] == ErrorCodes.NC_AXIS_LOCKED_BY_STOP
    assert cmd(core, "StopRelease")["error"] == 0
    core.step()
    assert state(core) == S.MC_AXISSTATE_STANDSTILL
    cmd(core, "Stop")
    core.step()
    assert state(core) == S.MC_AXISSTATE_STOPPING
    assert core.nctoplc[0]["CmdState"] == CmdState.DONE  # stop at standstill completes at once
    cmd(core, "Reset")
    core.step()
    assert state(core) == S.MC_AXISSTATE_STANDSTILL


def test_halt_is_discrete_and_does_not_lock():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=300.0, Direction=1)
    for _ in range(100):
        core.step()
    assert cmd(core, "Halt")["error"] == 0
    core.step()
    assert state(core) == S.MC_AXISSTATE_DISCRETEMOTION
    run_until(core, lambda: core.nctoplc[0]["CmdState"] == CmdState.DONE)
    assert state(core) == S.MC_AXISSTATE_STANDSTILL


def test_fault_stops_with_deceleration_keeps_drive_enabled_and_reset_recovers():
    core = powered(AxisDec=1000.0, AxisAcc=1000.0)
    cmd(core, "MoveVelocity", Velocity=500.0, Direction=1)
    run_until(core, lambda: core.nctoplc[0]["StateDWord"] & StateDWord.ConstantVelocity)
    core.fault(0, ErrorCodes.ZNC_CLIENT_LOST)
    power(core, ctrl=0)  # the watchdog also drops the enables
    core.step()
    r = core.nctoplc[0]
    assert state(core) == S.MC_AXISSTATE_ERRORSTOP and r["ErrorCode"] == ErrorCodes.ZNC_CLIENT_LOST
    assert r["CmdState"] == CmdState.ERROR
    assert r["StateDWord"] & StateDWord.ControlLoopClosed  # held enabled for the ramp
    v_prev = r["SetVelo"]
    n = run_until(core, lambda: core.nctoplc[0]["SetVelo"] == 0.0, 5000)
    assert 0.45 < n * core.cycle_time < 0.65  # 500 u/s at 1000 u/s^2 (+ jerk phases)
    assert v_prev > 0
    core.step()
    assert not core.nctoplc[0]["StateDWord"] & StateDWord.ControlLoopClosed  # released after the ramp
    assert cmd(core, "MoveRelative", Distance=1.0, Velocity=1.0)["error"] == ErrorCodes.MC_AXIS_CANNOT_BE_STARTED
    power(core)
    cmd(core, "Reset")
    core.step()
    assert state(core) == S.MC_AXISSTATE_STANDSTILL and core.nctoplc[0]["ErrorCode"] == 0


def test_feed_enable_withdrawn_in_travel_direction_is_an_error():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    for _ in range(20):
        core.step()
    power(core, ctrl=int(ControlDWord.Enable | ControlDWord.FeedEnableMinus))
    core.step()
    assert core.nctoplc[0]["ErrorCode"] == ErrorCodes.NC_AXIS_FEED_ENABLE_PLUS
    assert state(core) == S.MC_AXISSTATE_ERRORSTOP
    run_until(core, lambda: core.nctoplc[0]["SetVelo"] == 0.0, 2000)


def test_superseded_command_shows_newer_cmdno():
    core = powered()
    first = cmd(core, "MoveAbsolute", Position=100.0, Velocity=100.0)["CmdNo"]
    core.step()
    second = cmd(core, "MoveAbsolute", Position=50.0, Velocity=100.0)["CmdNo"]
    core.step()
    assert second == first + 1 and core.nctoplc[0]["CmdNo"] == second


def test_set_plctonc_many_applies_and_is_idempotent():
    core = make_core(3)
    core.step()
    recs = np.zeros(2, dtype=core.plctonc.dtype)
    recs["ControlDWord"] = ALL_ENABLES
    recs["Override"] = 1_000_000
    core.set_plctonc_many(np.array([0, 2]), recs)
    core.step()
    assert [state(core, i) for i in range(3)] == [S.MC_AXISSTATE_STANDSTILL, S.MC_AXISSTATE_DISABLED,
                                                  S.MC_AXISSTATE_STANDSTILL]
    core.set_plctonc_many(np.array([0, 2]), recs)  # unchanged frame: nothing to re-derive
    assert not core.inputs_pending


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
    assert rep["CmdNo"] == 2  # the stop job's number: the reset's own (NewestCmdNo counts it)
    core.step()
    r = core.nctoplc[0]
    assert r["ErrorCode"] == 0 and r["CmdNo"] == 2 and r["CmdState"] == CmdState.ACTIVE
    assert core.ncjobs[0]["NewestCmdNo"] == 2
    assert state(core) == S.MC_AXISSTATE_STOPPING  # never StandStill while still braking
    v_prev = abs(float(r["SetVelo"]))
    while core.axes.traj_on[0]:
        core.step()
        v = abs(float(core.nctoplc[0]["SetVelo"]))
        assert v <= v_prev + 1e-9  # the ramp goes on, it does not speed up
        assert core.axes.traj_on[0] or state(core) == S.MC_AXISSTATE_STANDSTILL
        v_prev = v
    assert core.nctoplc[0]["CmdState"] == CmdState.DONE and state(core) == S.MC_AXISSTATE_STANDSTILL


def test_every_cmdno_is_an_accepted_replys_moves_faults_and_resets():
    """bench/many_clients.py's program on one axis: MC_MoveAbsolute back and forth, axis errors 0x4655 (drive
    inputs too old) at any time, MC_Reset 1..150 cycles after the error shows (sometimes during the ~90-cycle fault ramp,
    sometimes at rest). NewestCmdNo hands out exactly the numbers of the accepted replies: the moves' and
    those of the resets that made the ramp a numbered stop job (no other number, none twice)."""
    rng = np.random.default_rng(7)
    core = powered()
    newest0 = int(core.ncjobs[0]["NewestCmdNo"])
    seen: list[int] = []  # the CmdNo of every accepted reply
    moves = resets = resets_numbered = 0
    reset_in: int | None = None
    k = 0
    for _ in range(30_000):
        a = core.axes
        if a.error[0] and reset_in is None:
            reset_in = int(rng.integers(1, 150))
        if reset_in is not None:
            reset_in -= 1
            if reset_in <= 0:
                reset_in = None
                rep = cmd(core, "Reset")
                assert rep["error"] == 0
                resets += 1
                if "CmdNo" in rep:
                    resets_numbered += 1
                    seen.append(int(rep["CmdNo"]))
        elif not (a.error[0] or a.traj_on[0] or a.has_job[0] or a.locked[0]):
            k += 1
            rep = cmd(core, "MoveAbsolute", Position=(0.0, 40.0)[k % 2], Velocity=100.0)
            assert rep["error"] == 0
            moves += 1
            seen.append(int(rep["CmdNo"]))
        if not a.error[0] and rng.random() < 0.001:
            core.fault(0, E.NC_DRIVE_IO_DATA_INVALID)
        core.step()
    progress = int(core.ncjobs[0]["NewestCmdNo"]) - newest0
    assert 0 < resets_numbered < resets  # both cases happened
    assert progress == moves + resets_numbered
    assert seen == list(range(newest0 + 1, newest0 + 1 + progress))


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
