"""Issue 17 through the blocks against a real NcCore (the Rig): MC_Stop / MC_Halt brake with the stopped
job's effective dynamics (a lone value used, a negative one refused), MC_MoveVelocity's MC_Current_Direction
and MC_Shortest_Way, MC_NewPosAndVelo's switching-position modes on an MC_MoveVelocity (an ActivationPos
already passed: 0x427F), MC_MoveSuperImposedExt's unused Jerk and its VelocityProcess 0 (0x4B06)."""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import ErrorCodes, MC_Direction
from plc_client import MC_Halt, MC_MoveSuperImposedExt, MC_MoveVelocity, MC_NewPosAndVelo, MC_Stop
from znc_testing.plc_rig import Rig, powered


def cruise(rig: Rig, **mv_inputs: Any) -> tuple[Any, dict, Any]:
    """An MC_MoveVelocity at its velocity; returns (axis, the calls of the program, the block)."""
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveVelocity())
    calls["mv"] = mv_inputs
    calls["extra"] = lambda p: None

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, **calls["mv"])
        calls["extra"](p)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 300)
    return ax, calls, mv


def braking_peak(rig: Rig, done: Any, limit: int = 500) -> tuple[float, int]:
    """PLC cycles until ``done()``: (largest |SetAcc| seen by the NC meanwhile, cycles)."""
    peak = [0.0]
    core = rig.core

    def cond() -> bool:
        peak[0] = max(peak[0], abs(float(core.nctoplc[0]["SetAcc"])))
        return bool(done())

    n = rig.run_until(cond, limit)
    return peak[0], n


def test_stop_with_zeros_brakes_with_the_moves_deceleration(rig: Rig) -> None:
    """MC_MoveVelocity(200, Deceleration 200, Jerk 2000), then MC_Stop with its inputs 0: braked at 200 u/s^2
    for ~1.1 s (before: AxisDec, ~0.1 s)."""
    ax, calls, _ = cruise(rig, Velocity=200.0, Deceleration=200.0, Jerk=2000.0)
    stop = rig.watch(MC_Stop())
    calls["extra"] = lambda p: stop(Axis=ax, Execute=True)
    peak, n = braking_peak(rig, lambda: stop.Done)
    assert peak <= 200.0 * (1 + 1e-6) and peak > 190.0
    assert n >= 100  # 200 / 200 + 200 / 2000 = 1.1 s at 10 ms per PLC cycle
    assert ax.Status.MotionCommandsLocked and ax.Status.NotMoving


def test_stop_with_a_lone_deceleration_uses_it(rig: Rig) -> None:
    ax, calls, _ = cruise(rig, Velocity=200.0, Deceleration=200.0, Jerk=2000.0)
    stop = rig.watch(MC_Stop())
    calls["extra"] = lambda p: stop(Axis=ax, Execute=True, Deceleration=400.0)
    peak, _ = braking_peak(rig, lambda: stop.Done)
    assert peak == pytest.approx(400.0, rel=1e-6)


@pytest.mark.parametrize("cls, inputs, code", [
    (MC_Stop, {"Deceleration": -1.0}, ErrorCodes.NC_DECELERATION_NOT_ALLOWED),
    (MC_Stop, {"Jerk": -1.0}, ErrorCodes.NC_JERK_NOT_ALLOWED),
    (MC_Halt, {"Jerk": -1.0}, ErrorCodes.NC_JERK_NOT_ALLOWED),
])
def test_negative_stop_dynamics_are_an_error_and_change_nothing(rig: Rig, cls: Any, inputs: dict, code: int) -> None:
    """Before: MC_Stop accepted them (axis defaults) and locked the axis."""
    ax, calls, _ = cruise(rig, Velocity=100.0)
    fb = rig.watch(cls())
    calls["extra"] = lambda p: fb(Axis=ax, Execute=True, **inputs)
    rig.run_until(lambda: not fb.Busy, 10)
    assert fb.Error and fb.ErrorID == code
    assert not ax.Status.MotionCommandsLocked and math.isclose(float(ax.NcToPlc["SetVelo"]), 100.0)


