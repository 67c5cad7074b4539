"""MC_NewPos / MC_NewPosAndVelo on an endless move (MoveVelocity): a new velocity, or a new
target that turns it into a positioning with the same CmdNo; the switching-position modes 9/10/11/14 armed
and applied when the set position passes ActivationPos in the job's direction (an ActivationPos already
passed: 0x427F, also on a positioning)."""
from __future__ import annotations

import math

import pytest

from nc_schema import CmdState, ErrorCodes, StateDWord
from znc_testing.nc_core import cmd, powered, run_until, snapshot


def _running(v: float = 10.0):
    core = powered(1)
    no = cmd(core, "MoveVelocity", Velocity=v, Direction=1)["CmdNo"]
    run_until(core, lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), v), 5000)
    return core, no


def test_change_velo_gives_a_new_velocity_with_the_same_cmdno() -> None:
    core, no = _running()
    rep = cmd(core, "NewPosAndVelo", Mode=2, NewVelo=4.0, NewPos=0.0, ActivationPos=0.0)
    assert rep["error"] == 0 and rep["CmdNo"] == no
    run_until(core, lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), 4.0), 5000)
    r = core.nctoplc[0]
    assert int(r["CmdNo"]) == no and int(r["CmdState"]) == int(CmdState.ACTIVE)
    assert int(r["StateDWord"]) & int(StateDWord.NewTargetPos)
    assert int(r["StateDWord"]) & int(StateDWord.ContinuousMotion)


def test_new_pos_turns_the_endless_move_into_a_positioning() -> None:
    core, no = _running()
    target = float(core.nctoplc[0]["SetPos"]) + 5.0
    assert cmd(core, "NewPos", NewPos=target)["CmdNo"] == no
    run_until(core, lambda: int(core.nctoplc[0]["CmdState"]) == int(CmdState.DONE), 20000)
    r = core.nctoplc[0]
    assert int(r["CmdNo"]) == no and float(r["SetPos"]) == target
    assert not int(r["StateDWord"]) & int(StateDWord.ContinuousMotion)


def test_invalid_values_of_a_switching_mode_are_refused_and_change_nothing() -> None:
    core, _ = _running()
    before = snapshot(core)
    rep = cmd(core, "NewPosAndVelo", Mode=10, NewVelo=1e6, NewPos=0.0, ActivationPos=500.0)
    assert rep["error"] == ErrorCodes.NC_VELOCITY_NOT_ALLOWED
    rep = cmd(core, "NewPosAndVelo", Mode=2, NewVelo=1e6, NewPos=0.0, ActivationPos=0.0)
    assert rep["error"] == ErrorCodes.NC_VELOCITY_NOT_ALLOWED
    assert snapshot(core) == before


def _running_at(v: float, direction: int = 1):
    """A MoveVelocity at |v| in ``direction`` (AxisVeloMax 1000, AxisAcc/Dec 5000, AxisJerk 50000)."""
    core = powered(1)
    no = cmd(core, "MoveVelocity", Velocity=v, Direction=direction)["CmdNo"]
    sense = 1.0 if direction == 1 else -1.0
    run_until(core, lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), sense * v), 5000)
    return core, no


def _step_recording(core, n: int) -> tuple[list[float], list[float]]:
    pos, vel = [], []
    for _ in range(n):
        core.step()
        pos.append(float(core.nctoplc[0]["SetPos"]))
        vel.append(float(core.nctoplc[0]["SetVelo"]))
    return pos, vel


@pytest.mark.parametrize("direction", [1, 3])
def test_change_velo_at_switchpos_applies_where_the_set_position_passes_it(direction: int) -> None:
    """Mode 10 on a MoveVelocity: the velocity stays until the set position passes ActivationPos (in the
    direction of travel), then changes (before: refused 0x4B05)."""
    core, no = _running_at(100.0, direction)
    sense = 1.0 if direction == 1 else -1.0
    at = float(core.nctoplc[0]["SetPos"]) + sense * 50.0
    rep = cmd(core, "NewPosAndVelo", Mode=10, NewVelo=20.0, ActivationPos=at)
    assert rep["error"] == 0 and rep["CmdNo"] == no, rep
    pos, vel = _step_recording(core, 1500)
    k = next(n for n, p in enumerate(pos) if (p - at) * sense >= 0)  # first cycle at/after ActivationPos
    assert all(math.isclose(v, sense * 100.0) for v in vel[:k + 1]), "unchanged until ActivationPos"
    assert abs(vel[k + 1]) < 100.0, "braking from the cycle after it was passed"
    assert math.isclose(vel[-1], sense * 20.0)
    r = core.nctoplc[0]
    assert int(r["CmdNo"]) == no and int(r["CmdState"]) == int(CmdState.ACTIVE)


