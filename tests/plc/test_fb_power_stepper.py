"""MC_PowerStepper (TcMC 4.23 / 4.23.1) against a real NcCore whose axes are simulated steppers (SimStepper):
stall detection (Encoderless: the terminal's load angle; Lagging: the following error) with every destall
mode, the terminal's status monitoring, and the combinations the manual calls not suitable."""
from __future__ import annotations

import itertools
import logging

import pytest

from nc_schema import ErrorCodes as E, StateDWord, make_request, parse_request
from nc_server.core import AxisParams
from plc_client import (
    E_DestallDetectMode as D, E_DestallMode as M, MC_MoveAbsolute, MC_MoveVelocity, MC_PowerStepper, MC_Reset,
    ST_PowerStepperStruct,
)
from plc_client.fb.stepper import terminal_status
from znc_testing.plc_rig import Rig

_ids = itertools.count(1)


def nc_cmd(rig: Rig, name: str, axis: int = 1, **args) -> dict:
    return rig.core.execute(parse_request(make_request(name, next(_ids), "test", **args)), axis)


def stepper_rig(**kw) -> Rig:
    p = dict(SimStepper=True, AxisEnPositionLagMonitoring=False, SimTimeConstant=0.01, AxisMaxPosLagValue=1.0,
             AxisMaxPosLagFilterTime=0.05, Homed=True)
    p.update(kw)
    return Rig(params=AxisParams(**p))


def setup(rig: Rig, params: ST_PowerStepperStruct, **inputs):
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    ps = MC_PowerStepper()
    calls: dict = {"body": lambda p: None, "in": dict(inputs)}

    def program(p) -> None:
        ps(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True, DestallParams=params, **calls["in"])
        calls["body"](p)

    plc.program = program
    rig.run_until(lambda: ps.Status, 20)
    return ax, ps, calls


def moving(rig: Rig, ax, calls, velocity: float = 20.0):
    mv = MC_MoveVelocity()
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=velocity, Direction=1)
    rig.run_until(lambda: mv.InVelocity, 100)
    return mv


@pytest.mark.parametrize("mode, homed_after", [(M.PwStMode_SetError, True), (M.PwStMode_SetErrNonRef, False)])
@pytest.mark.parametrize("detect", [D.PwStDetectMode_Encoderless, D.PwStDetectMode_Lagging])
def test_stall_sets_the_error(detect, mode, homed_after, caplog) -> None:
    rig = stepper_rig()
    ax, ps, calls = setup(rig, ST_PowerStepperStruct(detect, mode, True, False))
    assert terminal_status(ax) == (0x11, 0)  # Ready and Idle: the simulated terminal is seen
    moving(rig, ax, calls)
    assert not ps.Error and ax.Status.Homed
    caplog.set_level(logging.WARNING, logger="plc_client.fb")
    assert nc_cmd(rig, "SimStall", Stall=True)["error"] == 0
    rig.run_until(lambda: ps.Error, 100)
    assert ps.ErrorID == E.NC_DRIVE_STALL == 0x4636
    rig.run_until(lambda: int(ax.NcToPlc["ErrorCode"]) == 0x4636, 20)
    assert ax.Status.Homed is homed_after
    assert "MC_PowerStepper(AxId:=1) reporting error 0x4636 (stall error)!" in caplog.text
    assert ps.Status is False, "an axis in error: MC_Power's Status falls"
    # MC_Reset clears it; the motor stands (the fault ramp took the set velocity to 0): no new report
    rs = MC_Reset()
    calls["body"] = lambda p: rs(Axis=ax, Execute=True)
    rig.run_until(lambda: rs.Done, 50)
    rig.run(10)
    assert not ps.Error and ps.Status and not int(ax.NcToPlc["ErrorCode"])
    assert caplog.text.count("reporting error") == 1


def test_lagging_waits_for_the_filter_time() -> None:
    rig = stepper_rig(AxisMaxPosLagFilterTime=0.2)
    ax, ps, calls = setup(rig, ST_PowerStepperStruct(D.PwStDetectMode_Lagging, M.PwStMode_SetError, True, False))
    moving(rig, ax, calls)
    nc_cmd(rig, "SimStall", Stall=True)
    rig.run_until(lambda: abs(float(ax.NcToPlc["PosDiff"])) > 1.0, 100)
    assert not ps.Error
    k = rig.run_until(lambda: ps.Error, 100)
    assert k >= 19, f"reported after {k} cycles of 10 ms above the limit (filter time 0.2 s)"