def test_move_velocity_current_direction(rig: Rig) -> None:
    """At rest: Error 0x4B05. Moving backwards: a second block with MC_Current_Direction goes on backwards
    at its own velocity (before: 0x4B05 always)."""
    ax, _, calls = powered(rig)
    cur = rig.watch(MC_MoveVelocity())
    st = {"cur": True}
    calls["body"] = lambda p: cur(Axis=ax, Execute=st["cur"], Velocity=40.0,
                                  Direction=MC_Direction.MC_Current_Direction)
    rig.run_until(lambda: not cur.Busy, 10)
    assert cur.Error and cur.ErrorID == ErrorCodes.MC_COMMAND_NOT_PERMITTED
    st["cur"] = False
    rig.run(2)
    mv = rig.watch(MC_MoveVelocity())

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Velocity=20.0, Direction=MC_Direction.MC_Negative_Direction)
        cur(Axis=ax, Execute=st["cur"], Velocity=40.0, Direction=MC_Direction.MC_Current_Direction)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 100)
    st["cur"] = True
    rig.run_until(lambda: cur.InVelocity or cur.Error, 100)
    assert cur.InVelocity and math.isclose(float(ax.NcToPlc["SetVelo"]), -40.0)


def test_move_velocity_shortest_way_is_refused(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = rig.watch(MC_MoveVelocity())
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=40.0, Direction=MC_Direction.MC_Shortest_Way)
    rig.run_until(lambda: not mv.Busy, 10)
    assert mv.Error and mv.ErrorID == ErrorCodes.MC_COMMAND_NOT_PERMITTED


def test_new_pos_and_velo_at_a_switching_position_on_move_velocity(rig: Rig) -> None:
    """Mode 10 (CHANGE_VELO_AT_SWITCHPOS): Done when accepted; the velocity stays until the set position
    passes ActivationPos, then becomes NewVelo (before: Error 0x4B05)."""
    ax, calls, _ = cruise(rig, Velocity=100.0)
    npv = rig.watch(MC_NewPosAndVelo())
    at = float(ax.NcToPlc["SetPos"]) + 20.0
    calls["extra"] = lambda p: npv(Axis=ax, Execute=True, Mode=10, NewVelo=30.0, ActivationPos=at)
    rig.run_until(lambda: npv.Done or npv.Error, 10)
    assert npv.Done, npv.ErrorID
    core = rig.core
    seen: list[tuple[float, float]] = []

    def passed() -> bool:
        seen.append((float(core.nctoplc[0]["SetPos"]), float(core.nctoplc[0]["SetVelo"])))
        return seen[-1][0] >= at

    rig.run_until(passed, 100)
    assert len(seen) > 5 and all(v == 100.0 for p, v in seen if p < at), "unchanged before ActivationPos"
    rig.run_until(lambda: math.isclose(float(core.nctoplc[0]["SetVelo"]), 30.0), 100)
    assert ax.Status.ContinuousMotion


def test_new_pos_and_velo_with_an_activation_pos_already_passed_is_0x427f(rig: Rig) -> None:
    ax, calls, _ = cruise(rig, Velocity=100.0)
    npv = rig.watch(MC_NewPosAndVelo())
    at = float(ax.NcToPlc["SetPos"]) - 5.0
    calls["extra"] = lambda p: npv(Axis=ax, Execute=True, Mode=10, NewVelo=30.0, ActivationPos=at)
    rig.run_until(lambda: npv.Done or npv.Error, 10)
    assert npv.Error and npv.ErrorID == ErrorCodes.NC_NEW_TARGET_OVERRUN == 0x427F
    rig.run(20)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 100.0)


@pytest.mark.parametrize("jerk", [0.0, 500.0])
def test_superimposed_jerk_is_not_used(jerk: float) -> None:
    """Issue 17's conveyor: a belt at 300 u/s, Mode 2, Distance 300, VelocityDiff 500, Length 1000,
    VelocityProcess 300: Done with the full 300 whatever Jerk (before: Jerk 500 ended Error 0x4243 at 247)."""
    rig = Rig(n_axes=1)
    ax, calls, _ = cruise(rig, Velocity=300.0)
    sup = rig.watch(MC_MoveSuperImposedExt())
    calls["extra"] = lambda p: sup(Axis=ax, Execute=True, Mode=2, Distance=300.0, VelocityDiff=500.0, Length=1000.0,
                                   VelocityProcess=300.0, Jerk=jerk)
    rig.run_until(lambda: sup.Done or sup.Error, 400)
    assert sup.Done and not sup.Error, hex(sup.ErrorID)
    assert sup.ActualDistance == 300.0


def test_superimposed_velocity_process_0_is_0x4b06(rig: Rig) -> None:
    ax, calls, _ = cruise(rig, Velocity=100.0)
    sup = rig.watch(MC_MoveSuperImposedExt())
    calls["extra"] = lambda p: sup(Axis=ax, Execute=True, Mode=3, Distance=10.0, VelocityDiff=50.0, Length=100.0)
    rig.run_until(lambda: not sup.Busy, 10)
    assert sup.Error and sup.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT
