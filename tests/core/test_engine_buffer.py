"""BufferMode of the motion engine, cycle by cycle: the velocity when the first target is passed
(computed here from the PLCopen rule, not from the engine), the exact cycle in which the waiting job
takes over, the queue rules (one waiting job, Aborting replaces both, MC_Stop clears it) and the
fate of a waiting job that can no longer start. Every cycle is checked by engine_check.Trace."""
import math

import pytest

from nc_schema import CmdState, ControlDWord, ErrorCodes as E, MC_AxisStates as S, MC_AxisPara as P, StateDWord
from znc_testing.engine_check import Trace, cycles_for, ruckig_duration, velocity_at
from znc_testing.nc_core import ALL_ENABLES, cmd, power, powered, snapshot, state

BUFFERED, LOW, PREVIOUS, NEXT, HIGH = 1, 18, 19, 20, 21
DONE, ABORTED, ERROR = int(CmdState.DONE), int(CmdState.ABORTED), int(CmdState.ERROR)
P1, P2 = 100.0, 250.0
ACC, JERK = 5000.0, 50000.0  # the axis defaults


def blend_velocity(mode: int, v1: float, v2: float) -> float:
    """PLCopen Part 1: the velocity at the first target (directions equal, distances long enough)."""
    return {BUFFERED: 0.0, LOW: min(v1, v2), PREVIOUS: v1, NEXT: v2, HIGH: max(v1, v2)}[mode]


def ramp_distance(v_from: float, v_to: float, acc: float = ACC, jerk: float = JERK) -> float:
    """Distance a jerk-limited change v_from -> v_to at zero start/end acceleration covers."""
    dv = abs(v_to - v_from)
    t = 2 * math.sqrt(dv / jerk) if dv <= acc * acc / jerk else dv / acc + acc / jerk
    return 0.5 * (v_from + v_to) * t  # the ramp is point-symmetric about its middle


def ended(job_rec, k: int = 0) -> tuple[int, int, int]:
    e = job_rec["Ended"][k]
    return int(e["CmdNo"]), int(e["CmdState"]), int(e["ErrorId"])


def two_moves(mode: int, v1: float, v2: float, p1: float = P1, p2: float = P2, after: int = 5, **core_args):
    core = powered(**core_args)
    tr = Trace(core, vmax=max(v1, v2))
    r1 = cmd(core, "MoveAbsolute", Position=p1, Velocity=v1)
    tr.step(after)
    r2 = cmd(core, "MoveAbsolute", Position=p2, Velocity=v2, BufferMode=mode)
    assert r1["error"] == 0 and r2["error"] == 0 and r2["CmdNo"] == r1["CmdNo"] + 1
    return core, tr, r1["CmdNo"], r2["CmdNo"]


