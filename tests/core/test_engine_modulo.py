"""MoveModulo through the engine, cycle by cycle: the direction rules (never against the requested
direction, except inside the modulo tolerance window, TcMC 3.5), full turns, MC_Current_Direction
while moving and behind another job, a buffered modulo move refers to the previous target."""
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
