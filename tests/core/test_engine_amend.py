"""Position jobs and their amendments, cycle by cycle: MoveAdditive, MoveContinuous*, NewPos,
NewPosAndVelo (instant, at a switching position, reach a velocity at a position), ChangeDynParam
(TcMC 4.20 refusals and an accepted change), MoveAbsoluteOrRestart, SetActualPosition(OnTheFly),
SetReferenceFlag; a refused command changes nothing (a twin core without it runs bit-identically)."""
import math

import numpy as np
import pytest

from nc_schema import CmdState, ErrorCodes as E, StateDWord
from znc_testing.engine_check import Trace, velocity_at
from znc_testing.nc_core import cmd, powered, snapshot

DONE, ACTIVE, ABORTED = int(CmdState.DONE), int(CmdState.ACTIVE), int(CmdState.ABORTED)


def moving(target=100.0, velo=100.0, cycles=300, vmax=None, **params):
    """A core 300 cycles into MoveAbsolute(0 -> target) (at constant velocity with the defaults)."""
    core = powered(**params)
    tr = Trace(core, vmax=vmax)
    n = cmd(core, "MoveAbsolute", Position=target, Velocity=velo)["CmdNo"]
    tr.step(cycles)
    return core, tr, n


def twin_unchanged(setup, name, code, **args):
    """``name`` is refused with ``code`` and changes nothing: a twin core built the same way without
    the command runs bit-identically (NCTOPLC and NCJOBS) until both stand still (or 1.5 s)."""
    a, b = setup(), setup()
    before = snapshot(a)
    rep = cmd(a, name, **args)
    assert rep["error"] == code, rep
    assert "CmdNo" not in rep and snapshot(a) == before
    for _ in range(1500):
        a.step()
        b.step()
        assert a.nctoplc.tobytes() == b.nctoplc.tobytes() and a.ncjobs.tobytes() == b.ncjobs.tobytes()
        if not a.moving.any():
            break


# -- MoveAdditive -------------------------------------------------------------------------------
def test_move_additive_adds_to_the_target_of_the_aborted_move():
    core, tr, n1 = moving()
    n2 = cmd(core, "MoveAdditive", Distance=50.0, Velocity=100.0)["CmdNo"]
    tr.step()
    assert tr.fate(n1) == (ABORTED, 0) and float(tr.rows[-1]["TargetPos"]) == 150.0
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 150.0 and int(tr.rows[-1]["CmdNo"]) == n2
    assert (tr.col("SetVelo") >= 0).all()  # no turn at the old target


def test_move_additive_buffered_adds_to_the_previous_target():
    core, tr, n1 = moving()
    n2 = cmd(core, "MoveAdditive", Distance=-30.0, Velocity=100.0, BufferMode=1)["CmdNo"]
    tr.settle()
    assert tr.fate(n1) == (DONE, 0) and tr.rows[-1]["SetPos"] == 70.0 and int(tr.rows[-1]["CmdNo"]) == n2


def test_move_additive_at_rest_and_after_a_velocity_move_refers_to_the_set_position():
    core = powered()
    tr = Trace(core)
    cmd(core, "MoveAdditive", Distance=12.5, Velocity=100.0)
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 12.5
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    tr.step(200)
    p = float(tr.rows[-1]["SetPos"])
    cmd(core, "MoveAdditive", Distance=40.0, Velocity=100.0)
    tr.settle()
    assert tr.rows[-1]["SetPos"] == pytest.approx(p + 40.0, abs=1e-9)


# -- MoveContinuousAbsolute/Relative ------------------------------------------------------------
@pytest.mark.parametrize("end_velo", [40.0, 100.0, 160.0])
def test_move_continuous_passes_the_target_with_end_velocity(end_velo):
    core = powered()
    tr = Trace(core, vmax=max(100.0, end_velo))
    n = cmd(core, "MoveContinuousAbsolute", Position=100.0, Velocity=100.0, EndVelocity=end_velo)["CmdNo"]
    k = tr.until(lambda r: r["StateDWord"] & StateDWord.ContinuousMotion) - 1
    pos = tr.col("SetPos")
    assert pos[k - 1] < 100.0 <= pos[k] + 1e-9  # ContinuousMotion from the target on, not before
    assert velocity_at(tr, 100.0) == pytest.approx(end_velo, abs=5000.0 * tr.dt)
    tr.step(500)
    r, pos = tr.rows[-1], tr.col("SetPos")
    assert r["SetVelo"] == pytest.approx(end_velo) and int(r["CmdNo"]) == n and int(r["CmdState"]) == ACTIVE
    assert r["StateDWord"] & StateDWord.ContinuousMotion and r["StateDWord"] & StateDWord.ConstantVelocity
    assert float(r["TargetPos"]) == float(r["SetPos"])  # an endless motion: the target moves with it
    vel = tr.col("SetVelo")
    assert vel[pos < 100.0 - 20.0].max() <= 100.0 * (1 + 1e-9)  # Velocity until the ramp to EndVelocity