@pytest.mark.parametrize("v1,v2", [(100.0, 200.0), (200.0, 100.0)])
@pytest.mark.parametrize("mode", [BUFFERED, LOW, PREVIOUS, NEXT, HIGH])
def test_buffer_mode_transition(mode, v1, v2):
    core, tr, n1, n2 = two_moves(mode, v1, v2)
    tr.step()
    r, j = tr.rows[-1], tr.jobs[-1]
    # waiting: CmdBuffered, the record names it and its mode; the first job runs on
    assert r["StateDWord"] & StateDWord.CmdBuffered and int(j["BufferedCmdNo"]) == n2 and int(j["BufferedMode"]) == mode
    assert int(j["ActiveCmdNo"]) == n1 and int(j["ActiveState"]) == int(CmdState.ACTIVE)
    tr.settle()
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    pos = tr.col("SetPos")
    # the takeover cycle: the first one in which the set position reached the first target
    assert pos[k - 1] < P1 <= pos[k] + 1e-9
    v_exp = blend_velocity(mode, v1, v2)
    assert abs(float(tr.rows[k]["SetVelo"])) == pytest.approx(v_exp, abs=1e-6)
    assert velocity_at(tr, P1) == pytest.approx(v_exp, abs=ACC * tr.dt)
    # in that very cycle the first job is DONE in the record and the second is active
    assert ended(tr.jobs[k]) == (n1, DONE, 0)
    assert int(tr.jobs[k]["ActiveState"]) == int(CmdState.ACTIVE) and int(tr.jobs[k]["BufferedCmdNo"]) == 0
    assert not tr.rows[k]["StateDWord"] & StateDWord.CmdBuffered
    assert all(int(jj["BufferedCmdNo"]) == n2 and int(jj["ActiveCmdNo"]) == n1 for jj in tr.jobs[5:k])  # from the second command on
    # the first job keeps its own velocity until it has to change to the blending velocity
    vel = abs(tr.col("SetVelo"))
    before_ramp = pos[:k] <= P1 - ramp_distance(v1, v_exp) - 1e-6
    assert vel[:k][before_ramp].max() <= v1 * (1 + 1e-9)
    assert vel[:k].max() <= max(v1, v_exp) * (1 + 1e-9)
    assert vel[k:].max() <= max(v2, v_exp) * (1 + 1e-9)
    # the second ends exactly at its target, DONE; nothing moved backwards
    assert pos[-1] == P2 and int(tr.rows[-1]["CmdNo"]) == n2 and int(tr.rows[-1]["CmdState"]) == DONE
    assert (tr.col("SetVelo") >= -1e-9).all()
    assert tr.fate(n1) == (DONE, 0) and tr.fate(n2) == (DONE, 0)


def test_buffered_takes_over_in_the_cycle_the_first_plan_ends():
    """The cycle computed independently: the first plan's duration from ruckig itself."""
    core, tr, n1, n2 = two_moves(BUFFERED, 100.0, 200.0)
    tr.settle()
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    # the trace starts with the first command's first cycle (its set-point at t = dt)
    assert k == cycles_for(ruckig_duration(0.0, P1, 100.0, ACC, ACC, JERK), tr.dt) - 1
    assert float(tr.rows[k]["SetVelo"]) == 0.0 and float(tr.rows[k]["SetPos"]) == pytest.approx(P1, abs=1e-9)
    # and the second move's own duration from there
    k2 = tr.first(lambda r, j: int(r["CmdNo"]) == n2 and int(r["CmdState"]) == DONE)
    assert k2 - k == cycles_for(ruckig_duration(P1, P2, 200.0, ACC, ACC, JERK), tr.dt)


@pytest.mark.parametrize("mode", [LOW, PREVIOUS, NEXT, HIGH])
def test_blending_in_opposite_directions_passes_at_zero(mode):
    core, tr, n1, n2 = two_moves(mode, 100.0, 200.0, p2=20.0)
    tr.settle()
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    pos = tr.col("SetPos")
    assert float(tr.rows[k]["SetVelo"]) == 0.0 and pos[k] == pytest.approx(P1, abs=1e-9)
    assert pos.max() <= P1 + 1e-9  # never beyond the first target
    assert pos[-1] == 20.0 and tr.fate(n1) == (DONE, 0)


@pytest.mark.parametrize("mode", [LOW, HIGH])
def test_blending_issued_late_is_done_as_well_as_possible(mode):
    """Issued during the first move's braking ramp: no overshoot of the first target, no jump."""
    core = powered()
    tr = Trace(core, vmax=200.0)
    n1 = cmd(core, "MoveAbsolute", Position=P1, Velocity=200.0)["CmdNo"]
    tr.until(lambda r: r["SetPos"] > P1 - 2.0)
    n2 = cmd(core, "MoveAbsolute", Position=P2, Velocity=200.0, BufferMode=mode)["CmdNo"]
    tr.settle()
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    pos = tr.col("SetPos")
    assert pos[:k].max() <= P1 + 1e-9 and pos[-1] == P2 and tr.fate(n1) == (DONE, 0)


