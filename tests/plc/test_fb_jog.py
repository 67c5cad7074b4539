"""MC_Jog: first against the wire contract alone (a scripted NC: what is sent when, how the fate
of the Jog and of the block's Halt shows), then against the real NcCore (motion engine), cycle by
cycle: modes, priority and mutual locking of the keys, the Halt on release, inching distances,
INCHING_MODULO rounding."""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import E_JogMode, ErrorCodes
from nc_server.core import AxisParams
from plc_client import AXIS_REF, MC_Jog, MC_MoveAbsolute
from znc_testing.plc_rig import ABORTED, ACTIVE, DONE, IDLE, MOVING, Rig, ScriptNc, powered

SLOW, FAST, CONT, INCH, INCH_MOD = (int(m) for m in E_JogMode)


# ---- against the contract (scripted NC) -------------------------------------------------------------
def jog_on(nc: ScriptNc, jog: MC_Jog, st: dict, **inputs: Any) -> None:
    nc.watched.append(jog)
    nc.calls.append(lambda: jog(Axis=nc.ax, JogForward=st.get("f", False), JogBackwards=st.get("b", False),
                                **inputs))


def accept(nc: ScriptNc, cmd: str, cmdno: int) -> Any:
    p = nc.last_sent(cmd)
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=cmdno)
    return p


def jog_moving(nc: ScriptNc, jog: MC_Jog, st: dict, **inputs: Any) -> None:
    """``jog`` called every cycle with the keys in ``st``; its Jog accepted as CmdNo 5, then moving."""
    jog_on(nc, jog, st, **inputs)
    nc.cycle_once()
    accept(nc, "Jog", 5)
    nc.state(MOVING)
    nc.set_jobs(active=(5, ACTIVE))
    nc.cycle_once()


@pytest.mark.parametrize("mode, args", [
    (SLOW, {}),
    (FAST, {}),
    (CONT, {"Velocity": 30.0, "Acceleration": 1.0, "Deceleration": 2.0, "Jerk": 3.0}),
    (INCH, {"Position": 4.0, "Velocity": 30.0, "Acceleration": 1.0, "Deceleration": 2.0, "Jerk": 3.0}),
    (INCH_MOD, {"Position": 4.0, "Velocity": 30.0, "Acceleration": 1.0, "Deceleration": 2.0, "Jerk": 3.0}),
])
def test_contract_jog_arguments_by_mode(nc: ScriptNc, mode: int, args: dict) -> None:
    jog = MC_Jog()
    st = {"b": True}
    jog_on(nc, jog, st, Mode=mode, Position=4.0, Velocity=30.0, Acceleration=1.0, Deceleration=2.0, Jerk=3.0)
    nc.cycle_once()
    p = nc.last_sent("Jog")
    assert p.args == {"Mode": mode, "Direction": 3, **args}
    assert jog.Busy and not jog.Active


def test_contract_release_sends_halt_after_acceptance_and_follows_it(nc: ScriptNc) -> None:
    jog = MC_Jog()
    st = {"f": True}
    jog_on(nc, jog, st, Mode=CONT, Velocity=30.0, Deceleration=250.0, Jerk=9000.0)
    nc.cycle_once()
    st["f"] = False  # released before the NC answered: no Halt yet (it could overtake the Jog)
    nc.cycle_once()
    assert [p.cmd for p in nc.port.sent] == ["Jog"] and jog.Busy
    accept(nc, "Jog", 5)
    nc.state(MOVING)
    nc.set_jobs(active=(5, ACTIVE))
    nc.cycle_once()
    halt = nc.last_sent("Halt")
    assert halt.args["Deceleration"] == 250.0 and halt.args["Jerk"] == 9000.0, halt.args
    assert jog.Busy and jog.Active
    accept(nc, "Halt", 6)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, ABORTED, 0),))  # our Halt aborts our Jog: not CommandAborted
    nc.cycle_once()
    nc.cycle_once()
    assert jog.Busy and jog.Active and not jog.CommandAborted
    nc.state(IDLE)
    nc.set_jobs(active=(6, DONE), ended=((6, DONE, 0), (5, ABORTED, 0)))
    nc.cycle_once()
    assert jog.Done and not jog.Busy and not jog.Active
    nc.cycle_once()
    assert not jog.Done, "one cycle: the key is released"
    assert [p.cmd for p in nc.port.sent] == ["Jog", "Halt"]