def test_move_continuous_relative_negative_and_a_buffered_successor_starts_at_the_target():
    core = powered()
    tr = Trace(core)
    n1 = cmd(core, "MoveContinuousRelative", Distance=-80.0, Velocity=100.0, EndVelocity=50.0)["CmdNo"]
    n2 = cmd(core, "MoveRelative", Distance=-20.0, Velocity=50.0, BufferMode=1)["CmdNo"]
    tr.settle()
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    pos = tr.col("SetPos")
    assert pos[k - 1] > -80.0 >= pos[k] - 1e-9 and float(tr.rows[k]["SetVelo"]) == pytest.approx(-50.0)
    assert not any(r["StateDWord"] & StateDWord.ContinuousMotion for r in tr.rows)  # never past it alone
    assert tr.fate(n1) == (DONE, 0) and pos[-1] == -100.0


def test_move_continuous_with_end_velocity_zero_is_a_discrete_move():
    core = powered()
    tr = Trace(core)
    n = cmd(core, "MoveContinuousAbsolute", Position=30.0, Velocity=100.0, EndVelocity=0.0)["CmdNo"]
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 30.0 and tr.rows[-1]["CmdState"] == DONE and int(tr.rows[-1]["CmdNo"]) == n


# -- NewPos / NewPosAndVelo ----------------------------------------------------------------------
def test_new_pos_keeps_the_cmdno_and_ends_done_at_the_new_target():
    core, tr, n = moving()
    rep = cmd(core, "NewPos", NewPos=150.0)
    assert rep["error"] == 0 and rep["CmdNo"] == n
    r = tr.step()
    assert int(r["CmdNo"]) == n and r["StateDWord"] & StateDWord.NewTargetPos and int(tr.jobs[-1]["Flags"]) & 1
    assert float(r["TargetPos"]) == 150.0 and int(tr.jobs[-1]["NewestCmdNo"]) == n
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 150.0 and int(tr.rows[-1]["CmdState"]) == DONE
    assert (tr.col("SetVelo") >= 0).all() and tr.fates == {n: (DONE, 0)}  # the one job, DONE at the end
    assert int(tr.rows[-1]["CmdNo"]) == n


def test_new_pos_behind_reverses_within_the_limits():
    core, tr, n = moving()
    p = float(tr.rows[-1]["SetPos"])
    assert cmd(core, "NewPos", NewPos=p - 20.0)["error"] == 0
    tr.settle()
    pos = tr.col("SetPos")
    assert pos[-1] == p - 20.0 and int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE
    # braking distance from 100 u/s (acc 5000, jerk 50000): v^2/2a + v*a/2j = 1 + 5 = 6
    assert pos.max() - p <= 100.0 * 100.0 / (2 * 5000.0) + 100.0 * 5000.0 / (2 * 50000.0) + 0.2


def test_new_pos_beyond_a_soft_limit_is_refused():
    def setup():
        return moving(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=120.0)[0]
    twin_unchanged(setup, "NewPos", E.NC_TARGET_POSITION_NOT_ALLOWED, NewPos=130.0)


@pytest.mark.parametrize("mode,args,target,velo", [
    (1, dict(NewPos=150.0), 150.0, 100.0),
    (2, dict(NewVelo=200.0), 100.0, 200.0),
    (2, dict(NewVelo=30.0), 100.0, 30.0),
    (3, dict(NewPos=180.0, NewVelo=50.0), 180.0, 50.0),
])
def test_new_pos_and_velo_instantaneous(mode, args, target, velo):
    core, tr, n = moving(vmax=200.0)
    rep = cmd(core, "NewPosAndVelo", Mode=mode, **args)
    assert rep["error"] == 0 and rep["CmdNo"] == n
    tr.until(lambda r: r["StateDWord"] & StateDWord.ConstantVelocity and abs(r["SetVelo"] - velo) < 1e-9, 2000)
    tr.settle()
    r = tr.rows[-1]
    assert r["SetPos"] == target and int(r["CmdNo"]) == n and int(r["CmdState"]) == DONE
    assert abs(tr.col("SetVelo")[300:]).max() <= max(100.0, velo) * (1 + 1e-9)