def test_a_second_buffered_command_is_refused_and_changes_nothing():
    core, tr, n1, n2 = two_moves(BUFFERED, 100.0, 100.0)
    tr.step()
    before, jobs = snapshot(core), core.ncjobs.tobytes()
    for mode in (BUFFERED, LOW, NEXT):
        rep = cmd(core, "MoveRelative", Distance=10.0, Velocity=50.0, BufferMode=mode)
        assert rep["error"] == E.NC_COMMAND_BUFFER_FULL == 0x4292 and "CmdNo" not in rep
    assert cmd(core, "MoveVelocity", Velocity=50.0, Direction=1, BufferMode=BUFFERED)["error"] == 0x4292
    assert snapshot(core) == before and core.ncjobs.tobytes() == jobs
    tr.settle()
    assert tr.rows[-1]["SetPos"] == P2 and int(tr.jobs[-1]["NewestCmdNo"]) == n2


def test_aborting_command_while_one_waits_aborts_both():
    core, tr, n1, n2 = two_moves(NEXT, 100.0, 200.0)
    tr.step(20)
    n3 = cmd(core, "MoveAbsolute", Position=-30.0, Velocity=150.0)["CmdNo"]
    assert n3 == n2 + 1
    r = tr.step()
    assert tr.fate(n1) == (ABORTED, 0) and tr.fate(n2) == (ABORTED, 0)
    assert int(r["CmdNo"]) == n3 and not r["StateDWord"] & StateDWord.CmdBuffered
    tr.settle()
    assert tr.rows[-1]["SetPos"] == -30.0 and int(tr.rows[-1]["CmdState"]) == DONE


def test_stop_clears_the_queue():
    core, tr, n1, n2 = two_moves(BUFFERED, 100.0, 200.0)
    tr.step(20)
    n3 = cmd(core, "Stop")["CmdNo"]
    r = tr.step()
    assert tr.fate(n1) == (ABORTED, 0) and tr.fate(n2) == (ABORTED, 0)
    assert int(r["CmdNo"]) == n3 and int(tr.jobs[-1]["BufferedCmdNo"]) == 0
    tr.settle()
    assert int(tr.rows[-1]["CmdState"]) == DONE and state(core) == S.MC_AXISSTATE_STOPPING
    assert tr.rows[-1]["SetPos"] < P1


def test_error_clears_the_queue():
    core, tr, n1, n2 = two_moves(BUFFERED, 100.0, 200.0)
    tr.step(20)
    core.fault(0, E.NC_POSITION_LAG)
    tr.step()
    assert tr.fate(n1) == (ERROR, E.NC_POSITION_LAG) and tr.fate(n2) == (ABORTED, 0)
    tr.settle()
    assert state(core) == S.MC_AXISSTATE_ERRORSTOP


@pytest.mark.parametrize("mode", [BUFFERED, HIGH])
def test_waiting_job_beyond_a_soft_limit_enabled_meanwhile_ends_error(mode):
    """A limit switched on while the job waits: it ends ERROR 0x4222 when it would start, the axis
    stops (a blended first move: with its own deceleration), no axis error."""
    core, tr, n1, n2 = two_moves(mode, 100.0, 200.0)
    assert cmd(core, "WriteParameter", ParameterNumber=int(P.SWLimitPos), Value=200.0)["error"] == 0
    assert cmd(core, "WriteParameter", ParameterNumber=int(P.EnableLimitPos), Value=True)["error"] == 0
    tr.settle()
    assert tr.fate(n1) == (DONE, 0) and tr.fate(n2) == (ERROR, E.NC_TARGET_POSITION_NOT_ALLOWED)
    r = tr.rows[-1]
    assert r["ErrorCode"] == 0 and not r["StateDWord"] & StateDWord.Error
    assert state(core) == S.MC_AXISSTATE_STANDSTILL
    assert tr.col("SetPos").max() <= 200.0
    if mode == BUFFERED:
        assert r["SetPos"] == pytest.approx(P1, abs=1e-9)
    # the axis takes commands again
    assert cmd(core, "MoveAbsolute", Position=0.0, Velocity=100.0)["error"] == 0


