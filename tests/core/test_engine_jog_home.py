"""Jog, Home, OrientedStop and the PLCTONC override, cycle by cycle (engine_check.Trace): the jog
modes' velocities and ends, the homing sequence against a reference cam simulated from ActPos, the
direction rules of an oriented stop, Override > 100 % as an axis error."""
import math

import numpy as np
import pytest

from nc_schema import (
    DEFAULT_HOME_POSITION, CmdState, ControlDWord, ErrorCodes as E, HomingState as H, MC_AxisStates as S, StateDWord,
)
from znc_testing.engine_check import Trace
from znc_testing.nc_core import ALL_ENABLES, cmd, make_core, power, powered, snapshot, state

DONE, ACTIVE, ABORTED, ERROR = int(CmdState.DONE), int(CmdState.ACTIVE), int(CmdState.ABORTED), int(CmdState.ERROR)
POS, NEG = 1, 3
SLOW, FAST, CONT, INCH, INCH_MOD = 0, 1, 2, 3, 4


def stop_distance(v: float, dec: float = 5000.0, jerk: float = 50000.0) -> float:
    """Jerk-limited braking distance from v at zero acceleration (independent of the engine)."""
    if v <= dec * dec / jerk:
        return v * math.sqrt(v / jerk)  # triangular acceleration: t = 2 sqrt(v/j), d = v t / 2
    return 0.5 * v * (v / dec + dec / jerk)


# -- Jog ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("direction", [POS, NEG])
@pytest.mark.parametrize("mode,args,velo", [
    (SLOW, {}, 50.0),                       # AxisVeloManSlow
    (FAST, {}, 250.0),                      # AxisVeloManFast
    (SLOW, dict(Velocity=999.0, Acceleration=1.0), 50.0),  # the block's values do not count
    (CONT, dict(Velocity=77.0), 77.0),
])
def test_continuous_jog_runs_at_its_velocity_until_halt(mode, args, velo, direction):
    core = powered()
    tr = Trace(core, vmax=velo)
    sense = 1.0 if direction == POS else -1.0
    n = cmd(core, "Jog", Mode=mode, Direction=direction, **args)["CmdNo"]
    tr.step(400)
    r = tr.rows[-1]
    assert r["SetVelo"] == pytest.approx(sense * velo) and r["StateDWord"] & StateDWord.ContinuousMotion
    assert int(r["CmdNo"]) == n and int(r["CmdState"]) == ACTIVE and state(core) == S.MC_AXISSTATE_CONTINOUSMOTION
    assert (sense * tr.col("SetVelo") >= 0).all()  # never the other way
    p = float(r["SetPos"])
    h = cmd(core, "Halt")["CmdNo"]
    tr.settle()
    assert tr.fate(n) == (ABORTED, 0) and int(tr.rows[-1]["CmdNo"]) == h and int(tr.rows[-1]["CmdState"]) == DONE
    assert sense * (float(tr.rows[-1]["SetPos"]) - p) == pytest.approx(stop_distance(velo), abs=1e-3)
    assert state(core) == S.MC_AXISSTATE_STANDSTILL


def test_jog_manual_velocities_follow_the_parameters():
    core = powered(AxisVeloManSlow=12.0, AxisVeloManFast=600.0, AxisVeloMax=500.0)
    tr = Trace(core)
    cmd(core, "Jog", Mode=SLOW, Direction=POS)
    tr.step(300)
    assert tr.rows[-1]["SetVelo"] == pytest.approx(12.0)
    cmd(core, "Jog", Mode=FAST, Direction=POS)  # 600 > AxisVeloMax: at most AxisVeloMax
    tr.step(300)
    assert tr.rows[-1]["SetVelo"] == pytest.approx(500.0)


@pytest.mark.parametrize("start,direction,step,end", [
    (3.0, POS, 7.5, 10.5), (3.0, NEG, 7.5, -4.5), (-2.0, NEG, 0.25, -2.25),
])
def test_inching_moves_by_the_distance(start, direction, step, end):
    core = powered()
    tr = Trace(core)
    cmd(core, "MoveAbsolute", Position=start, Velocity=100.0)
    tr.settle()
    tr = Trace(core)
    n = cmd(core, "Jog", Mode=INCH, Direction=direction, Position=step, Velocity=100.0)["CmdNo"]
    tr.settle()
    assert tr.rows[-1]["SetPos"] == end and int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE
    sense = 1.0 if direction == POS else -1.0
    assert (sense * tr.col("SetVelo") >= 0).all()


