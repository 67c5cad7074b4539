"""Conformance scenarios for homing and position setting against the real NcCore (TcMC 3.14, 4.12,
4.13, 4.15; Tc2_MC2 MC_Home / MC_HomingMode): block outputs, StateDWord.Homed, HomingState, the
positions, cycle by cycle."""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import DEFAULT_HOME_POSITION, ErrorCodes, MC_HomingMode
from nc_server.core import AxisParams
from plc_client import (MC_GearIn, MC_Home, MC_MoveAbsolute, MC_MoveRelative, MC_MoveVelocity, MC_Power,
                        MC_SetActualPosition, MC_SetActualPositionOnTheFly, MC_SetReferenceFlag, MC_Stop)
from znc_testing.plc_rig import OffsetDrive, Rig, powered

CAM_AT = -3.5


def _homing_states(rig: Rig) -> list[int]:
    seen: list[int] = []
    step = rig.core.step

    def rec_step(*a: Any, **k: Any) -> None:
        step(*a, **k)
        s = int(rig.rec()["HomingState"])
        if not seen or seen[-1] != s:
            seen.append(s)

    rig.core.step = rec_step  # type: ignore[method-assign]
    return seen


def test_default_homing_clears_homed_while_running_and_sets_it_at_done() -> None:
    rig = Rig(params=AxisParams(Homed=True, AxisCalibrationValue=7.0))
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    trace: list[tuple[bool, bool, int, bool]] = []

    def body(p: Any) -> None:
        home(Axis=ax, Execute=True, bCalibrationCam=ax.ActPos < CAM_AT)
        trace.append((home.Busy, home.Done, int(ax.NcToPlc["HomingState"]), bool(ax.Status.Homed)))

    calls["body"] = body
    assert ax.Status.Homed
    rig.run_until(lambda: not home.Busy, 2000)
    assert home.Done
    assert all(not h for b, d, s, h in trace if b and s != 0), "Homed FALSE while the sequence runs"
    assert all(h and s == 0 for b, d, s, h in trace if d), "Done with Homed and HomingState 0"
    assert 0.0 <= ax.ActPos - 7.0 < 0.2, "DEFAULT_HOME_POSITION: AxisCalibrationValue"


def test_stop_during_homing_leaves_a_previously_homed_axis_unhomed() -> None:
    rig = Rig(params=AxisParams(Homed=True))
    ax, _, calls = powered(rig)
    home, stop = rig.watch(MC_Home(), MC_Stop())
    st = {"stop": False}

    def body(p: Any) -> None:
        home(Axis=ax, Execute=True, bCalibrationCam=ax.ActPos < CAM_AT)
        stop(Axis=ax, Execute=st["stop"])

    calls["body"] = body
    rig.run_until(lambda: int(ax.NcToPlc["HomingState"]) == 2, 20)
    st["stop"] = True
    rig.run_until(lambda: home.CommandAborted, 10)
    rig.run_until(lambda: stop.Done, 100)
    assert not ax.Status.Homed and not home.Done and not home.Error


def test_move_during_homing_is_refused_and_homing_goes_on() -> None:
    """PLCopen state table (reference §3.4): Homing -> a move is rejected (TcMC 3.14 names 'a
    superimposed travel command' among CommandAborted's reasons: the sources disagree; the NC keeps
    the PLCopen rule)."""
    rig = Rig()
    ax, _, calls = powered(rig)
    home, mv = rig.watch(MC_Home(), MC_MoveAbsolute())
    st = {"mv": False}

    def body(p: Any) -> None:
        home(Axis=ax, Execute=True, bCalibrationCam=ax.ActPos < CAM_AT)
        mv(Axis=ax, Execute=st["mv"], Position=5.0, Velocity=10.0)

    calls["body"] = body
    rig.run_until(lambda: int(ax.NcToPlc["HomingState"]) == 2, 20)
    st["mv"] = True
    rig.run_until(lambda: not mv.Busy or home.CommandAborted, 300)
    assert mv.Error and mv.ErrorID == ErrorCodes.MC_AXIS_CANNOT_BE_STARTED
    assert home.Busy and not home.CommandAborted and not ax.Status.Homed
    rig.run_until(lambda: not home.Busy, 2000)
    assert home.Done and ax.Status.Homed