def test_contract_standard_mode_halts_with_axis_defaults(nc: ScriptNc) -> None:
    jog = MC_Jog()
    st = {"f": True}
    jog_moving(nc, jog, st, Mode=SLOW, Deceleration=250.0, Jerk=9000.0)
    st["f"] = False
    nc.cycle_once()
    halt = nc.last_sent("Halt")
    assert halt.args["Deceleration"] == 0.0 and halt.args["Jerk"] == 0.0


def test_contract_priority_locking_and_abort(nc: ScriptNc) -> None:
    jog = MC_Jog()
    st = {"f": True, "b": True}
    jog_moving(nc, jog, st, Mode=SLOW)
    assert nc.last_sent("Jog").args["Direction"] == 1, "JogForward wins simultaneous edges"
    st["b"] = False
    nc.cycle_once()
    st["b"] = True  # an edge of the other key while Busy: ignored
    nc.cycle_once()
    assert len(nc.port.sent) == 1
    nc.set_jobs(active=(7, ACTIVE), ended=((5, ABORTED, 0),))  # somebody else's command
    nc.cycle_once()
    assert jog.CommandAborted and not jog.Busy
    st["f"] = False  # CommandAborted was held while the key was pressed; the release sends nothing
    nc.cycle_once()
    assert not jog.CommandAborted and len(nc.port.sent) == 1
    nc.cycle_once()  # JogBackwards is still pressed but has no new edge
    assert len(nc.port.sent) == 1 and not jog.Busy


def test_contract_inching_ignores_the_release_and_ends_by_the_window(nc: ScriptNc) -> None:
    jog = MC_Jog()
    st = {"f": True}
    jog_moving(nc, jog, st, Mode=INCH, Position=2.0, Velocity=10.0)
    st["f"] = False
    nc.cycle_once()
    assert [p.cmd for p in nc.port.sent] == ["Jog"] and jog.Busy
    nc.job_done(5)
    nc.cycle_once()
    assert jog.Done and not jog.Busy


def test_contract_invalid_mode(nc: ScriptNc) -> None:
    jog = MC_Jog()
    for bad in (5, -1, 2.0, True, "slow"):
        st = {"f": True}
        nc.calls = []
        jog_on(nc, jog, st, Mode=bad)
        nc.cycle_once()
        assert jog.Error and jog.ErrorID == ErrorCodes.MC_INVALID_MODE, bad
        st["f"] = False
        nc.cycle_once()
        assert not jog.Error
    assert nc.port.sent == []


# ---- against the real NC ------------------------------------------------------------------------------
def keys(jog: MC_Jog, ax: AXIS_REF, state: dict, **inputs: Any):
    """A program body calling ``jog`` with the keys in ``state`` and fixed ``inputs``."""
    return lambda p: jog(Axis=ax, JogForward=state.get("f", False), JogBackwards=state.get("b", False), **inputs)


def cmdno(rig: Rig) -> int:
    return int(rig.rec()["CmdNo"])


def test_standard_slow_runs_while_held_and_halts_on_release(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    st = {"f": True}
    calls["body"] = keys(jog, ax, st, Mode=SLOW, Velocity=999.0)  # Velocity has no effect in this mode
    rig.run(1)
    assert jog.Busy and not jog.Active
    rig.run_until(lambda: jog.Active, 5)
    first = cmdno(rig)
    rig.run(40)
    assert jog.Busy and jog.Active and not jog.Done
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), AxisParams().AxisVeloManSlow)  # 50 u/s
    assert ax.Status.ContinuousMotion
    st["f"] = False
    rig.run(1)
    assert jog.Busy and jog.Active  # the block's Halt ramp
    rig.run_until(lambda: not jog.Busy, 100)
    assert jog.Done and cmdno(rig) > first, "the release sends a Halt (a new command)"
    assert ax.Status.StandStill and not ax.Status.HasJob
    rig.run(1)
    dones = [o["Done"] for o in rig.outputs(jog)]
    assert dones.count(True) == 1, "the key was already released: Done for exactly one cycle"
    assert not jog.Done and not jog.Busy


def test_backwards_standard_fast(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    st = {"b": True}
    calls["body"] = keys(jog, ax, st, Mode=FAST)
    rig.run(40)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), -AxisParams().AxisVeloManFast)
    st["b"] = False
    rig.run_until(lambda: jog.Done, 100)
    assert ax.ActPos < -5.0 and ax.Status.StandStill