@pytest.mark.parametrize("start,direction,step,end", [
    (3.0, POS, 10.0, 10.0), (3.0, NEG, 10.0, 0.0),      # to the next multiple
    (10.0, POS, 10.0, 20.0), (10.0, NEG, 10.0, 0.0),    # from a multiple: exactly one step
    (-3.0, POS, 10.0, 0.0), (-3.0, NEG, 10.0, -10.0),
    (359.0, POS, 90.0, 360.0), (725.0, NEG, 90.0, 720.0),
])
def test_inching_modulo_ends_at_a_multiple_of_the_distance(start, direction, step, end):
    core = powered(Modulo=True)
    tr = Trace(core)
    cmd(core, "MoveAbsolute", Position=start, Velocity=500.0)
    tr.settle()
    tr = Trace(core)
    cmd(core, "Jog", Mode=INCH_MOD, Direction=direction, Position=step, Velocity=100.0)
    tr.settle()
    p = float(tr.rows[-1]["SetPos"])
    assert p == pytest.approx(end, abs=1e-9) and math.remainder(p, step) == pytest.approx(0.0, abs=1e-9)
    sense = 1.0 if direction == POS else -1.0
    assert (sense * tr.col("SetVelo") >= 0).all()  # never against the jog direction


@pytest.mark.parametrize("args,code", [
    (dict(Mode=9, Direction=POS, Velocity=10.0), E.MC_INVALID_MODE),
    (dict(Mode=CONT, Direction=2, Velocity=10.0), E.MC_COMMAND_NOT_PERMITTED),
    (dict(Mode=CONT, Direction=POS, Velocity=0.0), E.NC_VELOCITY_NOT_ALLOWED),
    (dict(Mode=INCH, Direction=POS, Velocity=10.0, Position=-0.5), E.MC_PARAMETER_NOT_CORRECT),  # (0: the jog increment)
    (dict(Mode=INCH_MOD, Direction=NEG, Velocity=10.0, Position=-1.0), E.MC_PARAMETER_NOT_CORRECT),
])
def test_jog_refusals_change_nothing(args, code):
    core = powered()
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    for _ in range(50):
        core.step()
    before = snapshot(core)
    assert cmd(core, "Jog", **args)["error"] == code
    assert snapshot(core) == before


def test_jog_against_a_missing_feed_enable_is_refused():
    core = make_core()
    power(core, ctrl=int(ControlDWord.Enable | ControlDWord.FeedEnablePlus))
    core.step()
    assert cmd(core, "Jog", Mode=SLOW, Direction=NEG)["error"] == E.NC_NO_ENABLE
    assert cmd(core, "Jog", Mode=INCH, Direction=NEG, Position=1.0, Velocity=10.0)["error"] == E.NC_NO_ENABLE
    assert cmd(core, "Jog", Mode=SLOW, Direction=POS)["error"] == 0


# -- Home -----------------------------------------------------------------------------------------
CAM = (-30.0, -10.0)  # reference cam, seen by the PLC from ActPos
PULSE_OFFSET = 0.25   # sync pulses at k + 0.25


def homing_core(cam=CAM, **params):
    args = dict(AxisCalibrationVelocityForward=100.0, AxisCalibrationVelocityBackward=20.0,
                SimSyncPulseOffset=PULSE_OFFSET, Homed=True)
    args.update(params)
    core = powered(**args)
    ctrl = {"base": ALL_ENABLES}

    def cam_input():  # the PLC reads the cam and sends it with the next PLCTONC
        p = float(core.nctoplc[0]["ActPos"])
        on = cam[0] <= p <= cam[1]
        power(core, ctrl=ctrl["base"] | (int(ControlDWord.HomingSensor) if on else 0))

    tr = Trace(core, before_step=cam_input,
               shift_ok=lambda p, r: int(p["HomingState"]) == int(H.SET_POSITION) and int(r["HomingState"]) == 0)
    return core, tr, ctrl