def test_waiting_job_without_its_feed_enable_ends_error():
    core = powered()
    tr = Trace(core)
    n1 = cmd(core, "MoveAbsolute", Position=-50.0, Velocity=100.0)["CmdNo"]
    tr.step(3)
    n2 = cmd(core, "MoveAbsolute", Position=50.0, Velocity=100.0, BufferMode=BUFFERED)["CmdNo"]
    tr.step(3)
    power(core, ctrl=int(ControlDWord.Enable | ControlDWord.FeedEnableMinus))  # plus withdrawn
    tr.settle()
    assert tr.fate(n1) == (DONE, 0) and tr.fate(n2) == (ERROR, E.NC_NO_ENABLE)
    assert tr.rows[-1]["ErrorCode"] == 0 and tr.rows[-1]["SetPos"] == pytest.approx(-50.0, abs=1e-9)
    assert state(core) == S.MC_AXISSTATE_STANDSTILL


def test_buffered_behind_move_velocity_starts_when_the_velocity_is_reached():
    core = powered()
    tr = Trace(core, vmax=150.0)
    n1 = cmd(core, "MoveVelocity", Velocity=150.0, Direction=1)["CmdNo"]
    n2 = cmd(core, "MoveRelative", Distance=100.0, Velocity=50.0, BufferMode=BUFFERED)["CmdNo"]
    assert n2 == n1 + 1
    tr.settle()
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    v = tr.col("SetVelo")
    assert v[k - 1] < 150.0 and v[k] == pytest.approx(150.0, abs=1e-9)  # the velocity was just reached
    assert ended(tr.jobs[k]) == (n1, DONE, 0)
    # the velocity ramp's duration, independently (ruckig in velocity control would be the same:
    # a ramp 0 -> 150 with acc 5000 / jerk 50000 is triangular in acceleration)
    assert (k + 1) * tr.dt == pytest.approx(2 * math.sqrt(150.0 / JERK), abs=tr.dt)
    # the relative distance refers to the set position where the buffered job started
    start = float(tr.rows[k]["SetPos"])
    assert tr.rows[-1]["SetPos"] == pytest.approx(start + 100.0, abs=1e-9)


def test_buffered_halt_behind_move_velocity():
    core = powered()
    tr = Trace(core, vmax=150.0)
    n1 = cmd(core, "MoveVelocity", Velocity=150.0, Direction=3)["CmdNo"]
    tr.step(10)
    n2 = cmd(core, "Halt", BufferMode=BUFFERED)["CmdNo"]
    tr.step()
    assert int(tr.jobs[-1]["BufferedCmdNo"]) == n2
    tr.settle()
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    assert float(tr.rows[k]["SetVelo"]) == pytest.approx(-150.0, abs=1e-9)
    assert tr.fate(n1) == (DONE, 0) and int(tr.rows[-1]["CmdState"]) == DONE and int(tr.rows[-1]["CmdNo"]) == n2
    assert state(core) == S.MC_AXISSTATE_STANDSTILL


def test_buffered_halt_behind_a_move_ends_at_rest_one_cycle_later():
    """The Halt takes over in the cycle the move reaches its target (the move is Done then), finds nothing to stop
    and is Done in the next cycle, at the target (an Aborting Halt would have stopped short)."""
    core = powered()
    tr = Trace(core, vmax=100.0)
    n1 = cmd(core, "MoveAbsolute", Position=150.0, Velocity=100.0)["CmdNo"]
    tr.step(10)
    n2 = cmd(core, "Halt", BufferMode=BUFFERED)["CmdNo"]
    tr.settle()
    k = tr.first(lambda r, j: int(j["ActiveCmdNo"]) == n2)
    assert ended(tr.jobs[k]) == (n1, DONE, 0) and float(tr.rows[k]["SetPos"]) == 150.0
    assert ended(tr.jobs[k + 1]) == (n2, DONE, 0) and float(tr.rows[k + 1]["SetPos"]) == 150.0
    assert state(core) == S.MC_AXISSTATE_STANDSTILL


