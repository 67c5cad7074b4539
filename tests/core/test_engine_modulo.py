"""MoveModulo through the engine, cycle by cycle: the direction rules (never against the requested
direction, except inside the modulo tolerance window, TcMC 3.5), full turns, MC_Current_Direction
while moving and behind another job, a buffered modulo move refers to the previous target; a start during
motion never reverses it (the first position with the modulo value at or beyond the rest point, in the current
direction, whatever Direction says, without extra turns)."""
import math

import pytest

from nc_schema import CmdState, ErrorCodes as E
from nc_server.core.planning import Dynamics, plan_velocity
from znc_testing.engine_check import Trace
from znc_testing.nc_core import cmd, powered, snapshot

POS, SHORT, NEG, CURRENT = 1, 2, 3, 4
DONE = int(CmdState.DONE)
FAST = dict(AxisVeloMax=3600.0, AxisAcc=36000.0, AxisDec=36000.0, AxisJerk=360000.0)


def at(start, tolerance=0.0):
    core = powered(Modulo=True, AxisModuloToleranceWindow=tolerance, **FAST)
    if start:
        cmd(core, "MoveAbsolute", Position=start, Velocity=3600.0)
        while core.moving.any():
            core.step()
    return core, Trace(core)


@pytest.mark.parametrize("direction,start,target,tol,end", [
    # TcMC 3.5 tables: (direction, absolute start, modulo target, window, absolute end)
    (POS, 90.0, 0.0, 0.0, 360.0), (POS, 90.0, 720.0, 0.0, 1080.0), (NEG, 90.0, 0.0, 0.0, 0.0),
    (NEG, 90.0, 360.0, 0.0, -360.0), (SHORT, 90.0, 0.0, 0.0, 0.0), (SHORT, 300.0, 10.0, 0.0, 370.0),
    (POS, 91.1, 90.0, 1.0, 450.0), (POS, 88.9, 450.0, 1.0, 450.0), (NEG, 88.9, 90.0, 1.0, -270.0),
    (NEG, 91.1, 450.0, 1.0, -270.0),
])
def test_modulo_moves_keep_their_direction(direction, start, target, tol, end):
    core, tr = at(start, tol)
    n = cmd(core, "MoveModulo", Position=target, Velocity=720.0, Direction=direction)["CmdNo"]
    tr.settle()
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(end, abs=1e-9)
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE
    v = tr.col("SetVelo")
    sense = 1.0 if end > start else -1.0
    assert (sense * v >= 0).all()  # one direction all the way
    if direction in (POS, NEG):
        assert sense == (1.0 if direction == POS else -1.0)


@pytest.mark.parametrize("direction,start,end", [(POS, 90.9, 90.0), (NEG, 89.1, 90.0)])
def test_inside_the_tolerance_window_a_small_move_against_the_direction(direction, start, end):
    core, tr = at(start, 1.0)
    cmd(core, "MoveModulo", Position=90.0, Velocity=720.0, Direction=direction)
    tr.settle()
    pos = tr.col("SetPos")
    assert pos[-1] == pytest.approx(end, abs=1e-9) and abs(pos - start).max() <= 1.0 + 1e-9


@pytest.mark.parametrize("direction,start,target,end", [
    (NEG, 359.5, 0.0, 360.0), (NEG, 359.5, 360.0, 0.0), (POS, 360.5, 359.8, 359.8),
])
def test_the_tolerance_window_reaches_across_the_period_boundary(direction, start, target, end):
    """TcMC 3.5: the window is "set position +/- tolerance value": at 359.5 with a window of 1, a target
    of 0 is 0.5 ahead (a small move against a negative direction), not a turn back to 0."""
    core, tr = at(start, 1.0)
    cmd(core, "MoveModulo", Position=target, Velocity=720.0, Direction=direction)
    tr.settle()
    pos = tr.col("SetPos")
    assert pos[-1] == pytest.approx(end, abs=1e-9)
    if abs(end - start) <= 1.0:
        assert abs(pos - start).max() <= 1.0 + 1e-9