def changes(values):
    out = [values[0]]
    for x in values[1:]:
        if x != out[-1]:
            out.append(x)
    return out


@pytest.mark.parametrize("position,ref", [(500.0, 500.0), (DEFAULT_HOME_POSITION, 0.0)])
def test_homing_sequence(position, ref):
    core, tr, _ = homing_core()
    n = cmd(core, "Home", Position=position)["CmdNo"]
    tr.settle()
    hs = [int(x) for x in tr.col("HomingState")]
    assert changes(hs) == [1, 2, 3, 4, 5, 6, 0]
    homed = np.array([bool(r["StateDWord"] & StateDWord.Homed) for r in tr.rows])
    busy = np.array([bool(r["StateDWord"] & StateDWord.HomingBusy) for r in tr.rows])
    end = len(hs) - 1
    assert homed[-1] and not homed[1:end].any()      # cleared during the sequence, set after it
    assert busy[:end].all() and not busy[end]
    assert all(state(core) != S.MC_AXISSTATE_HOMING for _ in [0])  # standing now
    # the phases against the cam and the pulse, from the samples
    act = tr.col("ActPos")
    k2, k3, k4, k5, k6 = (hs.index(s) for s in (2, 3, 4, 5, 6))
    v = tr.col("SetVelo")
    assert v[k2:k3].min() == pytest.approx(-100.0) and v[k4:k5].max() == pytest.approx(20.0)
    assert (v[:k4] <= 0).all() and (v[k4:] >= 0).all()  # towards the cam, then off it
    assert act[k3 - 2] > CAM[1] >= act[k3 - 1]   # stopped after the rising edge seen by the PLC
    assert act[k5 - 2] <= CAM[1] < act[k5 - 1]   # latch armed after the falling edge
    pulse = -10.0 + PULSE_OFFSET                 # the first pulse off the cam
    assert act[k6 - 2] < pulse <= act[k6 - 1]
    # the latched position becomes the reference: the axis stands at ref + its way since the pulse
    sp = tr.col("SetPos")  # at rest: the set position moves only by the shift
    assert sp[-1] == pytest.approx(ref + (sp[end - 1] - pulse), abs=1e-4)  # (its last cycle of motion)
    assert act[-1] - act[end - 1] == pytest.approx(ref - pulse, abs=1e-4)  # the actual position with it
    assert 0 < sp[-1] - ref < stop_distance(20.0) + 3 * 20.0 * tr.dt + 0.05
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE
    assert tr.rows[-1]["ErrorCode"] == 0 and state(core) == S.MC_AXISSTATE_STANDSTILL


def test_homing_with_the_cam_occupied_at_start_leaves_it_first():
    core, tr, _ = homing_core(cam=(-5.0, 5.0))
    tr.step()  # the PLC sends the cam it stands on
    cmd(core, "Home", Position=0.0)
    tr.settle()
    hs = changes([int(x) for x in tr.col("HomingState")[1:]])
    assert hs[0] == 3 and hs[1:] == [4, 5, 6, 0]
    assert (tr.col("SetVelo") >= 0).all()  # straight off the cam towards the pulse
    assert tr.rows[-1]["StateDWord"] & StateDWord.Homed


@pytest.mark.parametrize("clear_at", [4, 3])
def test_homing_without_cam_recipe(clear_at):
    """TcMC 3.14: the PLC sets the cam first and clears it once HomingState >= 4. A PLC clearing it
    already at state 3 (the axis at rest on the cam): the cam FALSE at rest when state 4 starts is
    the falling edge, the latch is armed at once (no endless wait for a cam that never comes)."""
    core = powered(AxisCalibrationVelocityBackward=20.0, SimSyncPulseOffset=PULSE_OFFSET)
    tr = Trace(core, shift_ok=lambda p, r: int(p["HomingState"]) == 6 and int(r["HomingState"]) == 0)
    power(core, ctrl=ALL_ENABLES | int(ControlDWord.HomingSensor))
    tr.step()
    cmd(core, "Home", Position=100.0)
    tr.until(lambda r: int(r["HomingState"]) >= clear_at)
    power(core)
    tr.settle()
    assert tr.rows[-1]["StateDWord"] & StateDWord.Homed and 100.0 < float(tr.rows[-1]["ActPos"]) < 101.0


