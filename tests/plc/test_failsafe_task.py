"""The PLC side of losing the NC and of HandOver, against a real in-process NcCore (virtual time).

* Busy blocks of every family end with 0x4B0F when the NC's data is lost, and the motion command a
  block gave up on is stopped by the task when the same NC comes back still running it;
* the NC's liveliness token gone: the data is invalid at once (no waiting for stale_cycles);
* a hand-over between two clients never disables the axis.
"""
from __future__ import annotations

from typing import Any, Callable

import pytest

from nc_schema import ErrorCodes, StateDWord
from plc_client import (
    MC_GearIn, MC_Home, MC_Jog, MC_MoveAbsolute, MC_MoveSuperImposed, MC_MoveVelocity, MC_NewPos, MC_Power, MC_SetOverride,
)
from znc_testing.plc_rig import Rig, powered

NO_UPDATE = ErrorCodes.MC_NO_NC_CYCLE_UPDATE
CLC = int(StateDWord.ControlLoopClosed)


def lose_and_return(rig: Rig, ax: Any, fb: Any) -> None:
    """The NC stops producing frames (frozen) until ``fb`` ends with 0x4B0F, then runs again."""
    rig.nc_running = False
    rig.run_until(lambda: not fb.Busy, 50)
    assert fb.Error and fb.ErrorID == NO_UPDATE, fb
    rig.nc_running = True


def moving_fast(rig: Rig, axis_id: int = 1) -> Callable[[], bool]:
    return lambda: abs(float(rig.rec(axis_id)["SetVelo"])) > 1.0


@pytest.mark.parametrize("make, inputs", [
    (MC_MoveAbsolute, {"Execute": True, "Position": 900.0, "Velocity": 50.0}),
    (MC_MoveVelocity, {"Execute": True, "Velocity": 50.0, "Acceleration": 10.0, "Deceleration": 100.0}),
    (MC_Jog, {"JogForward": True, "Mode": 2, "Velocity": 50.0}),  # MC_JOGMODE_CONTINOUS
    (MC_Home, {"Execute": True, "HomingMode": 0}),  # MC_DefaultHoming: searching the cam
])
def test_a_motion_given_up_on_lost_data_is_stopped_when_the_nc_is_back(rig: Rig, make: Any, inputs: dict) -> None:
    ax, _, calls = powered(rig)
    fb = rig.watch(make())
    calls["body"] = lambda p: fb(Axis=ax, **inputs)
    rig.run_until(moving_fast(rig), 200)
    assert fb.Busy
    lose_and_return(rig, ax, fb)
    rig.run_until(lambda: ax.Status.StandStill, 300)  # the task stopped it: no motion for an Error
    assert fb.Error and fb.ErrorID == NO_UPDATE
    assert not ax.Status.MotionCommandsLocked, "a homing stop is released again"


def test_a_superposition_given_up_on_lost_data_is_aborted(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, sp = MC_MoveVelocity(), MC_MoveSuperImposed()
    st = {"sp": False}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Velocity=20.0)
        sp(Axis=ax, Execute=st["sp"], Distance=500.0, VelocityDiff=5.0, Acceleration=10.0,
           Deceleration=20.0, Jerk=0.0, VelocityProcess=20.0, MaxDistance=1000.0)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 300)
    st["sp"] = True
    rig.run_until(lambda: rig.core.superposition.on[0], 50)
    lose_and_return(rig, ax, sp)
    rig.run_until(lambda: not rig.core.superposition.on[0], 300)
    assert abs(float(rig.rec()["SetVelo"]) - 20.0) < 1e-6, "the basic motion (not given up) goes on"