@pytest.mark.parametrize("direction", [POS, NEG])
@pytest.mark.parametrize("start,target", [(-912.736, 54.4), (4109.878, 4.86), (382.601, 231.8), (480.505, 201.3)])
def test_the_same_modulo_target_again_does_not_move(direction, start, target):
    """TcMC 3.5: "No motion occurs if target position and starting position are identical", also when the
    set position holds the target's modulo value as another sum of floats than the new target's."""
    core, tr = at(start)
    cmd(core, "MoveModulo", Position=target, Velocity=720.0, Direction=direction)
    tr.settle()
    reached = float(tr.rows[-1]["SetPos"])
    n = cmd(core, "MoveModulo", Position=target, Velocity=720.0, Direction=direction)["CmdNo"]
    tr.settle()
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(reached, abs=1e-9)
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE


@pytest.mark.parametrize("direction", [POS, NEG])
@pytest.mark.parametrize("period,target,tol", [
    (0.1, 0.3, 0.0), (3.6, 46.8, 0.0), (2 * math.pi, 22 * math.pi, 0.0), (2 * math.pi, 22 * math.pi, 0.01),
    (100.1, 300.3, 0.0), (0.1, 0.3, 0.01),
])
def test_a_whole_number_of_periods_makes_as_many_turns(direction, period, target, tol):
    """TcMC 3.5: "Target positions of more than 360 degrees lead to one or more full turns": from 0 a
    target of k periods makes k turns also where target / period rounds to k - 0.000...1 (0.3 / 0.1)."""
    core = powered(Modulo=True, AxisEncoderModuloValue=period, AxisModuloToleranceWindow=tol, **FAST)
    tr = Trace(core)
    n = cmd(core, "MoveModulo", Position=target, Velocity=720.0, Direction=direction)["CmdNo"]
    tr.settle()
    sense = 1.0 if direction == POS else -1.0
    assert float(tr.rows[-1]["SetPos"]) / period == pytest.approx(sense * round(target / period), abs=1e-9)
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE
    assert (sense * tr.col("SetVelo") >= 0).all()


@pytest.mark.parametrize("direction,offset", [(POS, 1e-7), (POS, 1e-10), (NEG, -1e-7), (NEG, -1e-10)])
def test_slightly_past_the_target_without_a_window_is_a_full_turn(direction, offset):
    """TcMC 3.5: "if the set position ... is slightly more than 90 deg, the same travel command leads to a
    full turn" (the mirror in the negative direction): with window 0 no hidden window but a rounding
    margin of a few LSBs (1e-10 at 90 deg is some 900 LSBs)."""
    core, tr = at(90.0 + offset)
    assert float(core.axes.set_pos[0]) == 90.0 + offset
    cmd(core, "MoveModulo", Position=90.0, Velocity=720.0, Direction=direction)
    tr.settle()
    sense = 1.0 if direction == POS else -1.0
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(90.0 + sense * 360.0, abs=1e-9)
    assert (sense * tr.col("SetVelo") >= 0).all()


@pytest.mark.parametrize("velocity_direction,end", [(POS, 720.0 + 45.0), (NEG, -720.0 + 45.0)])
def test_current_direction_while_moving(velocity_direction, end):
    core, tr = at(0.0)
    cmd(core, "MoveVelocity", Velocity=720.0, Direction=velocity_direction)
    tr.step(30)
    tr.until(lambda r: abs(float(r["SetPos"])) > 500.0 and abs(float(r["SetPos"])) < 600.0)
    cmd(core, "MoveModulo", Position=45.0, Velocity=720.0, Direction=CURRENT)
    tr.settle()
    sense = 1.0 if velocity_direction == POS else -1.0
    assert (sense * tr.col("SetVelo") >= 0).all()  # no reversal
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(end, abs=1e-9)


@pytest.mark.parametrize("mode", [1, 20])
def test_buffered_modulo_move_refers_to_the_previous_target(mode):
    core, tr = at(0.0)
    cmd(core, "MoveAbsolute", Position=100.0, Velocity=720.0)
    cmd(core, "MoveModulo", Position=30.0, Velocity=720.0, Direction=POS, BufferMode=mode)
    tr.settle()
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(390.0, abs=1e-9)
    assert (tr.col("SetVelo") >= 0).all()


@pytest.mark.parametrize("mode", [1, 20])
def test_buffered_current_direction_follows_the_previous_move(mode):
    """MC_Current_Direction of a job behind a negative move: on in the negative direction (a blend
    then passes the first target moving, instead of turning)."""
    core, tr = at(0.0)
    n1 = cmd(core, "MoveAbsolute", Position=-100.0, Velocity=720.0)["CmdNo"]
    cmd(core, "MoveModulo", Position=200.0, Velocity=720.0, Direction=CURRENT, BufferMode=mode)
    tr.settle()
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(-160.0, abs=1e-9)
    assert (tr.col("SetVelo") <= 0).all() and tr.fate(n1) == (DONE, 0)