def test_use_override_halts_and_finishes_the_profile() -> None:
    rig = stepper_rig()
    ax, ps, calls = setup(rig, ST_PowerStepperStruct(D.PwStDetectMode_Lagging, M.PwStMode_UseOverride, True, False))
    mv = MC_MoveAbsolute()
    rig.watch(mv)
    ov = []
    calls["body"] = lambda p: (mv(Axis=ax, Execute=True, Position=40.0, Velocity=20.0),
                               ov.append(int(ax.PlcToNc["Override"])))
    rig.run_until(lambda: float(ax.NcToPlc["ActPos"]) > 10.0, 200)
    nc_cmd(rig, "SimStall", Stall=True)
    rig.run_until(lambda: ps.stalled, 100)
    assert int(ax.PlcToNc["Override"]) == 0 and not ps.Error
    rig.run_until(lambda: abs(float(ax.NcToPlc["SetVelo"])) == 0.0, 200)  # the profile halts, not aborted
    assert mv.Busy and mv.Active and not mv.Error and not mv.CommandAborted
    rig.run_until(lambda: int(ax.PlcToNc["Override"]) == 1_000_000, 200)  # caught up: the override returns
    rig.run_until(lambda: mv.Done, 500)
    assert abs(float(ax.NcToPlc["ActPos"]) - 40.0) < 0.02 and not int(ax.NcToPlc["ErrorCode"])
    assert not ps.Error and 0 in ov and not any(o.get("Error") for o in rig.outputs(mv))


def test_none_mode_does_nothing() -> None:
    rig = stepper_rig()
    ax, ps, calls = setup(rig, ST_PowerStepperStruct(D.PwStDetectMode_Encoderless, M.PwStMode_None, True, False))
    moving(rig, ax, calls)
    nc_cmd(rig, "SimStall", Stall=True)
    rig.run(30)
    assert ps.stalled and not ps.Error and not int(ax.NcToPlc["ErrorCode"])
    assert int(ax.PlcToNc["Override"]) == 1_000_000


@pytest.mark.parametrize("params", [
    ST_PowerStepperStruct(D.PwStDetectMode_Encoderless, M.PwStMode_SetError, False, False),  # DestallEnable off
    ST_PowerStepperStruct(D.PwStDetectMode_None, M.PwStMode_SetError, True, False),          # no detection
])
def test_detection_off(params) -> None:
    rig = stepper_rig()
    ax, ps, calls = setup(rig, params)
    moving(rig, ax, calls)
    nc_cmd(rig, "SimStall", Stall=True)
    rig.run(30)
    assert not ps.stalled and not ps.Error and not int(ax.NcToPlc["ErrorCode"])


@pytest.mark.parametrize("params", [
    ST_PowerStepperStruct(D.PwStDetectMode_Encoderless, M.PwStMode_UseOverride, True, False),  # "not suitable"
    ST_PowerStepperStruct(7, M.PwStMode_SetError, True, False),
    ST_PowerStepperStruct(D.PwStDetectMode_Lagging, 9, True, False),
    {"DestallDetectMode": 1, "Nonsense": 2},
])
def test_invalid_parameters(params) -> None:
    rig = stepper_rig()
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    ps = MC_PowerStepper()
    plc.program = lambda p: ps(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True, DestallParams=params)
    rig.run(5)
    assert ps.Status and ps.Error and ps.ErrorID == E.MC_INVALID_MODE, "the enables still work"


@pytest.mark.parametrize("word, code", [(1 << 3, 0x4630), (1 << 4, 0x4631), (1 << 5, 0x4632), (1 << 6, 0x4633),
                                        (1 << 7, 0x4634), (1 << 8, 0x4635), ((1 << 7) | (1 << 4), 0x4631)])
def test_status_monitoring_reports_terminal_errors(word, code) -> None:
    rig = stepper_rig()
    ax, ps, calls = setup(rig, ST_PowerStepperStruct(D.PwStDetectMode_None, M.PwStMode_None, False, True))
    assert nc_cmd(rig, "SimTerminalError", StatusWord=word)["error"] == 0
    rig.run_until(lambda: ps.Error, 20)
    assert ps.ErrorID == code
    rig.run_until(lambda: int(ax.NcToPlc["ErrorCode"]) == code, 20)
    assert terminal_status(ax)[1] == word and terminal_status(ax)[0] & 0x40  # the status byte's Error bit
    # the condition persists: after a reset it is reported again
    rs = MC_Reset()
    calls["body"] = lambda p: rs(Axis=ax, Execute=True)
    rig.run_until(lambda: rs.Done or rs.Error, 50)
    rig.run_until(lambda: int(ax.NcToPlc["ErrorCode"]) == code and ps.Error, 50)
    nc_cmd(rig, "SimTerminalError", StatusWord=0)
    calls["body"] = lambda p: rs(Axis=ax, Execute=False)
    rig.run(2)
    calls["body"] = lambda p: rs(Axis=ax, Execute=True)
    rig.run_until(lambda: rs.Done, 50)
    rig.run(5)
    assert not ps.Error and not int(ax.NcToPlc["ErrorCode"])