def test_home_on_axis_in_error(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    rig.core.fault(0, 0x4550)
    rig.run(2)
    assert ax.Status.Error
    home = rig.watch(MC_Home())
    calls["body"] = lambda p: home(Axis=ax, Execute=True, HomingMode=int(MC_HomingMode.MC_ForceCalibration))
    rig.run_until(lambda: not home.Busy, 10)
    assert home.Error and home.ErrorID == ErrorCodes.MC_AXIS_CANNOT_BE_STARTED and not ax.Status.Homed


@pytest.mark.parametrize("mode", [int(MC_HomingMode.MC_DefaultHoming), int(MC_HomingMode.MC_Direct),
                                  int(MC_HomingMode.MC_ForceCalibration), int(MC_HomingMode.MC_ResetCalibration)])
def test_home_on_disabled_axis_is_refused_in_every_mode(mode: int) -> None:
    """PLCopen (reference §3.4): Disabled -> MC_Home rejected; also the modes without motion
    (Tc2_MC2 is silent on them)."""
    rig = Rig()
    plc = rig.plc("plc1")
    ax = plc.axis("nc1", 1)
    home = rig.watch(MC_Home())
    plc.program = lambda p: home(Axis=ax, Execute=True, Position=3.0, HomingMode=mode)
    rig.run_until(lambda: not home.Busy, 10)
    assert home.Error and home.ErrorID == ErrorCodes.NC_NO_ENABLE
    assert not ax.Status.Homed and ax.ActPos == 0.0


def test_direct_with_default_home_position_uses_calibration_value() -> None:
    rig = Rig(params=AxisParams(AxisCalibrationValue=12.5))
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    calls["body"] = lambda p: home(Axis=ax, Execute=True, HomingMode=int(MC_HomingMode.MC_Direct))
    rig.run_until(lambda: not home.Busy, 20)
    assert home.Done and ax.Status.Homed and math.isclose(ax.ActPos, 12.5, abs_tol=1e-9)
    assert math.isclose(float(ax.NcToPlc["SetPos"]), 12.5, abs_tol=1e-9)


@pytest.mark.parametrize("mode", [1, 2, 3, 5, 6, 9, -1])
def test_unimplemented_modes(rig: Rig, mode: int) -> None:
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    calls["body"] = lambda p: home(Axis=ax, Execute=True, HomingMode=mode)
    rig.run_until(lambda: not home.Busy, 10)
    assert home.Error and home.ErrorID == ErrorCodes.MC_INVALID_MODE and not ax.Status.Homed


@pytest.mark.parametrize("pos", [float("nan"), float("inf"), 2e9])
def test_home_bad_position(rig: Rig, pos: float) -> None:
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    calls["body"] = lambda p: home(Axis=ax, Execute=True, Position=pos, HomingMode=int(MC_HomingMode.MC_Direct))
    rig.run_until(lambda: not home.Busy, 10)
    assert home.Error and home.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT, hex(home.ErrorID)


def test_modes_without_motion_keep_homing_state_zero_and_done_timing(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    seen = _homing_states(rig)
    got: dict = {}

    def body(p: Any) -> None:
        home(Axis=ax, Execute=True, HomingMode=int(MC_HomingMode.MC_ForceCalibration))
        if home.Done and "homed" not in got:
            got["homed"] = ax.Status.Homed

    calls["body"] = body
    n = rig.run_until(lambda: home.Done, 10)
    assert got["homed"] and seen == [0] and n <= 4, (n, seen)


def test_set_actual_position_standing_shifts_set_and_target_not_limits() -> None:
    rig = Rig(params=AxisParams(AxisEnMaxSoftPosLimit=True, AxisMaxSoftPosLimit=100.0))
    ax, _, calls = powered(rig)
    sp, mv = rig.watch(MC_SetActualPosition(), MC_MoveRelative())
    st = {"mv": False}

    def body(p: Any) -> None:
        sp(Axis=ax, Execute=True, Position=95.0)
        mv(Axis=ax, Execute=st["mv"], Distance=10.0, Velocity=10.0)

    calls["body"] = body
    rig.run_until(lambda: sp.Done, 5)
    r = rig.rec()
    assert math.isclose(float(r["SetPos"]), 95.0) and math.isclose(float(r["ActPos"]), 95.0)
    assert math.isclose(float(r["TargetPos"]), 95.0)
    assert not ax.Status.Homed, "MC_SetActualPosition does not touch the reference flag"
    st["mv"] = True
    rig.run_until(lambda: not mv.Busy, 300)
    assert mv.Error and not mv.Done, "the soft limit 100 stays where it is (95 + 10 beyond it)"


def test_set_actual_position_on_disabled_axis() -> None:
    rig = Rig()
    plc = rig.plc("plc1")
    ax = plc.axis("nc1", 1)
    sp = rig.watch(MC_SetActualPosition())
    plc.program = lambda p: sp(Axis=ax, Execute=True, Position=-20.0)
    rig.run_until(lambda: not sp.Busy, 10)
    assert sp.Done and math.isclose(ax.ActPos, -20.0)


def test_set_actual_position_during_homing_refused(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    home, sp = rig.watch(MC_Home(), MC_SetActualPosition())
    st = {"sp": False}

    def body(p: Any) -> None:
        home(Axis=ax, Execute=True, bCalibrationCam=ax.ActPos < CAM_AT)
        sp(Axis=ax, Execute=st["sp"], Position=0.0)

    calls["body"] = body
    rig.run_until(lambda: home.Active, 10)
    st["sp"] = True
    rig.run_until(lambda: not sp.Busy, 10)
    assert sp.Error and sp.ErrorID == ErrorCodes.MC_AXIS_CANNOT_BE_STARTED and home.Busy


@pytest.mark.parametrize("a, b", [(float("nan"), 0.0), (0.0, float("inf"))])
def test_on_the_fly_bad_inputs(rig: Rig, a: float, b: float) -> None:
    ax, _, calls = powered(rig)
    fly = rig.watch(MC_SetActualPositionOnTheFly())
    calls["body"] = lambda p: fly(Axis=ax, Execute=True, ActualPosition=a, PreviousPosition=b)
    rig.run(1)
    assert fly.Error and fly.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT and not fly.Busy


def test_on_the_fly_during_velocity_move_keeps_homed_and_busy_done(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, fly, ref = rig.watch(MC_MoveVelocity(), MC_SetActualPositionOnTheFly(), MC_SetReferenceFlag())
    st = {"fly": False}

    def body(p: Any) -> None:
        ref(Axis=ax, Execute=True, ReferenceFlag=True)
        mv(Axis=ax, Execute=True, Velocity=10.0)
        fly(Axis=ax, Execute=st["fly"], ActualPosition=-100.0, PreviousPosition=ax.ActPos)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity and ref.Done, 100)
    st["fly"] = True
    rig.run(1)
    assert fly.Busy and not fly.Done
    rig.run_until(lambda: fly.Done, 5)
    assert -100.0 <= ax.ActPos < -99.0 and mv.InVelocity and not mv.CommandAborted and ax.Status.Homed


def test_reference_flag_while_moving(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, ref = rig.watch(MC_MoveVelocity(), MC_SetReferenceFlag())
    st = {"ref": False}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Velocity=10.0)
        ref(Axis=ax, Execute=st["ref"], ReferenceFlag=True)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 100)
    st["ref"] = True
    rig.run_until(lambda: not ref.Busy, 5)
    assert ref.Done and ax.Status.Homed and mv.InVelocity and not mv.CommandAborted


def test_axis_error_during_homing_ends_it_with_the_error_and_unhomed() -> None:
    """TcMC 3.14: 'Error: Becomes TRUE, as soon as an error occurs' (CommandAborted also names 'an
    error' among its reasons: the block reports Error with the axis's code)."""
    rig = Rig(params=AxisParams(Homed=True))
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    calls["body"] = lambda p: home(Axis=ax, Execute=True, bCalibrationCam=ax.ActPos < CAM_AT)
    rig.run_until(lambda: int(ax.NcToPlc["HomingState"]) == 2, 20)
    rig.core.fault(0, 0x4550)
    rig.run_until(lambda: not home.Busy, 5)
    assert home.Error and home.ErrorID == 0x4550 and not home.CommandAborted
    rig.run(2)  # (the fault was injected between NC cycles: its frame follows)
    assert not ax.Status.Homed and int(ax.NcToPlc["HomingState"]) == 0


def test_disable_during_homing_aborts_it() -> None:
    rig = Rig()
    plc = rig.plc("plc1")
    ax = plc.axis("nc1", 1)
    pw, home = MC_Power(), rig.watch(MC_Home())
    st = {"en": True, "h": False}

    def prog(p: Any) -> None:
        pw(Axis=ax, Enable=st["en"], Enable_Positive=True, Enable_Negative=True)
        home(Axis=ax, Execute=st["h"], bCalibrationCam=ax.ActPos < CAM_AT)

    plc.program = prog
    rig.run_until(lambda: pw.Status, 10)
    st["h"] = True
    rig.run_until(lambda: int(ax.NcToPlc["HomingState"]) == 2, 20)
    st["en"] = False
    rig.run_until(lambda: not home.Busy, 5)
    assert home.CommandAborted and not ax.Status.Homed and int(ax.NcToPlc["HomingState"]) == 0


@pytest.mark.parametrize("mode, homed_after, pos_after", [(0, True, None), (7, True, 10.0), (8, False, 10.0)])
def test_buffered_home_waits_for_the_move(mode: int, homed_after: bool, pos_after: float | None) -> None:
    rig = Rig(params=AxisParams(Homed=(mode == 8)))
    ax, _, calls = powered(rig)
    mv, home = rig.watch(MC_MoveAbsolute(), MC_Home())
    st = {"h": False}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Position=10.0, Velocity=20.0)
        home(Axis=ax, Execute=st["h"], HomingMode=mode, BufferMode=1, bCalibrationCam=ax.ActPos < CAM_AT)

    calls["body"] = body
    rig.run(5)
    st["h"] = True
    rig.run(2)
    assert home.Busy and not home.Active and ax.Status.Homed is (mode == 8), "waits, Homed untouched"
    rig.run_until(lambda: not home.Busy, 2000)
    assert home.Done and mv.Done and ax.Status.Homed is homed_after
    if pos_after is not None:
        assert math.isclose(ax.ActPos, pos_after, abs_tol=1e-6), "no motion, position unchanged"


def test_homing_positive_search_negative_sync() -> None:
    """The parameters' directions: cam searched in positive direction, left in negative; the
    axis stands at the reference + the braking distance (in the sync direction)."""
    rig = Rig(params=AxisParams(AxisInvertCalibrationCamSearchDirection=False,
                                AxisInvertSyncPulseSearchDirection=True))
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    calls["body"] = lambda p: home(Axis=ax, Execute=True, Position=20.0, bCalibrationCam=ax.ActPos > 3.5)
    rig.run_until(lambda: not home.Busy, 2000)
    assert home.Done and ax.Status.Homed
    assert -0.2 < ax.ActPos - 20.0 <= 0.0


def test_set_actual_position_keeps_the_lag() -> None:
    """Tc2_MC2 MC_SetPosition: 'the set position of the axis is set such that any following error
    that may exist is retained' (TcMC 4.12 is silent): actual and set position move together."""
    rig = Rig(drive_cls=OffsetDrive)
    ax, _, calls = powered(rig)
    sp = rig.watch(MC_SetActualPosition())
    rig.run(20)
    lag = float(rig.rec()["SetPos"]) - float(rig.rec()["ActPos"])
    assert lag > 0.4
    calls["body"] = lambda p: sp(Axis=ax, Execute=True, Position=50.0)
    rig.run_until(lambda: sp.Done, 10)
    r = rig.rec()
    assert math.isclose(float(r["ActPos"]), 50.0, abs_tol=1e-9)
    assert math.isclose(float(r["SetPos"]) - float(r["ActPos"]), lag, abs_tol=1e-6)


def test_home_and_set_position_on_a_coupled_slave_are_refused() -> None:
    rig = Rig()
    plc = rig.plc("plc1")
    a1, a2 = plc.axis("nc1", 1), plc.axis("nc1", 2)
    p1, p2, gi = MC_Power(), MC_Power(), MC_GearIn()
    home, sp = rig.watch(MC_Home(), MC_SetActualPosition())
    st = {"h": False}

    def prog(p: Any) -> None:
        p1(Axis=a1, Enable=True, Enable_Positive=True, Enable_Negative=True)
        p2(Axis=a2, Enable=True, Enable_Positive=True, Enable_Negative=True)
        gi(Master=a1, Slave=a2, Execute=p1.Status and p2.Status)
        home(Axis=a2, Execute=st["h"], HomingMode=int(MC_HomingMode.MC_ForceCalibration))
        sp(Axis=a2, Execute=st["h"], Position=7.0)

    plc.program = prog
    rig.run_until(lambda: gi.InGear, 50)
    st["h"] = True
    rig.run_until(lambda: not home.Busy and not sp.Busy, 10)
    assert home.Error and home.ErrorID == 0x4266 and not a2.Status.Homed
    assert sp.Error and sp.ErrorID == ErrorCodes.MC_AXIS_CANNOT_BE_STARTED and gi.InGear


def test_position_blocks_on_an_axis_in_error_are_executed(rig: Rig) -> None:
    """Not motion commands (zenoh-nc choice; TcMC 4.12/4.13/4.15 are silent): accepted in ErrorStop."""
    ax, _, calls = powered(rig)
    sp, ref, fly = rig.watch(MC_SetActualPosition(), MC_SetReferenceFlag(), MC_SetActualPositionOnTheFly())
    rig.core.fault(0, 0x4550)
    rig.run(2)
    calls["body"] = lambda p: (sp(Axis=ax, Execute=True, Position=370.0),
                               ref(Axis=ax, Execute=True, ReferenceFlag=True),
                               fly(Axis=ax, Execute=True, ActualPosition=1.0, PreviousPosition=0.0))
    rig.run_until(lambda: sp.Done and ref.Done and fly.Done, 10)
    assert math.isclose(ax.ActPos, 371.0, abs_tol=1e-9) and ax.Status.Homed and ax.Status.Error