def test_modulo_refusals_change_nothing():
    core, tr = at(90.0)
    cmd(core, "MoveVelocity", Velocity=100.0, Direction=POS)
    tr.step(10)
    before = snapshot(core)
    assert cmd(core, "MoveModulo", Position=400.0, Velocity=10.0, Direction=SHORT)["error"] == E.NC_MODULO_TARGET_INVALID
    assert cmd(core, "MoveModulo", Position=-1.0, Velocity=10.0, Direction=POS)["error"] == E.NC_MODULO_TARGET_INVALID
    assert cmd(core, "MoveModulo", Position=1.0, Velocity=10.0, Direction=128)["error"] == E.MC_INVALID_MODE
    assert snapshot(core) == before


# -- a start during motion (Tc2_MC2 MC_MoveModulo: "The direction of movement cannot be reversed by
# MC_MoveModulo ... The user is not able to specify the number of additional turns ... on the shortest
# possible path"): the first position with the modulo value at or beyond the rest point, in the current
# direction (ModuloKind). From 720 u/s with Deceleration 3600 and Jerk 36000 the axis needs
# 720 * (720 / 3600 + 3600 / 36000) / 2 = 108 u to come to rest.
OWN = dict(Deceleration=3600.0, Jerk=36000.0)


def moving(sense, **params):
    """An axis moving at 720 u/s in direction ``sense`` past |500|: (core, trace, set position)."""
    core = powered(Modulo=True, AxisModuloToleranceWindow=0.0, **{**FAST, **params})
    tr = Trace(core)
    cmd(core, "MoveVelocity", Velocity=720.0, Direction=POS if sense > 0 else NEG)
    tr.until(lambda r: sense * float(r["SetPos"]) > 500.0)
    assert float(core.axes.set_velo[0]) == pytest.approx(sense * 720.0)
    return core, tr, float(core.axes.set_pos[0])


def modulo_of(p):
    return p % 360.0


def ends_moving_on(core, tr, n, sense, end):
    """Job ``n`` ends DONE at ``end``; the set velocity never turned against ``sense`` (every cycle)."""
    tr.settle()
    v = tr.col("SetVelo")
    assert (sense * v >= 0.0).all(), f"reversed: {v.min() if sense > 0 else v.max()} u/s"
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(end, abs=1e-9)
    assert tr.fate(n) == (DONE, 0) or (int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE)


@pytest.mark.parametrize("sense", [1.0, -1.0])
@pytest.mark.parametrize("ahead,travel", [
    (20.0, 380.0),    # within the 108 u to rest: one period further
    (100.0, 460.0),   # just within
    (130.0, 130.0),   # just beyond: reached in this period (the shortest path)
])
def test_a_moving_start_never_reverses(sense, ahead, travel):
    core, tr, p0 = moving(sense)
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + sense * ahead), Velocity=720.0,
            Direction=POS if sense > 0 else NEG, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, sense, p0 + sense * travel)


@pytest.mark.parametrize("sense", [1.0, -1.0])
@pytest.mark.parametrize("ahead,travel", [(20.0, 380.0), (-100.0, 260.0), (130.0, 130.0)])
def test_an_opposite_direction_does_not_reverse_a_moving_axis(sense, ahead, travel):
    """Direction against the motion: the current direction wins (a target behind: on to it)."""
    core, tr, p0 = moving(sense)
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + sense * ahead), Velocity=720.0,
            Direction=NEG if sense > 0 else POS, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, sense, p0 + sense * travel)


@pytest.mark.parametrize("sense", [1.0, -1.0])
@pytest.mark.parametrize("ahead,travel", [(20.0, 380.0), (-30.0, 330.0), (170.0, 170.0)])
def test_shortest_way_while_moving_goes_on_in_the_current_direction(sense, ahead, travel):
    core, tr, p0 = moving(sense)
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + sense * ahead), Velocity=720.0, Direction=SHORT,
            **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, sense, p0 + sense * travel)