def test_continuous_uses_the_inputs_and_stops_with_the_jog_deceleration(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    st = {"f": True}
    calls["body"] = keys(jog, ax, st, Mode=CONT, Velocity=100.0, Acceleration=2000.0, Deceleration=400.0,
                         Jerk=100000.0)
    rig.run(30)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 100.0)
    st["f"] = False
    n = rig.run_until(lambda: jog.Done, 200)
    # 100 u/s at 400 u/s^2: >= 0.25 s (25 PLC cycles); the axis default (5000) would take 0.02 s
    assert n >= 22, f"stopped after {n} cycles: the Halt did not use the jog's Deceleration"


def test_key_tap_of_one_cycle_still_stops_the_axis(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    st = {"f": True}
    calls["body"] = keys(jog, ax, st, Mode=SLOW)
    rig.run(1)
    st["f"] = False  # released before the NC's reply arrived
    rig.run_until(lambda: not jog.Busy, 100)
    assert jog.Done
    rig.run(20)
    assert ax.Status.StandStill and not ax.Status.HasJob


def test_forward_has_priority_on_simultaneous_edges(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    st = {"f": True, "b": True}
    calls["body"] = keys(jog, ax, st, Mode=SLOW)
    rig.run(30)
    assert float(ax.NcToPlc["SetVelo"]) > 0
    st["f"] = False  # releasing the key that started it stops; the other key does nothing
    rig.run_until(lambda: jog.Done, 100)
    rig.run(20)
    assert ax.Status.StandStill, "JogBackwards held from the start has no edge: no motion"


def test_no_edge_accepted_while_moving(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    st = {"f": True}
    calls["body"] = keys(jog, ax, st, Mode=SLOW)
    rig.run_until(lambda: jog.Active, 5)
    no = cmdno(rig)
    st["b"] = True  # the other key while moving: locked out
    rig.run(5)
    st["b"] = False
    rig.run(2)
    st["b"] = True
    rig.run(5)
    assert cmdno(rig) == no and float(ax.NcToPlc["SetVelo"]) > 0
    st["f"] = False  # stop; JogBackwards stays pressed
    rig.run_until(lambda: jog.Done, 100)
    rig.run(20)
    assert ax.Status.StandStill and not jog.Busy, "a key held through the motion does not start"
    pos = ax.ActPos
    st["b"] = False
    rig.run(1)
    st["b"] = True  # a new press once the block is free
    rig.run(30)
    assert jog.Busy and float(ax.NcToPlc["SetVelo"]) < 0
    st["b"] = False
    rig.run_until(lambda: jog.Done, 100)
    assert ax.ActPos < pos


def test_inching_moves_by_position_per_press(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    st = {"f": True}
    calls["body"] = keys(jog, ax, st, Mode=INCH, Position=2.5, Velocity=20.0)
    rig.run_until(lambda: jog.Done, 200)
    assert math.isclose(ax.ActPos, 2.5, abs_tol=0.02) and ax.Status.InTargetPosition
    rig.run(10)
    assert jog.Done and not jog.Busy, "Done is held while the key stays pressed"
    assert math.isclose(ax.ActPos, 2.5, abs_tol=0.02), "holding the key does not move further"
    st["f"] = False
    rig.run(1)
    assert not jog.Done
    st["f"] = True
    rig.run_until(lambda: jog.Done, 200)
    assert math.isclose(ax.ActPos, 5.0, abs_tol=0.02)
    st["f"] = False
    rig.run(1)
    st["b"] = True
    rig.run(1)
    st["b"] = False  # released during the step: the step completes anyway
    rig.run_until(lambda: not jog.Busy, 200)
    assert jog.Done and math.isclose(ax.ActPos, 2.5, abs_tol=0.02)
    rig.run(1)
    assert not jog.Done, "the key was released during the step: Done for one cycle"


def test_inching_with_position_0_moves_by_the_axis_jog_increments() -> None:
    """Position 0 (the block's default): the NC moves by AxisJogIncrementForward / AxisJogIncrementBackward;
    an increment of 0 refuses the jog with 0x4B06 (the block reports it, nothing moves)."""
    rig = Rig(params=AxisParams(AxisJogIncrementForward=1.25, AxisJogIncrementBackward=0.0))
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    st = {"f": True}
    calls["body"] = keys(jog, ax, st, Mode=INCH, Velocity=20.0)  # Position left at 0
    rig.run_until(lambda: jog.Done, 200)
    assert math.isclose(ax.ActPos, 1.25, abs_tol=0.02) and ax.Status.InTargetPosition
    st["f"] = False
    rig.run(1)
    st["b"] = True
    rig.run_until(lambda: not jog.Busy, 5)
    assert jog.Error and jog.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT
    assert math.isclose(ax.ActPos, 1.25, abs_tol=0.02) and ax.Status.StandStill


def test_inching_modulo_ends_on_multiples_of_position(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, jog = rig.watch(MC_MoveAbsolute(), MC_Jog())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Position=0.7, Velocity=50.0)
    rig.run_until(lambda: mv.Done, 200)
    st = {"f": True}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=False)
        jog(Axis=ax, JogForward=st.get("f", False), JogBackwards=st.get("b", False), Mode=INCH_MOD,
            Position=2.0, Velocity=20.0)

    calls["body"] = body
    rig.run_until(lambda: jog.Done, 200)
    assert math.isclose(ax.ActPos, 2.0, abs_tol=0.02), "0.7 + 2 rounded to a multiple of 2"
    st["f"] = False
    rig.run(1)
    st["f"] = True
    rig.run_until(lambda: jog.Done, 200)
    assert math.isclose(ax.ActPos, 4.0, abs_tol=0.02)
    st["f"] = False
    rig.run(1)
    st["b"] = True
    rig.run_until(lambda: jog.Done, 200)
    assert math.isclose(ax.ActPos, 2.0, abs_tol=0.02)


def test_another_command_aborts_the_jog_and_no_halt_follows(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog, mv = rig.watch(MC_Jog(), MC_MoveAbsolute())
    st = {"f": True, "mv": False}

    def body(p: Any) -> None:
        jog(Axis=ax, JogForward=st["f"], Mode=SLOW)
        mv(Axis=ax, Execute=st["mv"], Position=-10.0, Velocity=100.0)

    calls["body"] = body
    rig.run_until(lambda: jog.Active, 5)
    rig.run(10)
    st["mv"] = True
    rig.run_until(lambda: jog.CommandAborted, 5)
    assert not jog.Busy and not jog.Active and jog.ErrorID == 0
    no = cmdno(rig)
    st["f"] = False
    rig.run(5)
    assert cmdno(rig) == no, "an aborted jog sends no Halt"
    rig.run_until(lambda: mv.Done, 300)
    assert math.isclose(ax.ActPos, -10.0, abs_tol=0.02)


def test_invalid_mode_and_rejected_jog(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    jog = rig.watch(MC_Jog())
    before = cmdno(rig)
    st = {"f": True}
    calls["body"] = keys(jog, ax, st, Mode=9)
    rig.run(1)
    assert jog.Error and jog.ErrorID == ErrorCodes.MC_INVALID_MODE
    rig.run(2)
    assert cmdno(rig) == before and jog.Error, "nothing sent; Error held while the key is pressed"
    st["f"] = False
    rig.run(1)
    assert not jog.Error and jog.ErrorID == 0
    calls["body"] = keys(jog, ax, st, Mode=CONT, Velocity=0.0)  # the NC refuses a zero velocity
    st["f"] = True
    rig.run_until(lambda: not jog.Busy, 5)
    assert jog.Error and jog.ErrorID == ErrorCodes.NC_VELOCITY_NOT_ALLOWED
    calls["body"] = keys(jog, ax, st, Mode=CONT, Velocity=float("nan"))
    st["f"] = False
    rig.run(1)
    st["f"] = True
    rig.run(1)
    assert jog.Error and jog.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT
    assert ax.Status.StandStill


def test_jog_without_power_reports_the_nc_code() -> None:
    rig = Rig()
    plc = rig.plc("plc1")
    ax = plc.axis("nc1", 1)
    jog = rig.watch(MC_Jog())
    plc.program = lambda p: jog(Axis=ax, JogForward=True, Mode=SLOW)
    rig.run_until(lambda: not jog.Busy, 5)
    assert jog.Error and jog.ErrorID == ErrorCodes.NC_NO_ENABLE