@pytest.mark.parametrize("mode,args,target,velo", [
    (9, dict(NewPos=150.0, ActivationPos=60.0), 150.0, 100.0),
    (10, dict(NewVelo=200.0, ActivationPos=60.0), 100.0, 200.0),
    (10, dict(NewVelo=20.0, ActivationPos=60.0), 100.0, 20.0),
    (11, dict(NewPos=70.0, NewVelo=50.0, ActivationPos=60.0), 70.0, 50.0),
])
def test_new_pos_and_velo_at_the_switching_position(mode, args, target, velo):
    core, tr, n = moving(vmax=200.0)
    assert cmd(core, "NewPosAndVelo", Mode=mode, **args)["error"] == 0
    tr.settle()
    pos, vel, tgt = tr.col("SetPos"), tr.col("SetVelo"), tr.col("TargetPos")
    k = int(np.argmax(pos >= 60.0))  # the cycle in which SetPos passes ActivationPos
    assert pos[k - 1] < 60.0
    # before: the old job unchanged (target 100, 100 u/s); the change takes effect from the next cycle
    assert (tgt[300:k] == 100.0).all() and np.allclose(vel[300:k + 1], 100.0)
    assert tgt[k + 1] == target
    if velo != 100.0:
        assert vel[k + 1] != pytest.approx(100.0, abs=1e-12)
    assert pos[-1] == target and int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE
    if mode == 11:
        assert vel.min() >= 0  # 70 is still ahead at 60 with 50 u/s: no turn


@pytest.mark.parametrize("new_velo", [200.0, 20.0])
def test_new_pos_and_velo_reach_velocity_at_position(new_velo):
    core, tr, n = moving(target=190.0, vmax=200.0)
    assert cmd(core, "NewPosAndVelo", Mode=14, NewVelo=new_velo, ActivationPos=150.0)["error"] == 0
    tr.settle()
    pos, vel = tr.col("SetPos"), np.abs(tr.col("SetVelo"))
    assert velocity_at(tr, 150.0) == pytest.approx(new_velo, rel=0.02)  # reached about there
    assert np.allclose(vel[300:][pos[300:] < 150.0 - 35.0], 100.0)  # not changed long before
    after = vel[pos > 150.0 + 1.0]
    assert after.max() <= max(new_velo, 0.0) * (1 + 1e-6) + 1e-9  # the new velocity, then braking
    assert pos[-1] == 190.0 and int(tr.rows[-1]["CmdState"]) == DONE


@pytest.mark.parametrize("name,args", [
    ("NewPos", dict(NewPos=5.0)),
    ("NewPosAndVelo", dict(Mode=1, NewPos=5.0)),
    ("NewPosAndVelo", dict(Mode=14, NewVelo=5.0, ActivationPos=3.0)),
    ("ChangeDynParam", dict(Acceleration=100.0)),
])
def test_amendments_are_refused_at_rest(name, args):
    def setup():
        core = powered()
        cmd(core, "MoveAbsolute", Position=10.0, Velocity=100.0)
        for _ in range(1000):
            core.step()
        return core
    twin_unchanged(setup, name, E.MC_AXIS_NOT_MOVING, **args)


def test_new_pos_and_velo_invalid_mode_and_velocity():
    twin_unchanged(lambda: moving()[0], "NewPosAndVelo", E.MC_INVALID_MODE, Mode=5, NewPos=10.0)
    twin_unchanged(lambda: moving()[0], "NewPosAndVelo", E.NC_VELOCITY_NOT_ALLOWED, Mode=2, NewVelo=0.0)
    twin_unchanged(lambda: moving()[0], "NewPosAndVelo", E.NC_VELOCITY_NOT_ALLOWED, Mode=10, NewVelo=5000.0,
                   ActivationPos=50.0)


# -- ChangeDynParam (TcMC 4.20) ------------------------------------------------------------------
def at_const_velocity():
    core, tr, n = moving(target=500.0, velo=200.0)
    return core