@pytest.mark.parametrize("sense", [1.0, -1.0])
@pytest.mark.parametrize("ahead,turns,travel", [(130.0, 1, 130.0), (130.0, 2, 130.0), (20.0, 2, 380.0)])
def test_a_moving_start_adds_no_turns(sense, ahead, turns, travel):
    """Position >= period while moving: its modulo value only ("not able to specify the number of
    additional turns")."""
    core, tr, p0 = moving(sense)
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + sense * ahead) + turns * 360.0, Velocity=720.0,
            Direction=POS if sense > 0 else NEG, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, sense, p0 + sense * travel)


@pytest.mark.parametrize("sense", [1.0, -1.0])
def test_a_moving_start_comes_to_rest_with_the_axis_dynamics_for_0(sense):
    """Deceleration/Jerk 0: AxisDec 36000, AxisJerk 360000 (43.2 u to rest from 720 u/s): 100 ahead is
    reached in this period, where the move's own 3600/36000 need 108 u (above: one period further)."""
    core, tr, p0 = moving(sense)
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + sense * 100.0), Velocity=720.0, Direction=CURRENT)["CmdNo"]
    ends_moving_on(core, tr, n, sense, p0 + sense * 100.0)


def test_a_moving_start_behind_a_move_velocity_does_not_reverse():
    """Buffered behind MC_MoveVelocity (no target: it starts once the velocity is reached, moving)."""
    core, tr, p0 = moving(1.0)
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + 20.0), Velocity=720.0, Direction=POS, BufferMode=1,
            **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, 1.0, p0 + 380.0)


@pytest.mark.parametrize("sense", [1.0, -1.0])
def test_a_queued_target_behind_the_rest_point_of_a_continuous_move(sense):
    """Behind MC_MoveContinuousAbsolute (passes +-100 at 720 u/s and goes on): the queued target +-110 (from
    the previous target, in its direction) lies within the way to rest: the moving rule, +-470."""
    core, tr = at(0.0)
    cmd(core, "MoveContinuousAbsolute", Position=sense * 100.0, Velocity=720.0, EndVelocity=720.0)
    n = cmd(core, "MoveModulo", Position=modulo_of(sense * 110.0), Velocity=720.0,
            Direction=POS if sense > 0 else NEG, BufferMode=1, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, sense, sense * 470.0)


@pytest.mark.parametrize("sense,position,end", [
    (1.0, 390.0, 750.0),     # Position 390 from 100: 390 and the turn asked for
    (-1.0, 690.0, -750.0),   # 690 = 330 + a turn, negative from -100: -390 and the turn
    (-1.0, 250.0, -110.0),   # no turn asked for
])
def test_a_blending_successor_keeps_its_queued_target_and_turns(sense, position, end):
    """BlendingNext behind a move to +-100: the target refers to the previous one with the standstill
    rules, the blend passes +-100 moving on (the moving rule would end within the first period)."""
    core, tr = at(0.0)
    cmd(core, "MoveAbsolute", Position=sense * 100.0, Velocity=720.0)
    n = cmd(core, "MoveModulo", Position=position, Velocity=720.0, Direction=POS if sense > 0 else NEG,
            BufferMode=20, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, sense, end)
    assert sense * tr.col("SetVelo")[tr.first(lambda r, j: sense * float(r["SetPos"]) >= 100.0)] > 100.0


@pytest.mark.parametrize("kind", ["MoveModulo", "MoveAbsolute"])
@pytest.mark.parametrize("sense", [1.0, -1.0])
@pytest.mark.parametrize("d", [108.01, 108.3, 108.5])
def test_a_blending_successor_can_stop_from_where_it_takes_over(kind, sense, d):
    """The successor needs 108 u to rest from 720 u/s and its target lies d (a little more) beyond the
    predecessor's: it takes over at the cycle boundary after that target, up to 0.72 u (a cycle at 720 u/s)
    on, so the blend velocity leaves room for that cycle (``JobKind.blend_velocity``). Otherwise the rest
    point lies beyond the target: a MoveModulo counted as moving made a full turn more, a MoveAbsolute
    passed its target and came back."""
    core, tr = at(0.0)
    cmd(core, "MoveAbsolute", Position=sense * 100.3, Velocity=720.0)
    end = sense * (100.3 + d)
    if kind == "MoveModulo":
        args = dict(Position=modulo_of(end), Direction=POS if sense > 0 else NEG)
    else:
        args = dict(Position=end)
    n = cmd(core, kind, Velocity=720.0, BufferMode=20, **args, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, sense, end)
    assert sense * tr.col("SetVelo")[tr.first(lambda r, j: sense * float(r["SetPos"]) >= 100.3)] > 100.0