def test_reach_velo_at_pos_on_an_endless_move() -> None:
    """Mode 14: NewVelo is reached at ActivationPos (the change starts before it)."""
    core, no = _running_at(200.0)
    at = float(core.nctoplc[0]["SetPos"]) + 100.0
    assert cmd(core, "NewPosAndVelo", Mode=14, NewVelo=50.0, ActivationPos=at)["error"] == 0
    pos, vel = _step_recording(core, 1500)
    k = next(n for n, p in enumerate(pos) if p >= at)
    assert vel[k] == pytest.approx(50.0, abs=1.0), "reached at ActivationPos (within a cycle)"
    assert vel[max(k - 20, 0)] > 50.0 + 1.0, "the change started before it"
    assert int(core.nctoplc[0]["CmdNo"]) == no


@pytest.mark.parametrize("mode, args", [(9, dict(NewPos=0.0)), (11, dict(NewPos=0.0, NewVelo=30.0))])
def test_change_pos_at_switchpos_turns_the_endless_move_into_a_positioning(mode: int, args: dict) -> None:
    core, no = _running_at(100.0)
    p0 = float(core.nctoplc[0]["SetPos"])
    at, target = p0 + 30.0, p0 + 80.0
    rep = cmd(core, "NewPosAndVelo", Mode=mode, ActivationPos=at, **{**args, "NewPos": target})
    assert rep["error"] == 0, rep
    pos, vel = _step_recording(core, 400)
    k = next(n for n, p in enumerate(pos) if p >= at)
    assert all(math.isclose(v, 100.0) for v in vel[:k + 1])
    run_until(core, lambda: int(core.nctoplc[0]["CmdState"]) == int(CmdState.DONE), 20_000)
    r = core.nctoplc[0]
    assert int(r["CmdNo"]) == no and float(r["SetPos"]) == target
    assert not int(r["StateDWord"]) & int(StateDWord.ContinuousMotion)


@pytest.mark.parametrize("direction", [1, 3])
@pytest.mark.parametrize("mode", [9, 10, 11, 14])
def test_an_activation_pos_already_passed_is_refused_and_changes_nothing(mode: int, direction: int) -> None:
    core, _ = _running_at(100.0, direction)
    sense = 1.0 if direction == 1 else -1.0
    at = float(core.nctoplc[0]["SetPos"]) - sense * 1.0  # behind the axis
    before = snapshot(core)
    rep = cmd(core, "NewPosAndVelo", Mode=mode, NewPos=float(core.nctoplc[0]["SetPos"]) + sense * 500.0,
              NewVelo=30.0, ActivationPos=at)
    assert rep["error"] == ErrorCodes.NC_NEW_TARGET_OVERRUN == 0x427F, rep
    assert snapshot(core) == before


def test_exactly_at_activation_pos_is_not_passed() -> None:
    """ActivationPos == the set position: accepted, applied in the next cycle's watch."""
    core, no = _running_at(100.0)
    at = float(core.nctoplc[0]["SetPos"])
    assert cmd(core, "NewPosAndVelo", Mode=10, NewVelo=20.0, ActivationPos=at)["error"] == 0
    _, vel = _step_recording(core, 3)
    assert vel[0] == 100.0 and vel[1] < 100.0


def test_an_activation_pos_passed_by_a_positioning_is_refused_too() -> None:
    """The check sits in the shared arming code: a MoveAbsolute past ActivationPos (before: switched at
    once)."""
    core = powered(1)
    assert cmd(core, "MoveAbsolute", Position=500.0, Velocity=100.0)["error"] == 0
    run_until(core, lambda: float(core.nctoplc[0]["SetPos"]) > 100.0, 20_000)
    before = snapshot(core)
    rep = cmd(core, "NewPosAndVelo", Mode=10, NewVelo=20.0, ActivationPos=50.0)
    assert rep["error"] == ErrorCodes.NC_NEW_TARGET_OVERRUN
    assert snapshot(core) == before
    assert cmd(core, "NewPosAndVelo", Mode=10, NewVelo=20.0, ActivationPos=150.0)["error"] == 0


def test_a_switch_on_an_endless_move_towards_a_software_limit_keeps_the_limit_stop() -> None:
    """The velocity job's watch does both: the armed change at ActivationPos, then the stop exactly at the
    enabled software limit (0x4462) with the new velocity."""
    core = powered(1, AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=60.0)
    no = cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)["CmdNo"]
    run_until(core, lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), 100.0), 5000)
    at = float(core.nctoplc[0]["SetPos"]) + 10.0
    assert cmd(core, "NewPosAndVelo", Mode=10, NewVelo=40.0, ActivationPos=at)["error"] == 0
    run_until(core, lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), 40.0), 5000)
    assert float(core.nctoplc[0]["SetPos"]) < 60.0 and int(core.nctoplc[0]["CmdNo"]) == no
    run_until(core, lambda: int(core.nctoplc[0]["ErrorCode"]) != 0, 20_000)
    assert int(core.nctoplc[0]["ErrorCode"]) == ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING
    run_until(core, lambda: float(core.nctoplc[0]["SetVelo"]) == 0.0, 5000)
    assert float(core.nctoplc[0]["SetPos"]) == pytest.approx(60.0, abs=1e-6)