@pytest.mark.parametrize("params", [
    ST_PowerStepperStruct(7, M.PwStMode_SetError, True, True),
    ST_PowerStepperStruct(D.PwStDetectMode_Lagging, 9, False, True),
    ST_PowerStepperStruct(D.PwStDetectMode_Encoderless, M.PwStMode_UseOverride, True, True),
])
def test_status_monitoring_with_refused_stall_settings(params) -> None:
    """TcMC 6.6: StatusMonEnable "specifies whether the status bits of the I/O terminal are monitored and
    whether errors that occur are to be reported" - a stall setting the block refuses does not switch that off."""
    rig = stepper_rig()
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    ps = MC_PowerStepper()
    plc.program = lambda p: ps(Axis=ax, Enable=True, Enable_Positive=True, Enable_Negative=True, DestallParams=params)
    rig.run(5)
    assert ps.Error and ps.ErrorID == E.MC_INVALID_MODE
    assert nc_cmd(rig, "SimTerminalError", StatusWord=1 << 3)["error"] == 0
    rig.run_until(lambda: int(ax.NcToPlc["ErrorCode"]) == 0x4630, 20)
    assert ps.Error and ps.ErrorID == 0x4630


def test_status_monitoring_off_and_explicit_inputs() -> None:
    rig = stepper_rig()
    prm = ST_PowerStepperStruct(D.PwStDetectMode_None, M.PwStMode_None, False, False)
    ax, ps, calls = setup(rig, prm)
    nc_cmd(rig, "SimTerminalError", StatusWord=1 << 3)
    rig.run(10)
    assert not ps.Error and not int(ax.NcToPlc["ErrorCode"])
    # a real terminal's inputs wired in: they win over the simulated terminal
    calls["in"] = {"KL_Status": 0x01, "KL_Status2": 1 << 8}
    prm.StatusMonEnable = True
    rig.run_until(lambda: ps.Error, 20)
    assert ps.ErrorID == 0x4635


def test_encoderless_on_a_servo_axis_with_wired_status_byte() -> None:
    rig = Rig(params=AxisParams(AxisEnPositionLagMonitoring=False))
    ax, ps, calls = setup(rig, ST_PowerStepperStruct(D.PwStDetectMode_Encoderless, M.PwStMode_SetError, True, False),
                          KL_Status=0x01)
    assert terminal_status(ax) is None
    rig.run(5)
    assert not ps.Error
    calls["in"] = {"KL_Status": 0x01 | (7 << 1)}  # LoadAngle 7
    rig.run_until(lambda: ps.Error, 20)
    assert ps.ErrorID == 0x4636


def test_sim_stall_refused_on_a_servo_axis() -> None:
    rig = Rig()
    assert nc_cmd(rig, "SimStall", Stall=True)["error"] == E.NC_FUNCTION_NOT_SUPPORTED
    assert nc_cmd(rig, "SimTerminalError", StatusWord=8)["error"] == E.NC_FUNCTION_NOT_SUPPORTED


def test_power_off() -> None:
    rig = stepper_rig()
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    ps = MC_PowerStepper()
    st = {"en": True}
    plc.program = lambda p: ps(Axis=ax, Enable=st["en"], Enable_Positive=True, Enable_Negative=True)
    rig.run_until(lambda: ps.Status, 20)
    assert int(ax.NcToPlc["StateDWord"]) & int(StateDWord.ControlLoopClosed)
    st["en"] = False
    rig.run(3)
    assert not ps.Status and not ps.Error and not int(ax.PlcToNc["ControlDWord"]) & 1


def test_the_axis_error_shows_with_enable_true_and_false() -> None:
    """MC_PowerStepper is MC_Power for a stepper axis (TcMC 4.23: "An MC_Power block is used internally"): an
    axis error it did not report itself (another client's SetExternalError) shows on Error/ErrorID with Enable
    TRUE and FALSE, Status FALSE; after MC_Reset Error falls with Enable FALSE, and Status comes back with
    Enable TRUE."""
    rig = stepper_rig()
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    ps, rs = MC_PowerStepper(), MC_Reset()
    st = {"en": True, "rst": False}

    def program(p) -> None:
        ps(Axis=ax, Enable=st["en"], Enable_Positive=True, Enable_Negative=True)
        rs(Axis=ax, Execute=st["rst"])

    plc.program = program
    rig.run_until(lambda: ps.Status, 20)
    assert not ps.Error
    assert nc_cmd(rig, "SetExternalError", ErrorCode=0x4260)["error"] == 0
    rig.run_until(lambda: ax.Status.Error, 20)
    rig.run(1)
    assert (ps.Error, ps.ErrorID, ps.Status) == (True, 0x4260, False), "Enable TRUE: MC_Power's axis error"
    st["en"] = False
    rig.run(3)
    assert not int(ax.PlcToNc["ControlDWord"]) & 1
    assert (ps.Error, ps.ErrorID, ps.Status) == (True, 0x4260, False), "Enable FALSE: the axis error still shows"
    st["rst"] = True
    rig.run_until(lambda: rs.Done, 50)
    rig.run(1)
    assert (ps.Error, ps.ErrorID, ps.Status) == (False, 0, False)
    st["en"] = True
    rig.run_until(lambda: ps.Status, 20)
    assert not ps.Error