@pytest.mark.parametrize("sense", [1.0, -1.0])
def test_a_software_limit_before_the_moving_target_refuses_the_start(sense):
    """The computed end (one period on) beyond the software limit +-750 (the axis passes +-500 when the
    command comes): refused as a MoveAbsolute there, nothing changes; p0 +- 130 inside it starts."""
    limit = dict(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=750.0) if sense > 0 else \
        dict(AxisEnMinSoftPosLimit=True, AxisMinSoftPosLimit=-750.0)
    core, tr, p0 = moving(sense, **limit)
    direction = POS if sense > 0 else NEG
    before = snapshot(core)
    got = cmd(core, "MoveModulo", Position=modulo_of(p0 + sense * 20.0), Velocity=720.0, Direction=direction,
              **OWN)["error"]
    assert got and got == cmd(core, "MoveAbsolute", Position=p0 + sense * 380.0, Velocity=720.0, **OWN)["error"]
    assert snapshot(core) == before
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + sense * 130.0), Velocity=720.0, Direction=direction,
            **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, sense, p0 + sense * 130.0)


def test_a_start_at_rest_after_a_motion_keeps_the_direction():
    """At rest (MC_Halt ended) the standstill rules again: a negative direction turns back."""
    core, tr, _ = moving(1.0)
    cmd(core, "Halt")
    tr.settle()
    p0 = float(core.axes.set_pos[0])
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + 20.0), Velocity=720.0, Direction=NEG)["CmdNo"]
    tr.settle()
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(p0 - 340.0, abs=1e-9)
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE


def test_a_moving_start_prepared_is_computed_from_its_activation_state():
    """Prepared (SVB) while moving and activated at the cycle boundary: the same as an execute, cycle by
    cycle. Prepared 120 u before the target (beyond the 108 u to rest: this period), 30 cycles (21.6 u) on
    the target lies within the way to rest: the old preparation is not activated, prepared again it ends
    one period further, as the execute."""
    from nc_schema import make_request, parse_request
    a, ta, p0 = moving(1.0)
    b, tb, q0 = moving(1.0)
    assert p0 == q0
    args = dict(Position=modulo_of(p0 + 120.0), Velocity=720.0, Direction=POS, **OWN)

    def req(rid):
        return parse_request(make_request("MoveModulo", 900 + rid, "t", **args))

    stale = a.prepare(req(0), 1)
    for tr in (ta, tb):
        tr.step(30)
    assert a.activate(stale) is None
    assert a.activate(a.prepare(req(1), 1))["error"] == 0 and b.execute(req(1), 1)["error"] == 0
    for _ in range(2000):
        ta.step()
        tb.step()
        assert snapshot(a) == snapshot(b)
    ends_moving_on(a, ta, int(ta.rows[-1]["CmdNo"]), 1.0, p0 + 480.0)


# -- a motion committed to a turn: a positioning to 50 u behind an axis at 720 u/s (AxisDec 36000, AxisJerk
# 360000) brakes so hard that, in its last cycles before the velocity crosses 0, no plan with that jerk can
# stop the axis without turning (a^2 / 2j > v). MC_MoveModulo (moving rule) and MC_OrientedStop then end in
# the direction after the turn, at or beyond the rest point of that plan (modulo_beyond_stop): one reversal,
# the one the axis must make, none back.
AXIS_DYN = Dynamics(3600.0, 36000.0, 36000.0, 360000.0)


def reversing(cycles_before_crossing, committed=True):
    """(core, trace from now on, start state) ``cycles_before_crossing`` cycles before the set velocity of a
    reversing MoveAbsolute crosses 0."""
    def setup():
        core = powered(Modulo=True, AxisModuloToleranceWindow=0.0, **FAST)
        cmd(core, "MoveVelocity", Velocity=720.0, Direction=POS)
        while float(core.axes.set_pos[0]) < 500.0:
            core.step()
        cmd(core, "MoveAbsolute", Position=float(core.axes.set_pos[0]) - 50.0, Velocity=720.0,
            Deceleration=36000.0, Jerk=360000.0)
        return core
    twin, n = setup(), 0
    while float(twin.axes.set_velo[0]) > 0.0:
        twin.step()
        n += 1
    core = setup()
    for _ in range(n - cycles_before_crossing):
        core.step()
    st = core.start_state(0)
    assert st.v > 0.0 and (st.a * st.a / (2 * 360000.0) > st.v) == committed  # (committed to the turn)
    return core, Trace(core), st