def in_braking_towards(target=100.0):
    core = powered()
    cmd(core, "MoveAbsolute", Position=target, Velocity=200.0)
    while core.nctoplc[0]["SetPos"] <= 80.0:
        core.step()
    return core


def accelerating_velocity():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)
    for _ in range(40):  # v 40, a 2000 (jerk phase)
        core.step()
    return core


def accelerating_position():
    core = powered()
    cmd(core, "MoveAbsolute", Position=5000.0, Velocity=200.0)
    for _ in range(40):
        core.step()
    return core


def braking_velocity():
    """Braking from 200 towards 20 u/s (MoveVelocity), at v 60 with a = -2000."""
    core = powered()
    cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)
    while core.nctoplc[0]["SetVelo"] < 199.999:
        core.step()
    cmd(core, "MoveVelocity", Velocity=20.0, Direction=1)
    while core.nctoplc[0]["SetVelo"] >= 60.0:
        core.step()
    return core


def braking_position():
    core = powered()
    cmd(core, "MoveAbsolute", Position=1000.0, Velocity=200.0)
    while core.nctoplc[0]["SetVelo"] < 199.999:
        core.step()
    cmd(core, "MoveAbsolute", Position=1000.0, Velocity=20.0)
    while core.nctoplc[0]["SetVelo"] >= 60.0:
        core.step()
    return core


def stopping():
    core = powered()
    cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)
    for _ in range(100):
        core.step()
    cmd(core, "Stop")
    core.step()
    return core


@pytest.mark.parametrize("setup,args,code", [
    (in_braking_towards, dict(Deceleration=100.0), E.NC_NEW_TARGET_OVERRUN),          # 0x427F
    (stopping, dict(Deceleration=100.0, Jerk=1000.0), E.NC_ESTOP_ALREADY_ACTIVE),    # 0x425D
    (accelerating_velocity, dict(Jerk=1000.0), E.NC_VELOCITY_OVERFLOW),              # 0x423A
    (accelerating_position, dict(Jerk=10000.0), E.NC_VELOCITY_OVERFLOW),
    (braking_velocity, dict(Jerk=5000.0), E.NC_ILLEGAL_REVERSAL),                    # 0x4289
    (braking_position, dict(Jerk=5000.0), E.NC_ILLEGAL_REVERSAL),
    (at_const_velocity, dict(Jerk=-1.0), E.NC_JERK_NOT_ALLOWED),
])
def test_change_dyn_param_refusals_keep_the_dynamics(setup, args, code):
    twin_unchanged(setup, "ChangeDynParam", code, **args)


def test_change_dyn_param_accepted_brakes_with_the_new_deceleration():
    core, tr, n = moving(target=500.0, velo=200.0)
    rep = cmd(core, "ChangeDynParam", Acceleration=5000.0, Deceleration=1000.0, Jerk=20000.0)
    assert rep["error"] == 0 and rep["CmdNo"] == n
    r = tr.step()
    assert r["StateDWord"] & StateDWord.NewTargetPos and int(r["CmdNo"]) == n
    tr.settle()
    acc, jerk = tr.col("SetAcc")[300:], tr.col("SetJerk")[300:]
    assert acc.min() == pytest.approx(-1000.0, rel=1e-6) and np.abs(jerk).max() <= 20000.0 * (1 + 1e-9)
    assert tr.rows[-1]["SetPos"] == 500.0 and int(tr.rows[-1]["CmdState"]) == DONE


def test_change_dyn_param_of_a_velocity_job_is_used_by_override_changes():
    core = powered()
    tr = Trace(core)
    cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)
    tr.step(200)
    assert cmd(core, "ChangeDynParam", Acceleration=500.0, Deceleration=500.0, Jerk=50000.0)["error"] == 0
    tr.step()
    from znc_testing.nc_core import power
    power(core, override=500_000)
    tr.until(lambda r: abs(r["SetVelo"] - 100.0) < 1e-9, 2000)
    assert tr.col("SetAcc")[200:].min() == pytest.approx(-500.0, rel=1e-6)