def test_a_coupling_given_up_on_lost_data_is_decoupled(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    slave = ax.task.axis("nc1", 2)
    pw2, mv, gi = MC_Power(), MC_MoveVelocity(), MC_GearIn()

    def body(p: Any) -> None:
        pw2(Axis=slave, Enable=True, Enable_Positive=True, Enable_Negative=True)
        mv(Axis=ax, Execute=pw2.Status, Velocity=10.0)
        gi(Master=ax, Slave=slave, Execute=mv.InVelocity, RatioNumerator=1, RatioDenominator=2)

    calls["body"] = body
    rig.run_until(lambda: gi.InGear, 500)
    lose_and_return(rig, slave, gi)
    rig.run_until(lambda: int(rig.rec(2)["CoupleState"]) == 0, 100)


def test_a_restarted_nc_is_not_sent_an_undo(rig: Rig) -> None:
    """The first frame after the loss has a lower cycle counter: another NC instance, which knows
    nothing of the command: nothing is sent to it."""
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveVelocity())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=20.0)
    rig.run_until(moving_fast(rig), 100)
    lose_and_return(rig, ax, mv)
    rig.core.cycle = 10  # (the same core, counting from the start again: a restart as the PLC sees it)
    sent = []
    port = ax.task.port
    orig = port.send
    port.send = lambda *a, **k: sent.append(a[2]) or orig(*a, **k)  # type: ignore[method-assign]
    rig.run(20)
    assert "Halt" not in sent and not ax.task._orphans


def test_nc_token_gone_makes_the_data_invalid_at_once(rig: Rig) -> None:
    ax, pw, calls = powered(rig)
    mv, ov = MC_MoveAbsolute(), MC_NewPos()
    plc = ax.task
    st = {"ov": False}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Position=500.0, Velocity=20.0)
        ov(Axis=ax, Execute=st["ov"], NewPos=600.0)

    calls["body"] = body
    rig.run_until(lambda: mv.Active, 20)
    plc.port.hold = True  # the reply never comes
    st["ov"] = True
    rig.run(2)
    assert ov.Busy
    plc.nc_down("nc1")  # what PlcRuntime does when nc/<nc>/alive is deleted
    rig.run(1)
    assert not ax.Status.Valid and ov.Error and ov.ErrorID == NO_UPDATE and pw.ErrorID == NO_UPDATE
    plc.nc_up("nc1")
    plc.port.hold = False
    rig.run(2)
    assert ax.Status.Valid and pw.Status


def test_hand_over_between_two_clients_never_disables_the_axis(rig: Rig) -> None:
    ax_a, pw_a, calls_a = powered(rig, "plcA")
    a = ax_a.task
    mv = MC_MoveVelocity()
    calls_a["body"] = lambda p: mv(Axis=ax_a, Execute=True, Velocity=30.0)
    rig.run_until(lambda: mv.InVelocity, 200)

    b = rig.plc("plcB")
    ax_b = b.axis("nc1", 1)
    pw_b, ov_b, halt = MC_Power(), MC_SetOverride(), MC_MoveVelocity()
    st = {"ov": False, "v": False}

    def prog_b(p: Any) -> None:
        pw_b(Axis=ax_b, Enable=True, Enable_Positive=True, Enable_Negative=True)
        ov_b(Axis=ax_b, Execute=st["ov"], Override=50.0)
        halt(Axis=ax_b, Execute=st["v"], Velocity=5.0)

    b.program = prog_b
    b.expect_hand_over("nc1", 1)
    rig.run(10)
    assert pw_b.Busy and not pw_b.Error and not pw_b.Active and not pw_b.Status  # waiting, no error
    assert rig.core.index(1) == 0 and pw_a.Status

    seen: list[int] = []
    calls_a["body"] = lambda p: (mv(Axis=ax_a, Execute=True, Velocity=30.0), seen.append(int(rig.rec()["StateDWord"])))
    req = a.hand_over("nc1", 1, "plcB")
    rig.run_until(lambda: pw_b.Status, 50)
    assert req.done and req.error == 0
    assert all(sd & CLC for sd in seen), "the axis was disabled during the hand-over"
    assert a.claim_state(ax_a).state == "handed" and b.claim_state(ax_b).state == "held"
    assert pw_b.Active and not pw_b.Error
    rig.run(20)
    assert not pw_a.Error and not pw_a.Status  # a's MC_Power: no error, the axis is not its any more
    assert abs(float(rig.rec()["SetVelo"]) - 30.0) < 1e-6, "the motion went on"
    # b now commands and holds it
    st["ov"], st["v"] = True, True
    rig.run_until(lambda: ov_b.Done and halt.InVelocity, 300)
    again = a.hand_over("nc1", 1, "plcA")
    rig.run(3)
    assert again.done and again.error == 0x723  # a does not hold it any more