@pytest.mark.parametrize("mode,homed_after", [(7, True), (8, False)])
def test_force_and_reset_calibration(mode, homed_after):
    core = powered(Homed=not homed_after)
    tr = Trace(core)
    n = cmd(core, "Home", HomingMode=mode)["CmdNo"]
    r = tr.step()
    assert bool(r["StateDWord"] & StateDWord.Homed) == homed_after and int(r["CmdNo"]) == n
    assert int(r["CmdState"]) == DONE and r["SetPos"] == 0.0


def test_home_direct_sets_the_position():
    core = powered()
    tr = Trace(core, shift_ok=lambda p, r: True)
    cmd(core, "MoveAbsolute", Position=7.0, Velocity=100.0)
    tr.settle()
    tr.step(50)
    act = float(tr.rows[-1]["ActPos"])
    n = cmd(core, "Home", HomingMode=4, Position=-300.0)["CmdNo"]
    r = tr.step()
    assert float(r["ActPos"]) == pytest.approx(-300.0, abs=1e-9) and r["StateDWord"] & StateDWord.Homed
    assert float(r["SetPos"]) == pytest.approx(-300.0 + 7.0 - act, abs=1e-9) and int(r["CmdState"]) == DONE
    assert int(r["CmdNo"]) == n


def test_home_refusals():
    core = powered()
    assert cmd(core, "Home", HomingMode=3)["error"] == E.MC_INVALID_MODE == 0x4B04
    assert cmd(core, "Home", HomingMode=99)["error"] == E.MC_INVALID_MODE
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)
    for _ in range(20):
        core.step()
    before = snapshot(core)
    assert cmd(core, "Home")["error"] == E.MC_AXIS_CANNOT_BE_STARTED == 0x4B01
    assert cmd(core, "Home", HomingMode=4, Position=0.0)["error"] == 0x4B01
    assert snapshot(core) == before
    off = make_core()
    off.step()
    assert cmd(off, "Home")["error"] == E.NC_NO_ENABLE == 0x4223


def test_home_is_refused_while_a_job_waits_at_override_zero():
    """A job held at override 0 stands but is DiscreteMotion: homing only from StandStill."""
    core = powered()
    power(core, override=0)
    core.step()
    cmd(core, "MoveAbsolute", Position=50.0, Velocity=100.0)
    for _ in range(5):
        core.step()
    assert core.nctoplc[0]["SetVelo"] == 0.0 and state(core) == S.MC_AXISSTATE_DISCRETEMOTION
    before = snapshot(core)
    assert cmd(core, "Home")["error"] == E.MC_AXIS_CANNOT_BE_STARTED
    assert snapshot(core) == before


def test_buffered_home_starts_after_the_move():
    core, tr, _ = homing_core(cam=(-5.0, 5.0))
    n1 = cmd(core, "MoveAbsolute", Position=2.0, Velocity=100.0)["CmdNo"]
    n2 = cmd(core, "Home", Position=0.0, BufferMode=1)["CmdNo"]
    tr.settle()
    assert tr.fate(n1) == (DONE, 0) and int(tr.rows[-1]["CmdNo"]) == n2 and int(tr.rows[-1]["CmdState"]) == DONE
    assert tr.rows[-1]["StateDWord"] & StateDWord.Homed


def test_stop_during_homing_aborts_it_and_the_axis_is_not_homed():
    core, tr, _ = homing_core()
    n = cmd(core, "Home")["CmdNo"]
    tr.until(lambda r: int(r["HomingState"]) == 2)
    tr.step(20)
    assert cmd(core, "MoveAbsolute", Position=0.0, Velocity=10.0)["error"] == E.MC_AXIS_CANNOT_BE_STARTED
    cmd(core, "Stop")
    tr.settle()
    r = tr.rows[-1]
    assert tr.fate(n) == (ABORTED, 0) and int(r["HomingState"]) == 0 and not r["StateDWord"] & StateDWord.Homed
    assert not r["StateDWord"] & StateDWord.HomingBusy