def turns_once_to(tr, st, position, max_cycles):
    """Ends at rest at the first position with the modulo value ``position`` at or below the end of the plan
    to rest from ``st`` (axis dynamics), with one reversal (positive, then negative), within ``max_cycles``
    (settle raises beyond)."""
    tr.settle(max_cycles)
    rest_end = plan_velocity(st, 0.0, AXIS_DYN).end.p
    end = float(tr.rows[-1]["SetPos"])
    assert rest_end - 360.0 < end <= rest_end + 1e-9
    assert modulo_of(end) == pytest.approx(position, abs=1e-6) or modulo_of(end) == pytest.approx(position + 360.0, abs=1e-6)
    v = tr.col("SetVelo")
    assert (v < -1e-9).any()
    first_back = int((v < -1e-9).argmax())  # (the first traced cycle may be past the crossing already)
    assert (v[:first_back] >= -1e-9).all() and (v[first_back:] <= 1e-9).all(), "turned back again"
    return end


@pytest.mark.parametrize("k,offset,direction,travel", [
    (3, -0.5, NEG, -360.5),   # (before: -0.5, past it and back; h2b at bad5e91: +359.5, two reversals)
    (3, 0.5, POS, -359.5),    # the direction after the turn wins over POS
    (10, -30.0, NEG, -30.0),  # the rest point lies above p0 - 30: reached in this period
    (10, -0.5, SHORT, -360.5),
])
def test_a_moving_start_committed_to_a_turn_goes_on_after_it(k, offset, direction, travel):
    core, tr, st = reversing(k)
    position = modulo_of(st.p + offset)
    n = cmd(core, "MoveModulo", Position=position, Velocity=720.0, Direction=direction)["CmdNo"]
    end = turns_once_to(tr, st, position, 5000)
    assert end == pytest.approx(st.p + travel, abs=1e-6)
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE


@pytest.mark.parametrize("k", [1, 3, 10])
@pytest.mark.parametrize("offset,travel", [(0.5, -359.5), (-0.5, -360.5), (5.0, -355.0)])
def test_an_oriented_stop_committed_to_a_turn_goes_on_after_it(k, offset, travel):
    """MC_OrientedStop of the braking positioning (its dynamics): the next position with the modulo value
    after the turn, with the speed of the turn (no crawl at the start's speed: 5.6 u/s one cycle before the
    crossing). Before: forward to p0 + 0.5 after the turn (two reversals); h2b at bad5e91 even + 360.5."""
    core, tr, st = reversing(k)
    position = modulo_of(st.p + offset)
    n = cmd(core, "OrientedStop", Position=position)["CmdNo"]
    end = turns_once_to(tr, st, position, 1500)
    assert end == pytest.approx(st.p + travel, abs=1e-6)
    assert tr.fate(n) == (DONE, 0) or (int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE)


def test_an_oriented_stop_not_committed_to_a_turn_keeps_its_direction():
    """30 cycles before the crossing (a^2 / 2j < v): the plan to rest does not turn, the stop goes on in
    the positive direction to the first position at or beyond its end (as before bad5e91)."""
    core, tr, st = reversing(30, committed=False)
    rest_end = plan_velocity(st, 0.0, AXIS_DYN).end.p
    cmd(core, "OrientedStop", Position=modulo_of(rest_end + 0.5))
    tr.settle()
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(rest_end + 0.5, abs=1e-6)
    assert (tr.col("SetVelo") >= 0.0).all()


# -- near rest: moving is the NC's own notion (set velocity not 0), no threshold of MoveModulo's own
def halted(abort_before_end=None):
    """An axis at 720 u/s past 500 stopped by MC_Halt (Deceleration 3600, Jerk 36000): (core, trace from the
    Halt on, the Halt's end position, its cycles). ``abort_before_end``: stepped to that many cycles
    before the Halt's end."""
    def setup():
        core = powered(Modulo=True, AxisModuloToleranceWindow=0.0, **FAST)
        cmd(core, "MoveVelocity", Velocity=720.0, Direction=POS)
        while float(core.axes.set_pos[0]) < 500.0:
            core.step()
        cmd(core, "Halt", Deceleration=3600.0, Jerk=36000.0)
        return core
    twin, n = setup(), 0
    while twin.moving.any():
        twin.step()
        n += 1
    core = setup()
    if abort_before_end is not None:
        for _ in range(n - abort_before_end):
            core.step()
    return core, Trace(core), float(twin.axes.set_pos[0]), n


