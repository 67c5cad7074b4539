"""MoveModulo through the engine, cycle by cycle: the direction rules (never against the requested
direction, except inside the modulo tolerance window, TcMC 3.5), full turns, MC_Current_Direction
while moving and behind another job, a buffered modulo move refers to the previous target; a start during
motion never reverses it (the first position with the modulo value at or beyond the rest point, in the current
direction, whatever Direction says, without extra turns)."""
import math

import pytest

from nc_schema import CmdState, ErrorCodes as E
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


def test_a_queued_target_behind_the_rest_point_of_a_continuous_move():
    """Behind MC_MoveContinuousAbsolute (passes 100 at 720 u/s and goes on): the queued target 110 (from
    the previous target, positive direction) lies within the way to rest: the moving rule, 470."""
    core, tr = at(0.0)
    cmd(core, "MoveContinuousAbsolute", Position=100.0, Velocity=720.0, EndVelocity=720.0)
    n = cmd(core, "MoveModulo", Position=110.0, Velocity=720.0, Direction=POS, BufferMode=1, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, 1.0, 470.0)


def test_a_blending_successor_keeps_its_queued_target_and_turns():
    """BlendingNext behind a positive move: the target refers to the previous one with the standstill
    rules (Position 390 from 100: 390 and the turn asked for, 750), the blend passes 100 moving on (the
    moving rule would end at 390)."""
    core, tr = at(0.0)
    cmd(core, "MoveAbsolute", Position=100.0, Velocity=720.0)
    n = cmd(core, "MoveModulo", Position=390.0, Velocity=720.0, Direction=POS, BufferMode=20, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, 1.0, 750.0)
    assert tr.col("SetVelo")[tr.first(lambda r, j: float(r["SetPos"]) >= 100.0)] > 100.0


def test_a_software_limit_before_the_moving_target_refuses_the_start():
    """The computed end (one period on) beyond AxisMaxSoftPosLimit 750 (the axis passes 500 when the
    command comes): refused as a MoveAbsolute there, nothing changes; p0 + 130 below it starts."""
    core, tr, p0 = moving(1.0, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=750.0)
    before = snapshot(core)
    got = cmd(core, "MoveModulo", Position=modulo_of(p0 + 20.0), Velocity=720.0, Direction=POS, **OWN)["error"]
    assert got and got == cmd(core, "MoveAbsolute", Position=p0 + 380.0, Velocity=720.0, **OWN)["error"]
    assert snapshot(core) == before
    n = cmd(core, "MoveModulo", Position=modulo_of(p0 + 130.0), Velocity=720.0, Direction=POS, **OWN)["CmdNo"]
    ends_moving_on(core, tr, n, 1.0, p0 + 130.0)


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