# -- OrientedStop ---------------------------------------------------------------------------------
@pytest.mark.parametrize("direction", [POS, NEG])
@pytest.mark.parametrize("position", [90.0, 0.0, 359.5])
def test_oriented_stop_ends_at_the_next_reachable_modulo_position(direction, position):
    core = powered(Modulo=True)
    tr = Trace(core)
    sense = 1.0 if direction == POS else -1.0
    cmd(core, "MoveVelocity", Velocity=360.0, Direction=direction)
    tr.step(500)
    p = float(tr.rows[-1]["SetPos"])
    n = cmd(core, "OrientedStop", Position=position)["CmdNo"]
    tr.settle()
    e = float(tr.rows[-1]["SetPos"])
    assert e % 360.0 == pytest.approx(position, abs=1e-6) or (e % 360.0) - 360.0 == pytest.approx(position - 360.0, abs=1e-6)
    natural = p + sense * stop_distance(360.0)
    way = sense * (e - natural)
    assert -0.5 <= way < 360.0  # the next one at or after the natural stop (+/- a cycle)
    assert (sense * tr.col("SetVelo") >= 0).all()  # never reversing
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE


def test_oriented_stop_refusals():
    core = powered(Modulo=True)
    assert cmd(core, "OrientedStop", Position=90.0)["error"] == E.MC_AXIS_NOT_MOVING == 0x4B03
    cmd(core, "MoveVelocity", Velocity=360.0, Direction=1)
    for _ in range(100):
        core.step()
    before = snapshot(core)
    assert cmd(core, "OrientedStop", Position=360.0)["error"] == E.NC_ORIENTED_STOP_NOT_ALLOWED == 0x4281
    assert cmd(core, "OrientedStop", Position=-1.0)["error"] == 0x4281
    assert snapshot(core) == before


def test_oriented_stop_beyond_a_soft_limit_stops_the_axis_and_ends_with_the_error():
    """TcMC 3.16: "an oriented stop would cause an active software limit switch to be exceeded. For all
    fault conditions, the axis is stopped safely, but it may subsequently not be at the required
    oriented position": the standard stop, then the job ends ERROR 0x4222."""
    core = powered(Modulo=True, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=200.0)
    tr = Trace(core)
    cmd(core, "MoveVelocity", Velocity=360.0, Direction=1)
    tr.until(lambda r: r["SetPos"] >= 100.0)
    p = float(tr.rows[-1]["SetPos"])
    r = cmd(core, "OrientedStop", Position=350.0)
    assert r["error"] == 0
    n = r["CmdNo"]
    tr.settle()
    e = float(tr.rows[-1]["SetPos"])
    assert e == pytest.approx(p + stop_distance(360.0), abs=0.5), "the standard stop (not the oriented one)"
    assert e < 200.0 and (tr.col("SetVelo") >= 0).all()
    assert tr.fate(n) == (ERROR, E.NC_TARGET_POSITION_NOT_ALLOWED)
    assert not core.nctoplc[0]["StateDWord"] & StateDWord.Error, "a command error, not an axis error"


def test_oriented_stop_ending_in_error_aborts_the_job_buffered_behind_it():
    """Errors clear the queue (schema/README.md; PLCopen Buffered waits for Done): a job buffered behind
    an oriented stop that ends ERROR 0x4222 (beyond the software limit) never starts, it ends ABORTED."""
    core = powered(Modulo=True, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=200.0)
    tr = Trace(core)
    cmd(core, "MoveVelocity", Velocity=360.0, Direction=1)
    tr.until(lambda r: r["SetPos"] >= 100.0)
    n = cmd(core, "OrientedStop", Position=350.0)["CmdNo"]
    tr.step(3)
    r = cmd(core, "MoveRelative", Distance=30.0, Velocity=100.0, BufferMode=1)  # MC_Buffered
    assert r["error"] == 0
    m = r["CmdNo"]
    tr.settle()
    e = float(tr.rows[-1]["SetPos"])
    tr.step(50)
    assert tr.fate(n) == (ERROR, E.NC_TARGET_POSITION_NOT_ALLOWED) and tr.fate(m) == (ABORTED, 0)
    assert float(tr.rows[-1]["SetPos"]) == e and float(tr.rows[-1]["SetVelo"]) == 0.0, "the axis stands"
    assert not tr.rows[-1]["StateDWord"] & StateDWord.HasJob
    assert state(core) == S.MC_AXISSTATE_STANDSTILL
    assert cmd(core, "MoveRelative", Distance=-30.0, Velocity=100.0)["error"] == 0  # (the axis takes commands)