def test_buffered_after_a_finished_job_starts_at_once():
    """Nothing active any more: a buffered command is simply the next job."""
    core = powered()
    tr = Trace(core)
    cmd(core, "MoveAbsolute", Position=10.0, Velocity=100.0)
    tr.settle()
    n = cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0, BufferMode=LOW)["CmdNo"]
    r = tr.step()
    assert int(r["CmdNo"]) == n and int(r["CmdState"]) == int(CmdState.ACTIVE) and not r["StateDWord"] & StateDWord.CmdBuffered
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 20.0


def test_override_zero_holds_a_buffered_sequence():
    core, tr, n1, n2 = two_moves(BUFFERED, 100.0, 200.0)
    tr.step(300)
    power(core, override=0)
    tr.until(lambda r: r["SetVelo"] == 0.0 and r["SetPos"] < P1, 3000)
    tr.step(500)  # held: nothing moves, nothing takes over
    r = tr.rows[-1]
    assert r["SetPos"] < P1 and r["StateDWord"] & StateDWord.CmdBuffered and int(r["CmdNo"]) == n1
    assert int(r["CmdState"]) == int(CmdState.ACTIVE)
    power(core)
    tr.settle()
    assert tr.rows[-1]["SetPos"] == P2 and tr.fate(n1) == (DONE, 0)


@pytest.mark.parametrize("mode,ov", [(LOW, 0.5), (NEXT, 0.5), (PREVIOUS, 0.25)])
def test_override_during_a_blend_scales_the_blending_velocity(mode, ov):
    """The blending velocity follows the override like the travel velocities: passed at rule * override."""
    v1, v2 = 100.0, 200.0
    core, tr, n1, n2 = two_moves(mode, v1, v2)
    tr.step(100)
    power(core, override=round(ov * 1_000_000))
    tr.until(lambda r: int(r["CmdNo"]) == n2)
    assert velocity_at(tr, P1) == pytest.approx(blend_velocity(mode, v1, v2) * ov, abs=ACC * tr.dt)
    tr.settle()
    assert tr.rows[-1]["SetPos"] == P2


@pytest.mark.parametrize("mode", [LOW, NEXT])
def test_override_dip_before_a_blend_does_not_lower_it_for_good(mode):
    """Override down and up again before the first target: passed with the full blending velocity."""
    v1, v2 = 100.0, 200.0
    core, tr, n1, n2 = two_moves(mode, v1, v2, p1=200.0, p2=400.0)
    tr.step(100)
    power(core, override=300_000)
    tr.step(200)
    power(core)
    tr.until(lambda r: int(r["CmdNo"]) == n2)
    assert velocity_at(tr, 200.0) == pytest.approx(blend_velocity(mode, v1, v2), abs=ACC * tr.dt)
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 400.0



def _counting_plans(core):
    """Wrap ``core.plan``: returns the list of (planning function, end velocity of a plan_position)."""
    calls = []
    orig = core.plan

    def counting(fn, *args):
        calls.append((fn.__name__, args[-1] if fn.__name__ == "plan_position" else None))
        return orig(fn, *args)

    core.plan = counting
    return calls


def test_override_replan_of_an_unreachable_blend_makes_no_more_plans_than_halving():
    """P0 -> P1 = 20 at 100, then 400 BlendingNext: 400 at P1 is not reachable. On the command path (the
    buffered command, between cycles) the highest end velocity that fits is searched (~271 u/s); an
    override change re-plans in the cycle with the halving only: 360 (90 %) does not fit, 180 does --
    the 4 plans (2 velocity ramps of the end-velocity check, 2 positionings) of the code before the
    search (03e5cb4), never the 8 bisections more (12 plans)."""
    core = powered()
    r1 = cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0)
    for _ in range(5):
        core.step()
    on_command = _counting_plans(core)
    r2 = cmd(core, "MoveAbsolute", Position=300.0, Velocity=400.0, BufferMode=NEXT)
    assert r1["error"] == 0 and r2["error"] == 0
    ends = [v for f, v in on_command if f == "plan_position"]
    assert any(200.0 < v < 400.0 for v in ends), ends  # the command path searched (the scenario needs it)
    del core.plan
    for _ in range(5):
        core.step()
    assert core.nctoplc[0]["SetPos"] < 20.0 and int(core.ncjobs[0]["BufferedCmdNo"]) == r2["CmdNo"]
    in_cycle = _counting_plans(core)
    power(core, override=900_000)
    core.step()
    assert in_cycle == [("plan_velocity", None), ("plan_velocity", None),
                        ("plan_position", 360.0), ("plan_position", 180.0)], in_cycle
    del core.plan
    tr = Trace(core, vmax=400.0)
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 300.0 and tr.fate(r2["CmdNo"]) == (DONE, 0)

