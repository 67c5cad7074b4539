"""Parameters that act (issue 17): the actual position correction (1046/1047), backlash compensation
(1035/1036), the dead time (1032) and motion monitoring (1029-1031, 0x435D): each one's effect on the
pure core, when it can be written, its TwinCAT code for a bad value (nothing changes) and that a
written value is retained."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from nc_schema import ErrorCodes as E, OpModeDWord, StateDWord
from nc_server.core import AxisConfig, AxisParams, NcCore
from nc_server.core.params import ConfigError, param_name
from nc_server.drives.sim import SimDrive
from nc_server.server.retain import RetainKeeper, encode_retain, write_atomic
from znc_testing.nc_core import cmd, make_core, power, powered, run_until, snapshot

DT = 0.001
IN_TARGET = int(StateDWord.InTargetPosition)
#: the lag of the simulated drive (first-order, SimTimeConstant 1 ms, stepped every 1 ms) at 100 u/s [u]
LAG_100 = 100.0 * DT * math.exp(-1.0) / (1.0 - math.exp(-1.0))


def write(core: NcCore, number: int, value: Any, axis: int = 1) -> int:
    """WriteParameter; its error code."""
    return int(cmd(core, "WriteParameter", axis, ParameterNumber=number, Value=value)["error"])


def correction(core: NcCore, value: float, i: int = 0) -> None:
    """PLCTONC.PositionCorrection of row ``i`` (the rest of its PLCTONC as it is)."""
    rec = core.plctonc[i].copy()
    rec["PositionCorrection"] = value
    core.set_plctonc(i, rec)


def move(core: NcCore, position: float, velocity: float = 100.0) -> None:
    assert cmd(core, "MoveAbsolute", Position=position, Velocity=velocity)["error"] == 0
    run_until(core, lambda: int(core.nctoplc[0]["StateDWord"]) & IN_TARGET and not core.axes.has_job[0])


def row(core: NcCore) -> np.void:
    return core.nctoplc[0]


# ---- actual position correction (1046, 1047) ---------------------------------------------------------------
def test_position_correction_is_added_to_the_actual_position() -> None:
    core = powered(AxisEnActPosCorrection=True)
    assert int(row(core)["OpModeDWord"]) & int(OpModeDWord.OpModePosCorrection)
    correction(core, 2.0)
    core.step()
    r = row(core)
    # unfiltered: the whole correction at once; the drive has not moved yet
    assert r["ActPos"] - r["ActPosWithoutPosCorrection"] == pytest.approx(2.0)
    for _ in range(100):
        core.step()
    r = row(core)
    # the controller closes its loop on the corrected position: the drive (the uncorrected side) moved by -2
    assert r["ActPos"] == pytest.approx(0.0, abs=1e-6) and r["SetPos"] == 0.0
    assert r["ActPosWithoutPosCorrection"] == pytest.approx(-2.0, abs=1e-6)
    assert float(core.drive.act_pos[0]) == pytest.approx(-2.0, abs=1e-6)


def test_position_correction_goes_through_a_pt1_filter() -> None:
    t = 0.05
    core = powered(AxisEnActPosCorrection=True, AxisActPosCorrectionFilterTime=t)
    correction(core, 2.0)
    alpha = 1.0 - math.exp(-DT / t)
    for k in range(1, 201):
        core.step()
        r = row(core)
        assert r["ActPos"] - r["ActPosWithoutPosCorrection"] == pytest.approx(2.0 * (1.0 - (1.0 - alpha) ** k), rel=1e-9)
    # written while moving or standing: the filter time applies from the next cycle
    assert write(core, 1047, 0.0) == 0
    correction(core, -1.0)
    core.step()
    r = row(core)
    assert r["ActPos"] - r["ActPosWithoutPosCorrection"] == pytest.approx(-1.0)


def test_position_correction_off_ignores_the_input_and_non_finite_values_are_ignored() -> None:
    core = powered()
    correction(core, 5.0)
    for _ in range(20):
        core.step()
    r = row(core)
    assert r["ActPos"] == r["ActPosWithoutPosCorrection"] == 0.0
    assert not int(r["OpModeDWord"]) & int(OpModeDWord.OpModePosCorrection)
    core = powered(AxisEnActPosCorrection=True)
    correction(core, 1.5)
    core.step()
    correction(core, float("nan"))
    for _ in range(20):
        core.step()
    r = row(core)
    assert r["ActPos"] - r["ActPosWithoutPosCorrection"] == pytest.approx(1.5)
    assert math.isfinite(float(r["ActPos"]))


def test_position_correction_switched_off_at_standstill_leaves_at_once() -> None:
    core = powered(AxisEnActPosCorrection=True)
    correction(core, 3.0)
    for _ in range(50):
        core.step()
    assert write(core, 1046, False) == 0
    core.step()
    r = row(core)
    assert r["ActPos"] == r["ActPosWithoutPosCorrection"]
    assert not int(r["OpModeDWord"]) & int(OpModeDWord.OpModePosCorrection)
    for _ in range(50):
        core.step()
    assert float(row(core)["ActPos"]) == pytest.approx(0.0, abs=1e-6)  # the drive went back
    assert write(core, 1046, True) == 0  # on again: the filter starts from 0, the input is still 3
    core.step()
    r = row(core)
    assert r["ActPos"] - r["ActPosWithoutPosCorrection"] == pytest.approx(3.0)


def test_positioning_with_a_correction_ends_on_the_target() -> None:
    core = powered(AxisEnActPosCorrection=True, AxisActPosCorrectionFilterTime=0.01)
    correction(core, 0.7)
    move(core, 50.0)
    r = row(core)
    assert r["ActPos"] == pytest.approx(50.0, abs=0.02) and r["ErrorCode"] == 0
    assert r["ActPosWithoutPosCorrection"] == pytest.approx(49.3, abs=0.02)


# ---- backlash compensation (1035, 1036) ---------------------------------------------------------------------
def test_backlash_is_added_on_the_negative_side_as_a_step_at_the_reversal() -> None:
    b = 0.4
    core = powered(AxisEnBacklashCompensation=True, AxisBacklash=b, AxisVeloMax=500.0)
    assert int(row(core)["OpModeDWord"]) & int(OpModeDWord.OpModeBacklashCompensation)
    move(core, 10.0)  # positive: the reference direction, no compensation
    assert float(core.drive.act_pos[0]) == pytest.approx(float(row(core)["ActPos"]))
    assert cmd(core, "MoveAbsolute", Position=0.0, Velocity=100.0)["error"] == 0
    before = float(row(core)["ActPos"])
    run_until(core, lambda: float(core.nctoplc[0]["SetVelo"]) < 0)
    # the cycle the set velocity turns negative: the play comes as one step
    assert float(row(core)["ActPos"]) - float(core.drive.act_pos[0]) == pytest.approx(b)
    # (in that cycle the drive, a first-order lag of 1 ms, already covers 1 - e^-1 of the step)
    assert float(row(core)["ActPos"]) - before == pytest.approx(b * math.exp(-1.0), abs=0.01)
    run_until(core, lambda: int(core.nctoplc[0]["StateDWord"]) & IN_TARGET and not core.axes.has_job[0])
    r = row(core)
    # on the negative side the drive stands the backlash further negative; ActPos is on the target
    assert r["ActPos"] == pytest.approx(0.0, abs=0.02) and r["ErrorCode"] == 0
    assert float(core.drive.act_pos[0]) == pytest.approx(-b, abs=0.02)
    assert r["ActPosWithoutPosCorrection"] == r["ActPos"]  # (the backlash is not the PLC's correction)
    move(core, 5.0)  # positive again: no compensation
    assert float(core.drive.act_pos[0]) == pytest.approx(5.0, abs=0.02)
    assert float(row(core)["ActPos"]) == pytest.approx(5.0, abs=0.02)


def test_backlash_with_a_dead_time_steps_when_the_delayed_set_point_reverses() -> None:
    # the drive follows the set position 20 cycles late: the play must come when that one reverses, not
    # when SetVelo does (a step while the drive still travels the old way would jerk it backwards)
    b, cycles = 0.4, 20
    core = powered(AxisEnBacklashCompensation=True, AxisBacklash=b, AxisVeloMax=500.0,
                   AxisDelayTimeVeloPosition=cycles * DT)
    move(core, 10.0)
    assert cmd(core, "MoveAbsolute", Position=0.0, Velocity=100.0)["error"] == 0
    run_until(core, lambda: float(core.nctoplc[0]["SetVelo"]) < 0)
    for _ in range(cycles - 2):  # the delayed set-point still stands (the move started from rest)
        core.step()
        assert float(row(core)["ActPos"]) - float(core.drive.act_pos[0]) == pytest.approx(0.0, abs=1e-9)
    run_until(core, lambda: abs(float(row(core)["ActPos"]) - float(core.drive.act_pos[0])) > b / 2, max_cycles=10)
    run_until(core, lambda: int(core.nctoplc[0]["StateDWord"]) & IN_TARGET and not core.axes.has_job[0])
    assert float(core.drive.act_pos[0]) == pytest.approx(-b, abs=0.02) and row(core)["ErrorCode"] == 0


def test_backlash_switched_on_starts_from_the_positive_reference_direction() -> None:
    core = powered(AxisVeloMax=500.0)
    move(core, -10.0)  # the last motion was negative, but the compensation was off
    assert write(core, 1036, 0.3) == 0
    assert write(core, 1035, True) == 0
    for _ in range(20):
        core.step()
    assert float(core.drive.act_pos[0]) == pytest.approx(float(row(core)["ActPos"]))
    move(core, -20.0)  # the next negative motion brings it
    assert float(core.drive.act_pos[0]) == pytest.approx(-20.3, abs=0.02)
    assert write(core, 1035, False) == 0  # off at standstill: the drive goes back to the set position
    for _ in range(100):
        core.step()
    assert float(core.drive.act_pos[0]) == pytest.approx(-20.0, abs=1e-6)
    assert float(row(core)["ActPos"]) == pytest.approx(-20.0, abs=1e-6)


# ---- dead time (1032) -------------------------------------------------------------------------------------
@pytest.mark.parametrize("dead_time, cycles", [(0.005, 5), (0.0034, 3), (0.1, 100)])
def test_posdiff_compares_with_the_delayed_set_position(dead_time: float, cycles: int) -> None:
    core = powered(AxisDelayTimeVeloPosition=dead_time, AxisVeloMax=500.0)
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)["error"] == 0
    sets = []
    for _ in range(400):
        core.step()
        r = row(core)
        sets.append(float(r["SetPos"]))
        if len(sets) > cycles:
            assert float(r["PosDiff"]) == pytest.approx(sets[-1 - cycles] - float(r["ActPos"]), abs=1e-9)
    r = row(core)
    lag = LAG_100  # the simulated drive's lag at constant velocity
    assert float(r["PosDiff"]) == pytest.approx(lag, rel=0.1)  # the dead time does not show as a lag
    assert float(r["SetPos"] - r["ActPos"]) == pytest.approx(lag + 100.0 * cycles * DT, rel=0.05)
    assert r["ErrorCode"] == 0


def test_dead_time_against_a_lag_monitoring_that_would_trip_without_it() -> None:
    # the drive follows the delayed set position; a lag window of 1 u at 500 u/s with a 10 ms dead time:
    # SetPos - ActPos is about 5.5 u, PosDiff about 0.5 u, no 0x4550
    core = powered(AxisDelayTimeVeloPosition=0.01, AxisVeloMax=1000.0, AxisMaxPosLagValue=1.0)
    move(core, 200.0, 500.0)
    assert row(core)["ErrorCode"] == 0 and float(row(core)["ActPos"]) == pytest.approx(200.0, abs=0.02)


def test_set_actual_position_moves_the_history_with_it() -> None:
    core = powered(AxisDelayTimeVeloPosition=0.02, AxisVeloMax=500.0)
    assert cmd(core, "SetActualPosition", Position=100.0)["error"] == 0
    for _ in range(30):
        core.step()
        assert float(core.drive.act_pos[0]) == 0.0  # nothing moves: the old positions are not replayed
        assert float(row(core)["PosDiff"]) == pytest.approx(0.0, abs=1e-9)
    assert cmd(core, "MoveVelocity", Velocity=100.0, Direction=1)["error"] == 0
    for _ in range(200):
        core.step()
    v0 = float(core.axes.set_velo[0])
    before = float(core.drive.act_pos[0])
    assert cmd(core, "SetActualPositionOnTheFly", ActualPosition=0.0,
               PreviousPosition=float(row(core)["ActPos"]))["error"] == 0  # (on the fly: the running motion goes on)
    core.step()
    assert float(core.drive.act_pos[0]) - before == pytest.approx(v0 * DT, rel=0.05)  # no jump of the drive
    assert float(row(core)["PosDiff"]) == pytest.approx(LAG_100, rel=0.1)


def test_enabling_after_the_position_moved_without_motion_does_not_replay_the_history() -> None:
    # a disabled axis whose actual position jumped (here: a position correction of 100 u switched in);
    # its set position follows; enabled a few cycles later, the drive must stay where it is
    core = make_core(AxisDelayTimeVeloPosition=0.05, AxisEnActPosCorrection=True)
    core.step()
    correction(core, 100.0)
    for _ in range(10):
        core.step()
    assert float(row(core)["ActPos"]) == pytest.approx(100.0)
    power(core)
    rec = core.plctonc[0].copy()
    rec["PositionCorrection"] = 100.0
    core.set_plctonc(0, rec)
    for _ in range(100):
        core.step()
        assert float(core.drive.act_pos[0]) == pytest.approx(0.0, abs=1e-9)
    assert float(row(core)["ActPos"]) == pytest.approx(100.0) and row(core)["ErrorCode"] == 0


def test_dead_time_off_again_restarts_from_the_set_position() -> None:
    core = powered(AxisDelayTimeVeloPosition=0.02, AxisVeloMax=500.0)
    move(core, 30.0)
    assert write(core, 1032, 0.0) == 0
    core.step()
    assert float(row(core)["PosDiff"]) == pytest.approx(float(row(core)["SetPos"] - row(core)["ActPos"]))
    move(core, 0.0)
    assert float(row(core)["ActPos"]) == pytest.approx(0.0, abs=0.02)


# ---- motion monitoring (1029-1031) ---------------------------------------------------------------------------
def _stepper(**kw: Any) -> NcCore:
    """A simulated stepper (it can be made to stall: SimStall) without lag monitoring (the stall would trip it)."""
    p: dict[str, Any] = dict(SimStepper=True, AxisEnPositionLagMonitoring=False, AxisEnMotionMonitoring=True,
                             AxisMotionMonitoringWindow=0.5, AxisMotionMonitoringTime=0.05)
    p.update(kw)
    return powered(**p)


def test_a_blocked_axis_gets_motion_monitoring_error_after_the_time() -> None:
    core = _stepper()
    assert int(row(core)["OpModeDWord"]) & int(OpModeDWord.OpModeMotionMonitoring)
    assert cmd(core, "MoveVelocity", Velocity=50.0, Direction=1)["error"] == 0
    for _ in range(300):
        core.step()
    assert row(core)["ErrorCode"] == 0  # it moves: 0.5 u every 10 ms
    assert cmd(core, "SimStall", Stall=True)["error"] == 0
    n = run_until(core, lambda: core.nctoplc[0]["ErrorCode"], 1000)
    assert row(core)["ErrorCode"] == E.NC_AXIS_MOTION_MONITORING
    # the window it was in began up to one window (10 ms here) before the stall: 40..50 ms after it
    assert 38 <= n <= 52, n


def test_motion_monitoring_watches_only_an_axis_that_should_move() -> None:
    core = _stepper()
    assert cmd(core, "SimStall", Stall=True)["error"] == 0
    for _ in range(200):  # standing, enabled
        core.step()
    assert row(core)["ErrorCode"] == 0
    power(core, override=0)  # override 0: a held job is not a blocked axis
    core.step()
    assert cmd(core, "MoveVelocity", Velocity=50.0, Direction=1)["error"] == 0
    for _ in range(200):
        core.step()
    assert row(core)["ErrorCode"] == 0 and core.axes.has_job[0]
    assert cmd(core, "SimStall", Stall=True)["error"] == 0
    power(core)  # override 100 %: it should move now, but cannot
    run_until(core, lambda: core.nctoplc[0]["ErrorCode"], 1000)
    assert row(core)["ErrorCode"] == E.NC_AXIS_MOTION_MONITORING


def test_motion_monitoring_off_or_slow_enough_window() -> None:
    core = _stepper(AxisEnMotionMonitoring=False)
    assert cmd(core, "MoveVelocity", Velocity=50.0, Direction=1)["error"] == 0
    assert cmd(core, "SimStall", Stall=True)["error"] == 0
    for _ in range(500):
        core.step()
    assert row(core)["ErrorCode"] == 0  # off: a stalled axis goes unnoticed (lag monitoring is off too)
    # switched on while it runs (all three are written any time): its first window starts then
    assert write(core, 1031, 0.2) == 0 and write(core, 1030, 0.1) == 0
    assert write(core, 1029, True) == 0
    n = run_until(core, lambda: core.nctoplc[0]["ErrorCode"], 1000)
    assert row(core)["ErrorCode"] == E.NC_AXIS_MOTION_MONITORING and 195 <= n <= 205, n
    # a servo axis moving 50 u/s covers the window 0.5 u in 10 ms < 50 ms: never an error
    core = powered(AxisEnMotionMonitoring=True, AxisMotionMonitoringWindow=0.5, AxisMotionMonitoringTime=0.05)
    move(core, 20.0, 50.0)
    assert row(core)["ErrorCode"] == 0


# ---- when writable, bad values, the configuration ----------------------------------------------------------
@pytest.fixture
def moving() -> NcCore:
    core = powered(AxisVeloMax=500.0)
    assert cmd(core, "MoveVelocity", Velocity=50.0, Direction=1)["error"] == 0
    for _ in range(100):
        core.step()
    return core


@pytest.mark.parametrize("number, value", [(1032, 0.01), (1035, True), (1036, 0.2), (1046, True)])
def test_written_only_at_standstill(moving: NcCore, number: int, value: Any) -> None:
    before = [vars(p) for p in moving.params]
    assert write(moving, number, value) == E.NC_GROUP_NOT_READY
    assert [vars(p) for p in moving.params] == before
    assert cmd(moving, "Halt")["error"] == 0
    run_until(moving, lambda: not moving.axes.has_job[0])
    assert write(moving, number, value) == 0


def test_the_filter_time_is_written_any_time(moving: NcCore) -> None:
    assert write(moving, 1047, 0.02) == 0  # (motion monitoring's 1029-1031: test_motion_monitoring_off_...)
    assert moving.read_parameter(0, 1047) == 0.02


@pytest.mark.parametrize("number, value, code", [
    (1032, 0.2, E.NC_AXIS_DEAD_TIME_NOT_ALLOWED),                   # at most 0.1 s
    (1032, -0.001, E.NC_AXIS_DEAD_TIME_NOT_ALLOWED),
    (1029, 0.5, E.NC_AXIS_MOTION_MONITORING_NOT_ALLOWED),           # a BOOL: 0 or 1
    (1030, 0.0, E.NC_AXIS_MOTION_MONITORING_WINDOW_NOT_ALLOWED),
    (1031, 0.0, E.NC_AXIS_MOTION_MONITORING_TIME_NOT_ALLOWED),
    (1031, -1.0, E.NC_AXIS_MOTION_MONITORING_TIME_NOT_ALLOWED),
    (1046, 2.0, E.NC_ENCODER_POS_CORRECTION_NOT_ALLOWED),
    (1047, -0.1, E.NC_ENCODER_POS_CORRECTION_FILTER_TIME_NOT_ALLOWED),
    (1047, 101.0, E.NC_ENCODER_POS_CORRECTION_FILTER_TIME_NOT_ALLOWED),
    (1036, -0.1, E.ADSERR_DEVICE_INVALIDPARM),          # a play is not negative (TwinCAT lists no code)
    (1032, True, E.ADSERR_DEVICE_INVALIDPARM),           # a BOOL for an LREAL: the type, not the value
])
def test_bad_values_get_twincat_codes_and_change_nothing(number: int, value: Any, code: int) -> None:
    core = powered()
    before = snapshot(core)
    assert write(core, number, value) == code
    assert snapshot(core) == before


@pytest.mark.parametrize("name, value, code", [
    ("AxisDelayTimeVeloPosition", 0.5, 0x430C), ("AxisMotionMonitoringTime", 0.0, 0x4324),
    ("AxisMotionMonitoringWindow", -1.0, 0x4330), ("AxisActPosCorrectionFilterTime", -1.0, 0x440F),
    ("AxisEnActPosCorrection", 1, 0x440E), ("AxisBacklash", -1.0, 0x70B),
])
def test_the_configuration_refuses_them_with_the_same_codes(name: str, value: Any, code: int) -> None:
    with pytest.raises(ConfigError) as ei:
        AxisParams.from_mapping({name: value})
    assert ei.value.code == code


def test_the_parameter_set_shows_them() -> None:
    core = powered(AxisEnBacklashCompensation=True, AxisBacklash=0.25, AxisEnActPosCorrection=True,
                   AxisActPosCorrectionFilterTime=0.03)
    ps = cmd(core, "ReadParameterSet")["Value"]
    assert ps["bEnableBacklashCompensation"] == 1 and ps["fBacklash"] == 0.25
    assert ps["bEncEnablePosCorrection"] == 1 and ps["fEncPosCorrectionFilterTime"] == 0.03


# ---- retained -------------------------------------------------------------------------------------------------
WRITTEN = {1032: 0.004, 1035: True, 1036: 0.3, 1046: True, 1047: 0.02, 1029: True, 1030: 0.2, 1031: 0.3}


def _nc(drive: bool = False) -> NcCore:
    axes = [AxisConfig(1, "A1", AxisParams())]
    if drive:  # (the keeper applies after the first step)
        return NcCore(axes, DT, drive=SimDrive([a.params for a in axes], DT))
    core = NcCore(axes, DT)
    core.step()
    return core


def test_written_values_are_retained(tmp_path: Path) -> None:
    core = _nc()
    k = RetainKeeper(tmp_path / "nc1.retain", "nc1", core)
    k.load()
    k.apply(core)
    for number, value in WRITTEN.items():
        assert write(core, number, value) == 0, number
    data = k.data_of(k._snapshot(core))
    k.close()
    kept = data.axes[1].params
    for number, value in WRITTEN.items():
        assert kept[param_name(number)][0] == value, number
    write_atomic(tmp_path / "nc1.retain", encode_retain(data))
    again = _nc(drive=True)
    k2 = RetainKeeper(tmp_path / "nc1.retain", "nc1", again)
    k2.load()
    again.step()
    k2.apply(again)
    again.step()
    for number, value in WRITTEN.items():
        assert again.read_parameter(0, number) == value, number
    assert int(again.nctoplc[0]["OpModeDWord"]) & int(OpModeDWord.OpModeBacklashCompensation | OpModeDWord.OpModePosCorrection)
    assert again.corrections.delay[0] == 4 and again.corrections.active
    k2.close()