# -- MoveAbsoluteOrRestart -----------------------------------------------------------------------
def test_move_absolute_or_restart_keeps_the_running_dynamics():
    core = powered()
    tr = Trace(core)
    n1 = cmd(core, "MoveAbsoluteOrRestart", Position=300.0, Velocity=100.0, Acceleration=1000.0,
             Deceleration=1000.0, Jerk=10000.0)["CmdNo"]
    tr.step(300)
    assert np.abs(tr.col("SetAcc")).max() <= 1000.0 * (1 + 1e-9)
    rep = cmd(core, "MoveAbsoluteOrRestart", Position=600.0, Velocity=200.0, Acceleration=20000.0,
              Deceleration=20000.0, Jerk=1e6)
    assert rep["error"] == 0 and rep["CmdNo"] == n1 + 1
    tr.settle()
    acc, jerk = tr.col("SetAcc"), tr.col("SetJerk")
    assert np.abs(acc).max() <= 1000.0 * (1 + 1e-9) and np.abs(jerk).max() <= 10000.0 * (1 + 1e-9)
    assert tr.col("SetVelo").max() == pytest.approx(200.0)
    assert tr.rows[-1]["SetPos"] == 600.0 and tr.fate(n1) == (ABORTED, 0)
    # from rest it uses its own dynamics
    cmd(core, "MoveAbsoluteOrRestart", Position=500.0, Velocity=100.0, Acceleration=3000.0, Deceleration=3000.0,
        Jerk=1e6)
    tr2 = Trace(core, amax=3000.0, jerk=1e6)
    tr2.settle()
    assert np.abs(tr2.col("SetAcc")).max() == pytest.approx(3000.0, rel=1e-6)


# -- SetActualPosition / OnTheFly / SetReferenceFlag ---------------------------------------------
def test_set_actual_position_at_rest():
    core = powered()
    tr = Trace(core)
    cmd(core, "MoveAbsolute", Position=10.0, Velocity=100.0)
    tr.settle()
    tr.step(100)
    lag = float(tr.rows[-1]["PosDiff"])
    assert cmd(core, "SetActualPosition", Position=500.0)["error"] == 0
    tr.shift(500.0 - float(tr.rows[-1]["ActPos"]))
    r = tr.step()
    assert float(r["ActPos"]) == pytest.approx(500.0, abs=1e-9) and float(r["PosDiff"]) == pytest.approx(lag, abs=1e-9)
    assert float(r["TargetPos"]) == pytest.approx(500.0 + lag, abs=1e-9) and r["ErrorCode"] == 0
    cmd(core, "MoveRelative", Distance=10.0, Velocity=100.0)
    tr.settle()
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(510.0 + lag, abs=1e-9)


def test_set_actual_position_is_refused_while_moving():
    twin_unchanged(lambda: moving()[0], "SetActualPosition", E.MC_AXIS_CANNOT_BE_STARTED, Position=0.0)


def test_set_actual_position_on_the_fly_shifts_the_target_and_covers_the_same_distance():
    core, tr, n = moving()
    p0, lag0 = float(tr.rows[-1]["SetPos"]), float(tr.rows[-1]["PosDiff"])
    rep = cmd(core, "SetActualPositionOnTheFly", ActualPosition=1040.0, PreviousPosition=40.0)
    assert rep["error"] == 0 and rep["CmdNo"] == n
    tr.shift(1000.0)
    r = tr.step()
    assert float(r["TargetPos"]) == 1100.0 and int(r["CmdNo"]) == n
    assert float(r["PosDiff"]) == pytest.approx(lag0, abs=0.01)  # no lag jump
    assert float(r["SetPos"]) == pytest.approx(p0 + 1000.0 + 0.1, abs=1e-6)  # 100 u/s * 1 ms on
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 1100.0 and int(tr.rows[-1]["CmdState"]) == DONE and r["ErrorCode"] == 0
    assert np.abs(tr.col("PosDiff")).max() < 0.2


def test_set_actual_position_on_the_fly_of_a_waiting_job_shifts_it_too():
    core, tr, n1 = moving()
    n2 = cmd(core, "MoveAbsolute", Position=200.0, Velocity=100.0, BufferMode=1)["CmdNo"]
    cmd(core, "SetActualPositionOnTheFly", ActualPosition=-50.0, PreviousPosition=0.0)
    tr.shift(-50.0)
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 150.0 and tr.fate(n1) == (DONE, 0) and int(tr.rows[-1]["CmdNo"]) == n2


