"""MC_MoveVelocity's Direction (TcMC 3.3, MC_Direction 6.2): MC_Current_Direction is the direction of the
axis's set velocity when the command is accepted (a running superposition included; a buffered command:
the direction of the job it follows); at rest 0x4B05. MC_Shortest_Way is refused with 0x4B05 (an endless
move has no target to be short to). A refusal changes nothing."""
from __future__ import annotations

import math

import pytest

from nc_schema import CmdState, ErrorCodes as E, MC_Direction
from znc_testing.nc_core import cmd, powered, run_until, snapshot

CUR = int(MC_Direction.MC_Current_Direction)
SHORT = int(MC_Direction.MC_Shortest_Way)


def velo(core, i: int = 0) -> float:
    return float(core.nctoplc[i]["SetVelo"])


@pytest.mark.parametrize("direction, sense", [(1, 1.0), (3, -1.0)])
def test_current_direction_keeps_the_direction_of_travel(direction: int, sense: float) -> None:
    """Before: refused 0x4B05 always."""
    core = powered()
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=direction)["error"] == 0
    for _ in range(20):
        core.step()
    rep = cmd(core, "MoveVelocity", Velocity=300.0, Direction=CUR)
    assert rep["error"] == 0, rep
    run_until(core, lambda: math.isclose(velo(core), sense * 300.0), 5000)
    assert int(core.nctoplc[0]["CmdNo"]) == rep["CmdNo"]


def test_current_direction_of_a_positioning_on_its_way_back() -> None:
    """The axis moves towards a target below it: the current direction is negative."""
    core = powered()
    assert cmd(core, "MoveAbsolute", Position=-500.0, Velocity=200.0)["error"] == 0
    for _ in range(50):
        core.step()
    assert cmd(core, "MoveVelocity", Velocity=50.0, Direction=CUR)["error"] == 0
    run_until(core, lambda: math.isclose(velo(core), -50.0), 5000)


def test_current_direction_at_rest_is_refused_and_changes_nothing() -> None:
    core = powered()
    before = snapshot(core)
    rep = cmd(core, "MoveVelocity", Velocity=100.0, Direction=CUR)
    assert rep["error"] == E.MC_COMMAND_NOT_PERMITTED and "rest" in rep["text"]
    assert snapshot(core) == before


def test_shortest_way_is_refused_moving_or_not() -> None:
    core = powered()
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=SHORT)["error"] == E.MC_COMMAND_NOT_PERMITTED
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)["error"] == 0
    for _ in range(20):
        core.step()
    before = snapshot(core)
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=SHORT)["error"] == E.MC_COMMAND_NOT_PERMITTED
    assert snapshot(core) == before


def test_current_direction_counts_a_running_superposition() -> None:
    """The basic motion stands, a superposition moves the axis backwards: the total set velocity is the
    current direction (the direction the axis moves in)."""
    core = powered()
    rep = cmd(core, "MoveSuperImposed", Mode=3, Distance=-500.0, VelocityDiff=100.0, Length=1e5,
              VelocityProcess=100.0)
    assert rep["error"] == 0, rep
    run_until(core, lambda: velo(core) < -50.0, 5000)
    assert cmd(core, "MoveVelocity", Velocity=20.0, Direction=CUR)["error"] == 0
    run_until(core, lambda: math.isclose(velo(core), -20.0), 20_000)


def test_a_buffered_current_direction_takes_the_direction_of_the_job_it_follows() -> None:
    """Buffered behind a positioning to -100 (it ends at rest there): the direction it travelled, fixed at
    acceptance, although the axis stands when the MoveVelocity starts."""
    core = powered()
    assert cmd(core, "MoveAbsolute", Position=-100.0, Velocity=200.0)["error"] == 0
    core.step()
    rep = cmd(core, "MoveVelocity", Velocity=30.0, Direction=CUR, BufferMode=1)
    assert rep["error"] == 0, rep
    run_until(core, lambda: int(core.nctoplc[0]["CmdNo"]) == rep["CmdNo"], 20_000)
    run_until(core, lambda: math.isclose(velo(core), -30.0), 5000)
    assert int(core.nctoplc[0]["CmdState"]) == int(CmdState.ACTIVE)


def test_the_direction_is_fixed_at_acceptance() -> None:
    """A reversal after the command was accepted (a buffered one waiting) does not change it."""
    core = powered()
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)["error"] == 0
    for _ in range(50):
        core.step()
    rep = cmd(core, "MoveVelocity", Velocity=40.0, Direction=CUR, BufferMode=1)
    assert rep["error"] == 0
    run_until(core, lambda: int(core.nctoplc[0]["CmdNo"]) == rep["CmdNo"], 20_000)
    run_until(core, lambda: math.isclose(velo(core), 40.0), 5000)


def test_current_direction_buffered_behind_a_loop_movement_is_its_return_leg() -> None:
    """A loop movement (AxisLoopingDistance 5: targets approached from above) to 20 from 0 goes on to 25 and
    ends moving down: a buffered MC_Current_Direction follows that last leg."""
    core = powered(AxisEnLoopingDistance=True, AxisLoopingDistance=5.0)
    assert cmd(core, "MoveAbsolute", Position=20.0, Velocity=100.0)["error"] == 0
    for _ in range(20):
        core.step()
    assert velo(core) > 0  # (still on the way out)
    assert cmd(core, "MoveVelocity", Velocity=30.0, Direction=CUR, BufferMode=1)["error"] == 0
    run_until(core, lambda: math.isclose(velo(core), -30.0), 20000)
