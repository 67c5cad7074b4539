"""MC_NewPos / MC_NewPosAndVelo on an endless move (MoveVelocity): a new velocity, or a new
target that turns it into a positioning with the same CmdNo; switching-position modes refused."""
from __future__ import annotations

import math

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


def test_switching_modes_on_an_endless_move_are_refused_and_change_nothing() -> None:
    core, _ = _running()
    before = snapshot(core)
    for mode in (9, 10, 11, 14):
        rep = cmd(core, "NewPosAndVelo", Mode=mode, NewVelo=5.0, NewPos=100.0, ActivationPos=50.0)
        assert rep["error"] == ErrorCodes.MC_COMMAND_NOT_PERMITTED, rep
    assert snapshot(core) == before
    rep = cmd(core, "NewPosAndVelo", Mode=2, NewVelo=1e6, NewPos=0.0, ActivationPos=0.0)
    assert rep["error"] == ErrorCodes.NC_VELOCITY_NOT_ALLOWED
    assert snapshot(core) == before