def test_a_start_in_the_last_cycle_of_a_halt_counts_as_moving():
    """Aborting one cycle before the Halt's end (0.018 u/s, 1e-5 u to rest): the moving rule, NEG to 20
    behind the Halt's end goes on to + 340 (ModuloKind, schema: start it after standstill or buffered)."""
    core, tr, p_end, _ = halted(abort_before_end=1)
    assert 0.0 < float(core.axes.set_velo[0]) < 0.1 and 0.0 < p_end - float(core.axes.set_pos[0]) < 1e-4
    n = cmd(core, "MoveModulo", Position=modulo_of(p_end - 20.0), Velocity=720.0, Direction=NEG)["CmdNo"]
    ends_moving_on(core, tr, n, 1.0, p_end + 340.0)


def test_a_start_buffered_behind_a_halt_takes_the_standstill_rule():
    """Buffered behind the Halt it starts at rest where the Halt ends: NEG to 20 behind it is - 20."""
    core, tr, p_end, cycles = halted()
    n = cmd(core, "MoveModulo", Position=modulo_of(p_end - 20.0), Velocity=720.0, Direction=NEG,
            BufferMode=1)["CmdNo"]
    tr.settle()
    v = tr.col("SetVelo")
    assert (v[:cycles - 1] >= 0.0).all() and (v[cycles:] <= 0.0).all()
    assert float(tr.rows[-1]["SetPos"]) == pytest.approx(p_end - 20.0, abs=1e-9)
    assert int(tr.rows[-1]["CmdNo"]) == n and int(tr.rows[-1]["CmdState"]) == DONE


def test_a_turn_only_the_moves_own_weaker_jerk_causes_is_refused():
    """Braking hard in a Halt (AxisDec 36000, AxisJerk 360000), 20 cycles in (648 u/s, -7200 u/s^2): a
    MoveModulo with Jerk 3600 could not stop without turning, the running jerk could: not a committed
    turn, refused 0x4289 (the check of every start), nothing changes."""
    core, _, _ = moving(1.0)
    cmd(core, "Halt")
    for _ in range(20):
        core.step()
    before = snapshot(core)
    p = float(core.axes.set_pos[0])
    got = cmd(core, "MoveModulo", Position=modulo_of(p + 0.5), Velocity=720.0, Direction=POS, Deceleration=36000.0,
              Jerk=3600.0)["error"]
    assert got == E.NC_ILLEGAL_REVERSAL == 0x4289
    assert snapshot(core) == before


@pytest.mark.parametrize("sense", [1, -1])
def test_oriented_stop_after_a_committed_turn_is_never_faster_than_the_running_motion(sense):
    """MC_OrientedStop while a positioning already turns the axis (MoveVelocity 1500, then MoveAbsolute 100 u
    behind at 200 u/s): after the turn it goes on to the oriented position at the running motion's 200 u/s,
    not at the start's speed in the old direction (~500 u/s)."""
    fast = dict(AxisVeloMax=3600.0, AxisAcc=36000.0, AxisDec=36000.0, AxisJerk=360000.0)
    core = powered(Modulo=True, AxisModuloToleranceWindow=0.0, **fast)
    cmd(core, "MoveVelocity", Velocity=1500.0, Direction=1 if sense > 0 else 3)
    for _ in range(300):
        core.step()
    cmd(core, "MoveAbsolute", Position=float(core.axes.set_pos[0]) - sense * 100.0, Velocity=200.0)
    for _ in range(75):
        core.step()
    assert sense * float(core.axes.set_velo[0]) > 400.0  # (still fast in the old direction: a committed turn)
    assert cmd(core, "OrientedStop", Position=100.0)["error"] == 0
    after = []
    for _ in range(100_000):
        core.step()
        v = float(core.axes.set_velo[0])
        if sense * v < 0:
            after.append(abs(v))
        if not core.moving.any():
            break
    assert not core.moving.any() and after
    assert max(after) <= 200.0 * (1 + 1e-6)
    assert abs(math.remainder(float(core.axes.set_pos[0]) - 100.0, 360.0)) < 1e-6