@pytest.mark.parametrize("sense", [1, -1])
def test_oriented_stop_of_an_axis_already_beyond_its_soft_limit_stops_it_and_ends_with_the_error(sense):
    """TcMC 3.16's fault condition also when the axis already stands beyond the limit and moves further
    out (MC_SetActualPositionOnTheFly just shifted it there): 0x4461 / 0x4460, the standard stop, the job
    ends ERROR with that code (before: refused, the velocity move went on)."""
    lim = dict(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=200.0) if sense > 0 else dict(
        AxisEnMinSoftPosLimit=True, AxisMinSoftPosLimit=-200.0)
    core = powered(Modulo=True, **lim)
    tr = Trace(core)
    cmd(core, "MoveVelocity", Velocity=20.0, Direction=POS if sense > 0 else NEG)
    tr.until(lambda r: sense * r["SetPos"] >= 10.0)
    p = float(core.axes.set_pos[0])
    # 1 u beyond the limit: within AxisMaxPosLagValue (5), so the monitoring takes no axis error
    assert cmd(core, "SetActualPositionOnTheFly", PreviousPosition=p, ActualPosition=sense * 201.0)["error"] == 0
    r = cmd(core, "OrientedStop", Position=90.0)  # (before the next cycle: the axis now stands at 201)
    assert r["error"] == 0, r
    n = r["CmdNo"]
    core.step()
    tr = Trace(core)  # (a new trace from the shifted position: the shift is a jump of SetPos)
    tr.settle()
    code = E.NC_SOFT_LIMIT_MAX_START if sense > 0 else E.NC_SOFT_LIMIT_MIN_START
    assert tr.fate(n) == (ERROR, code)
    assert (sense * tr.col("SetVelo") >= 0).all() and float(tr.rows[-1]["SetVelo"]) == 0.0
    assert sense * float(tr.rows[-1]["SetPos"]) < 205.0
    assert not core.nctoplc[0]["StateDWord"] & StateDWord.Error, "a command error, not an axis error"


# -- Override -------------------------------------------------------------------------------------
def test_plctonc_override_above_100_percent_is_an_axis_error():
    core = powered()
    tr = Trace(core)
    n = cmd(core, "MoveVelocity", Velocity=200.0, Direction=1)["CmdNo"]
    tr.step(200)
    power(core, override=1_000_001)
    r = tr.step()
    assert r["ErrorCode"] == E.NC_OVERRIDE_NOT_ALLOWED == 0x4238 and tr.fate(n) == (ERROR, 0x4238)
    assert state(core) == S.MC_AXISSTATE_ERRORSTOP
    tr.settle()
    assert tr.col("SetVelo").max() <= 200.0 * (1 + 1e-9)  # never faster than 100 %
    power(core)
    cmd(core, "Reset")  # set position := actual position
    tr.shift(float(tr.rows[-1]["ActPos"]) - float(tr.rows[-1]["SetPos"]))
    tr.step()
    assert tr.rows[-1]["ErrorCode"] == 0 and state(core) == S.MC_AXISSTATE_STANDSTILL


def test_plctonc_override_above_100_percent_at_rest():
    core = powered()
    power(core, override=2_000_000)
    core.step()
    assert core.nctoplc[0]["ErrorCode"] == 0x4238 and state(core) == S.MC_AXISSTATE_ERRORSTOP
    assert core.nctoplc[0]["SetVelo"] == 0.0


def test_set_actual_position_on_the_fly_before_the_homing_sets_the_position_changes_nothing():
    """The latched pulse is an NC position like the others: shifted with them, the homing's result is
    the same (it defines the positions)."""
    ends = []
    for shift in (0.0, 1000.0):
        core, tr, _ = homing_core()
        cmd(core, "Home", Position=500.0)
        tr.until(lambda r: int(r["HomingState"]) == int(H.SET_POSITION))
        if shift:
            cmd(core, "SetActualPositionOnTheFly", ActualPosition=shift, PreviousPosition=0.0)
            tr.shift(shift)
        tr.settle()
        ends.append(float(tr.rows[-1]["SetPos"]))
    assert ends[1] == pytest.approx(ends[0], abs=1e-9)