def test_blending_into_move_velocity():
    """A velocity job behind a position job with BlendingNext: reached at the first target."""
    core = powered()
    tr = Trace(core, vmax=200.0)
    n1 = cmd(core, "MoveAbsolute", Position=P1, Velocity=100.0)["CmdNo"]
    n2 = cmd(core, "MoveVelocity", Velocity=200.0, Direction=1, BufferMode=NEXT)["CmdNo"]
    tr.until(lambda r: int(r["CmdNo"]) == n2)
    assert velocity_at(tr, P1) == pytest.approx(200.0, abs=ACC * tr.dt)
    assert tr.fate(n1) == (DONE, 0)
    tr.step(50)
    assert tr.rows[-1]["StateDWord"] & StateDWord.ContinuousMotion and tr.rows[-1]["SetVelo"] == pytest.approx(200.0)


def test_relative_moves_buffered_refer_to_the_previous_target():
    core = powered()
    tr = Trace(core)
    cmd(core, "MoveRelative", Distance=40.0, Velocity=100.0)
    tr.step(50)
    n2 = cmd(core, "MoveRelative", Distance=25.0, Velocity=100.0, BufferMode=LOW)["CmdNo"]
    tr.settle()
    assert tr.rows[-1]["SetPos"] == 65.0 and int(tr.rows[-1]["CmdNo"]) == n2


def test_move_velocity_buffered_behind_move_velocity():
    core = powered()
    tr = Trace(core, vmax=200.0)
    n1 = cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)["CmdNo"]
    n2 = cmd(core, "MoveVelocity", Velocity=200.0, Direction=1, BufferMode=BUFFERED)["CmdNo"]
    tr.until(lambda r: int(r["CmdNo"]) == n2)
    k = len(tr.rows) - 1
    assert float(tr.rows[k]["SetVelo"]) == pytest.approx(100.0, abs=1e-9) and ended(tr.jobs[k]) == (n1, DONE, 0)
    tr.until(lambda r: abs(float(r["SetVelo"]) - 200.0) < 1e-9)
    assert tr.rows[-1]["StateDWord"] & StateDWord.ContinuousMotion and int(tr.rows[-1]["CmdState"]) == int(CmdState.ACTIVE)


def test_enable_off_aborts_the_active_and_the_waiting_job():
    core, tr, n1, n2 = two_moves(LOW, 100.0, 200.0)
    tr.step(50)
    power(core, ctrl=0)
    r = tr.step()
    assert tr.fate(n1) == (ABORTED, 0) and tr.fate(n2) == (ABORTED, 0)
    assert state(core) == S.MC_AXISSTATE_DISABLED and not r["StateDWord"] & StateDWord.CmdBuffered


def test_cmdno_wraps_with_a_waiting_job():
    core = powered()
    core.queues[0].newest = 65534
    tr = Trace(core)
    n1 = cmd(core, "MoveAbsolute", Position=10.0, Velocity=100.0)["CmdNo"]
    n2 = cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0, BufferMode=BUFFERED)["CmdNo"]
    assert (n1, n2) == (65535, 1)
    tr.settle()
    assert tr.fate(65535) == (DONE, 0) and tr.fate(1) == (DONE, 0) and int(tr.rows[-1]["CmdNo"]) == 1