def test_set_reference_flag():
    core = powered()
    tr = Trace(core)
    assert not tr.step()["StateDWord"] & StateDWord.Homed
    assert cmd(core, "SetReferenceFlag", ReferenceFlag=True)["error"] == 0
    assert tr.step()["StateDWord"] & StateDWord.Homed
    assert cmd(core, "SetReferenceFlag", ReferenceFlag=False)["error"] == 0
    assert not tr.step()["StateDWord"] & StateDWord.Homed


def test_set_actual_position_on_the_fly_keeps_a_velocity_job_going():
    core = powered()
    tr = Trace(core)
    n = cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)["CmdNo"]
    tr.step(200)
    p = float(tr.rows[-1]["SetPos"])
    cmd(core, "SetActualPositionOnTheFly", ActualPosition=0.0, PreviousPosition=p)
    tr.shift(-p)
    tr.step(100)
    r = tr.rows[-1]
    assert float(r["SetPos"]) == pytest.approx(10.0, abs=1e-6) and r["SetVelo"] == pytest.approx(100.0)
    assert int(r["CmdNo"]) == n and int(r["CmdState"]) == ACTIVE and math.isclose(float(r["TargetPos"]), float(r["SetPos"]))


# -- amendments of moves with an end velocity ----------------------------------------------------
def continuous_move(end_velo=150.0):
    core = powered()
    tr = Trace(core, vmax=200.0)
    n = cmd(core, "MoveContinuousAbsolute", Position=200.0, Velocity=100.0, EndVelocity=end_velo)["CmdNo"]
    return core, tr, n


def test_new_pos_of_a_continuous_move_keeps_its_end_velocity():
    core, tr, n = continuous_move()
    tr.step(800)
    assert cmd(core, "NewPos", NewPos=250.0)["error"] == 0
    tr.until(lambda r: r["StateDWord"] & StateDWord.ContinuousMotion, 5000)
    pos = tr.col("SetPos")
    assert pos[-2] < 250.0 <= pos[-1] + 1e-9 and velocity_at(tr, 250.0) == pytest.approx(150.0, abs=5.0)
    tr.step(100)
    assert tr.rows[-1]["SetVelo"] == pytest.approx(150.0) and int(tr.rows[-1]["CmdNo"]) == n


@pytest.mark.parametrize("at", [800, "ramp"])
def test_new_velocity_of_a_continuous_move_before_its_target(at):
    """Also during the speed-up ramp just before the target: the target is still passed at EndVelocity."""
    core, tr, n = continuous_move()
    if at == "ramp":
        tr.until(lambda r: r["SetVelo"] > 110.0)
    else:
        tr.step(at)
    assert cmd(core, "NewPosAndVelo", Mode=2, NewVelo=60.0)["error"] == 0
    tr.until(lambda r: r["StateDWord"] & StateDWord.ContinuousMotion, 10_000)
    pos = tr.col("SetPos")
    assert pos[-2] < 200.0 <= pos[-1] + 1e-9 and velocity_at(tr, 200.0) == pytest.approx(150.0, abs=5.0)
    assert (tr.col("SetVelo") >= 0).all()


def test_new_velocity_of_a_continuous_move_past_its_target_is_its_endless_velocity():
    core, tr, n = continuous_move()
    tr.until(lambda r: r["StateDWord"] & StateDWord.ContinuousMotion, 5000)
    assert cmd(core, "NewPosAndVelo", Mode=2, NewVelo=40.0)["error"] == 0
    tr.step(300)
    r = tr.rows[-1]
    assert r["SetVelo"] == pytest.approx(40.0) and r["StateDWord"] & StateDWord.ContinuousMotion
    assert (tr.col("SetVelo") >= 0).all() and int(r["CmdNo"]) == n and int(r["CmdState"]) == ACTIVE


def test_change_dyn_param_before_a_blend_to_a_faster_successor_keeps_the_blend():
    core = powered()
    tr = Trace(core, vmax=200.0)
    cmd(core, "MoveAbsolute", Position=200.0, Velocity=100.0)
    n2 = cmd(core, "MoveAbsolute", Position=400.0, Velocity=200.0, BufferMode=20)["CmdNo"]
    tr.step(500)
    assert cmd(core, "ChangeDynParam", Acceleration=2000.0, Deceleration=2000.0, Jerk=50000.0)["error"] == 0
    tr.until(lambda r: int(r["CmdNo"]) == n2)
    assert velocity_at(tr, 200.0) == pytest.approx(200.0, abs=5.0)
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 400.0