def test_homing_waits_for_the_falling_cam_edge_after_braking_beyond_a_narrow_cam():
    """Reference §1.6 HomingState: '4 wait for falling cam edge'. The search stops ~6 u beyond a
    1 u wide cam, i.e. off it: the latch is armed only after the cam has been passed again on the
    way towards the sync pulse (rising, then falling edge), not at once because the cam is FALSE."""
    cam = (-11.0, -10.0)
    core, tr, _ = homing_core(cam=cam)
    cmd(core, "Home", Position=500.0)
    tr.settle()
    hs = [int(x) for x in tr.col("HomingState")]
    assert changes(hs) == [1, 2, 3, 4, 5, 6, 0]
    act = tr.col("ActPos")
    k4, k5, k6 = (hs.index(s) for s in (4, 5, 6))
    assert act[k4] < cam[0], "braked beyond the cam (the scenario)"
    assert act[k5 - 2] <= cam[1] < act[k5 - 1], "latch armed after the falling edge on the way back"
    pulse = -10.0 + PULSE_OFFSET
    assert act[k6 - 2] < pulse <= act[k6 - 1]
    assert tr.rows[-1]["StateDWord"] & StateDWord.Homed
    assert 0 < float(tr.rows[-1]["SetPos"]) - 500.0 < stop_distance(20.0) + 3 * 20.0 * tr.dt + 0.05


def test_homing_on_in_the_search_direction_beyond_a_narrow_cam_does_not_wait_for_it():
    """Sync direction = search direction (both negative): the falling edge of a cam narrower than
    the braking distance lay in the braking (state 3), so state 4 does not wait for another one;
    the latch takes the next pulse on the way (zenoh-nc choice; the reference is silent)."""
    core, tr, _ = homing_core(cam=(-11.0, -10.0), AxisInvertSyncPulseSearchDirection=True)
    cmd(core, "Home", Position=500.0)
    tr.settle()
    hs = [int(x) for x in tr.col("HomingState")]
    assert changes(hs)[-3:] == [5, 6, 0] and tr.rows[-1]["StateDWord"] & StateDWord.Homed
    assert (tr.col("SetVelo") <= 0).all()


@pytest.mark.parametrize("search", [-1.0, 1.0])
def test_homing_judges_the_falling_cam_edge_by_the_actual_motion(search):
    """Reference §1.6 HomingState '4 wait for falling cam edge', with a lagging drive
    (SimTimeConstant 0.01): the set position stops still on the cam, the actual position overshoots
    beyond its far edge and the PLC's cam falls in state 4 while the axis still moves in the search
    direction. That fall is the far side, not the edge: the cam is crossed again on the way to the
    sync pulse (search opposite) and the latch takes the first pulse past the near edge (-9.75 /
    +9.25), not -14.75 / +14.25 beyond the cam. Both cam search directions (mirrored)."""
    far, near = -15.56 * -search, -10.0 * -search
    cam = (min(far, near), max(far, near))
    core, tr, _ = homing_core(cam=cam, SimTimeConstant=0.01,
                              AxisInvertCalibrationCamSearchDirection=search < 0,
                              AxisInvertSyncPulseSearchDirection=search > 0)
    cmd(core, "Home", Position=500.0)
    tr.settle()
    hs = [int(x) for x in tr.col("HomingState")]
    assert changes(hs) == [1, 2, 3, 4, 5, 6, 0]
    act = tr.col("ActPos") * -search  # mirrored to the negative search: the cam at [-15.56, -10]
    k4, k5, k6 = (hs.index(s) for s in (4, 5, 6))
    assert act[k4] >= -15.56 > act[k4:k5].min(), "the far edge was left in state 4 (the scenario)"
    assert act[k5 - 2] <= -10.0 < act[k5 - 1], "latch armed after the falling edge at the near side"
    pulse = -10.0 + PULSE_OFFSET if search < 0 else -(10.0 - (1.0 - PULSE_OFFSET))  # -9.75 (mirrored 9.25)
    assert act[k6 - 2] < pulse <= act[k6 - 1]
    assert tr.rows[-1]["StateDWord"] & StateDWord.Homed