# -- a slower motion never turns back ------------------------------------------------------------
def slower(how):
    core, tr, n = moving(target=300.0)
    if how == "abort":
        assert cmd(core, "MoveAbsolute", Position=300.0, Velocity=30.0)["error"] == 0
    elif how == "new velocity":
        assert cmd(core, "NewPosAndVelo", Mode=2, NewVelo=30.0)["error"] == 0
    else:
        from znc_testing.nc_core import power
        power(core, override=300_000)
    return tr


@pytest.mark.parametrize("how", ["abort", "new velocity", "override"])
def test_slowing_down_never_turns_the_axis_back(how):
    """ruckig's brake pre-profile (the axis faster than its new velocity) undershoots into the other
    direction when planned with symmetric velocity limits: the NC plans one way."""
    tr = slower(how)
    tr.until(lambda r: abs(float(r["SetVelo"]) - 30.0) < 1e-9 and r["StateDWord"] & StateDWord.ConstantVelocity, 3000)
    assert tr.col("SetVelo").min() >= 0.0
    assert np.all(np.diff(tr.col("SetPos")) >= 0)


@pytest.mark.parametrize("ov_from,ov_to", [(1.0, 0.5), (1.0, 0.3), (0.7, 1.0), (0.7, 0.5)])
def test_override_change_while_speeding_up_to_a_blend_never_turns_back(ov_from, ov_to):
    from znc_testing.nc_core import power
    core = powered()
    power(core, override=round(ov_from * 1e6))
    tr = Trace(core, vmax=200.0)
    cmd(core, "MoveAbsolute", Position=100.0, Velocity=100.0)
    n2 = cmd(core, "MoveAbsolute", Position=250.0, Velocity=200.0, BufferMode=20)["CmdNo"]
    tr.until(lambda r: r["SetVelo"] > 100.0 * ov_from + 10.0)  # in the ramp up to the blending velocity
    power(core, override=round(ov_to * 1e6))
    tr.settle()
    assert tr.col("SetVelo").min() >= 0.0 and np.all(np.diff(tr.col("SetPos")) >= -1e-12)
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    assert tr.col("SetPos")[:k].max() <= 100.0 + 1e-9 and tr.rows[-1]["SetPos"] == 250.0
    if ov_to < ov_from:  # the new blending velocity is reachable from here: at the rule times the override
        assert velocity_at(tr, 100.0) == pytest.approx(200.0 * ov_to, abs=1.0)


def test_a_job_with_an_armed_switching_position_that_ends_first():
    """The switching position is never reached: the job ends at its target (the cycle in which it
    ends must not hand the gone job to its kind's watch -- it raised AttributeError in the NC cycle)."""
    for name, extra in (("MoveContinuousAbsolute", dict(EndVelocity=0.0)), ("MoveAbsolute", {})):
        core = powered()
        tr = Trace(core)
        n = cmd(core, name, Position=10.0, Velocity=100.0, **extra)["CmdNo"]
        tr.step(20)
        assert cmd(core, "NewPosAndVelo", Mode=9, NewPos=30.0, ActivationPos=50.0)["error"] == 0
        tr.settle()
        assert tr.rows[-1]["SetPos"] == 10.0 and tr.fate(n) == (DONE, 0) and int(tr.rows[-1]["CmdState"]) == DONE


def test_set_actual_position_on_the_fly_moves_an_armed_switching_position_with_it():
    core, tr, n = moving()
    assert cmd(core, "NewPosAndVelo", Mode=10, NewVelo=30.0, ActivationPos=60.0)["error"] == 0
    tr.until(lambda r: float(r["SetPos"]) > 40.0)
    cmd(core, "SetActualPositionOnTheFly", ActualPosition=1040.0, PreviousPosition=40.0)
    tr.shift(1000.0)
    tr.settle()
    pos, vel = tr.col("SetPos"), tr.col("SetVelo")
    k = int((pos >= 1060.0).argmax())  # the same place on the axis: 60 before the shift
    assert vel[k] == pytest.approx(100.0) and vel[k + 1] < 100.0 and (vel[:k] >= 100.0 - 1e-9)[300:].all()
    assert pos[-1] == 1100.0 and int(tr.rows[-1]["CmdNo"]) == n
