"""MC_MoveSuperImposed, MC_MoveSuperImposedExt, MC_AbortSuperposition against the wire contract alone:
a scripted NC answers the requests and writes the superposition slot of the job record
(NCJOBS.SuperCmdNo / SuperState / SuperErrorId / Super*) cycle by cycle."""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import ErrorCodes
from plc_client import E_SuperpositionMode, MC_AbortSuperposition, MC_MoveSuperImposed, MC_MoveSuperImposedExt
from znc_testing.plc_rig import ABORTED, ACTIVE, DONE, ERROR, MOVING, ScriptNc

SUPER = {"Distance": 5.0, "VelocityDiff": 2.0, "Acceleration": 10.0, "Deceleration": 20.0, "Jerk": 0.0,
         "VelocityProcess": 50.0}
ACTUALS = {"ActualDistance": 4.5, "ActualVelocityDiff": 1.5, "ActualLength": 90.0}


def drive(nc: ScriptNc, fb: Any, **inputs: Any) -> dict[str, Any]:
    st = {"Axis": nc.ax, **inputs}
    nc.calls.append(lambda: fb(**st))
    nc.watched.append(fb)
    return st


def super_slot(nc: ScriptNc, no: int, state: int, error: int = 0, **values: float) -> None:
    assert nc.jobs is not None
    j = nc.jobs[0]
    j["SuperCmdNo"], j["SuperState"], j["SuperErrorId"] = no, state, error
    for k, v in values.items():
        j[k] = v


def start(nc: ScriptNc, fb: Any, no: int, value: Any = None, **inputs: Any) -> dict[str, Any]:
    st = drive(nc, fb, Execute=True, **inputs)
    nc.cycle_once()
    assert fb.Busy
    nc.port.answer(nc.port.sent[-1], cycle=nc.nc_cycle, cmdno=no, value=value)
    return st


@pytest.fixture
def moving(nc: ScriptNc) -> ScriptNc:
    """The axis moves with its own job 5 (the basic motion the superposition is added to)."""
    nc.state(MOVING)
    nc.set_jobs(active=(5, ACTIVE))
    nc.cycle_once()
    return nc


def test_move_superimposed_request_and_done(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    st = start(nc, fb, 3, value=ACTUALS, MaxDistance=100.0, **SUPER)
    p = nc.last_sent("MoveSuperImposed")
    assert p.axis_id == 1
    sent = {k: v for k, v in SUPER.items() if k != "Jerk"}
    assert p.args == {"Mode": 4, "Length": 100.0, **sent}, "Mode 4 LENGTHREDUCTION_LIMITEDMOTION, Length=MaxDistance"
    assert p.args["Mode"] == E_SuperpositionMode.SUPERPOSITIONMODE_LENGTHREDUCTION_LIMITEDMOTION
    super_slot(nc, 3, ACTIVE)
    nc.cycle_once(3)
    assert fb.Busy and not fb.Done
    assert int(nc.jobs[0]["ActiveCmdNo"]) == 5, "the basic motion stays the axis's job"
    super_slot(nc, 3, DONE)
    nc.cycle_once()
    assert fb.Done and not fb.Busy and not fb.CommandAborted and not fb.Error
    nc.cycle_once()
    assert fb.Done, "held while Execute stays TRUE"
    st["Execute"] = False
    nc.cycle_once()
    assert not fb.Done and not fb.Busy


def test_superposition_not_shown_before_the_replys_cycle(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    drive(nc, fb, Execute=True, MaxDistance=10.0, **SUPER)
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], cycle=nc.nc_cycle + 15, cmdno=3)
    nc.cycle_once(2)  # SuperCmdNo still 0 in these frames: not yet evaluated
    assert fb.Busy and not fb.Error
    super_slot(nc, 3, ACTIVE)
    nc.cycle_once()
    assert fb.Busy and not fb.Error


def test_done_is_a_one_cycle_pulse_when_execute_fell_early(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    st = start(nc, fb, 3, MaxDistance=100.0, **SUPER)
    st["Execute"] = False
    super_slot(nc, 3, ACTIVE)
    nc.cycle_once(2)
    assert fb.Busy
    super_slot(nc, 3, DONE)
    nc.cycle_once(3)
    assert nc.history(fb, "Done").count(True) == 1
    assert not fb.Done and not fb.Busy


def test_rising_edge_while_busy_is_ignored(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    st = start(nc, fb, 3, MaxDistance=100.0, **SUPER)
    super_slot(nc, 3, ACTIVE)
    nc.cycle_once()
    st["Execute"] = False
    nc.cycle_once()
    st.update(Execute=True, Distance=-7.0)
    nc.cycle_once(2)
    assert len(nc.port.sent) == 1 and fb.Busy


def test_incomplete_compensation_is_error_4243(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposedExt()
    start(nc, fb, 3, value=ACTUALS, Mode=2, Length=90.0, **SUPER)
    super_slot(nc, 3, ACTIVE)
    nc.cycle_once()
    super_slot(nc, 3, ERROR, ErrorCodes.NC_COMPENSATION_INCOMPLETE)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == 0x4243 and not fb.Busy and not fb.Done
    assert fb.ActualDistance == 4.5, "the distance applied as far as possible"


def test_error_without_an_error_id_takes_the_axis_code(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    start(nc, fb, 3, MaxDistance=100.0, **SUPER)
    nc.state(MOVING, ErrorCode=0x4550)
    super_slot(nc, 3, ERROR, 0)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == 0x4550


@pytest.mark.parametrize("how", ["aborted", "newer", "newer-wrapped"])
def test_superposition_aborted(moving: ScriptNc, how: str) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    mine = 65535 if how == "newer-wrapped" else 3
    start(nc, fb, mine, MaxDistance=100.0, **SUPER)
    super_slot(nc, mine, ACTIVE)
    nc.cycle_once()
    if how == "aborted":
        super_slot(nc, mine, ABORTED)  # MC_AbortSuperposition, MC_Stop, ...
    else:
        super_slot(nc, 1 if how == "newer-wrapped" else 4, ACTIVE)  # another superposition took over
    nc.cycle_once()
    assert fb.CommandAborted and not fb.Busy and fb.ErrorID == 0


@pytest.mark.parametrize("slot", [0, 2])
def test_superposition_lost_is_error_4b60(moving: ScriptNc, slot: int) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    start(nc, fb, 3, MaxDistance=100.0, **SUPER)
    super_slot(nc, slot, DONE)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == ErrorCodes.MC_CMD_NOT_ACTIVE


def test_without_job_records_the_superposition_cannot_be_followed() -> None:
    nc = ScriptNc(jobs=False)
    nc.cycle_once()
    fb = MC_MoveSuperImposed()
    start(nc, fb, 3, MaxDistance=100.0, **SUPER)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == ErrorCodes.MC_CMD_NOT_ACTIVE


def test_refused_by_the_nc_and_cmdno_zero(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    drive(nc, fb, Execute=True, MaxDistance=0.0, **SUPER)
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.MC_PARAMETER_NOT_CORRECT, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == 0x4B06
    fb2 = MC_MoveSuperImposed()
    nc.calls.clear()
    start(nc, fb2, 0, MaxDistance=10.0, **SUPER)
    nc.cycle_once()
    assert fb2.Error and fb2.ErrorID == ErrorCodes.MC_CMD_NUMBER_ZERO


@pytest.mark.parametrize("bad", [{"Distance": math.nan}, {"VelocityDiff": "2"}, {"MaxDistance": math.inf},
                                 {"VelocityProcess": None}, {"Acceleration": True}])
def test_non_finite_input_refused_locally(moving: ScriptNc, bad: dict) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    drive(nc, fb, Execute=True, **{**SUPER, "MaxDistance": 10.0, **bad})
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == 0x4B06 and not nc.port.sent


@pytest.mark.parametrize("cls, extra", [(MC_MoveSuperImposed, {"MaxDistance": 10.0}),
                                        (MC_MoveSuperImposedExt, {"Mode": 2, "Length": 10.0})])
@pytest.mark.parametrize("jerk", [500.0, -1.0, math.nan, "x"])
def test_jerk_is_neither_checked_nor_sent(moving: ScriptNc, cls: Any, extra: dict, jerk: Any) -> None:
    """TcMC 3.9/3.10 "Jerk: the jerk value is not used" (before: sent, and a bad one refused locally)."""
    nc = moving
    fb = cls()
    drive(nc, fb, Execute=True, **{**SUPER, **extra, "Jerk": jerk})
    nc.cycle_once()
    assert fb.Busy and not fb.Error
    p = nc.last_sent("MoveSuperImposed")
    assert "Jerk" not in p.args and p.args["VelocityProcess"] == 50.0


@pytest.mark.parametrize("mode", [0, 5, True, 4.0, "4", None])
def test_ext_invalid_mode(moving: ScriptNc, mode: Any) -> None:
    nc = moving
    fb = MC_MoveSuperImposedExt()
    drive(nc, fb, Execute=True, Mode=mode, Length=10.0, **SUPER)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == ErrorCodes.MC_INVALID_MODE and not nc.port.sent


def test_ext_mode_length_and_actual_values(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposedExt()
    st = start(nc, fb, 3, value=ACTUALS, Mode=E_SuperpositionMode.SUPERPOSITIONMODE_VELOREDUCTION_ADDITIVEMOTION,
               Length=90.0, **SUPER)
    p = nc.last_sent("MoveSuperImposed")
    assert p.args["Mode"] == 1 and type(p.args["Mode"]) is int and p.args["Length"] == 90.0
    super_slot(nc, 3, ACTIVE)
    nc.cycle_once()
    assert (fb.ActualDistance, fb.ActualVelocityDiff, fb.ActualLength) == (4.5, 1.5, 90.0)
    super_slot(nc, 3, DONE)
    nc.cycle_once()
    assert fb.Done
    st["Execute"] = False
    nc.cycle_once()
    assert not fb.Done and fb.ActualDistance == 4.5, "values survive the falling edge"
    st["Execute"] = True
    nc.cycle_once()
    assert fb.Busy and fb.ActualDistance == 0.0, "cleared by the next start"


def test_ext_actual_values_from_the_job_record_without_a_reply_value(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposedExt()
    start(nc, fb, 3, value=None, Mode=3, Length=90.0, **SUPER)
    super_slot(nc, 3, ACTIVE, SuperDistance=5.0, SuperVelocityDiff=2.0, SuperLength=60.0)
    nc.cycle_once()
    assert (fb.ActualDistance, fb.ActualVelocityDiff, fb.ActualLength) == (5.0, 2.0, 60.0)


def test_stale_axis_while_busy(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    start(nc, fb, 3, MaxDistance=100.0, **SUPER)
    super_slot(nc, 3, ACTIVE)
    for _ in range(nc.stale_cycles + 1):
        nc.nc_cycle -= 10
        nc.cycle_once()
        if fb.Error:
            break
    assert fb.Error and fb.ErrorID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE


# ---- MC_AbortSuperposition -------------------------------------------------------------------------------
def test_abort_superposition_done_once_shown_and_the_running_one_aborted(moving: ScriptNc) -> None:
    nc = moving
    fb = MC_MoveSuperImposed()
    start(nc, fb, 3, MaxDistance=100.0, **SUPER)
    super_slot(nc, 3, ACTIVE)
    nc.cycle_once()
    ab = MC_AbortSuperposition()
    st = drive(nc, ab, Execute=True)
    nc.cycle_once()
    p = nc.last_sent("AbortSuperposition")
    assert p.args == {} and ab.Busy
    nc.port.answer(p, cycle=nc.nc_cycle + 5)
    nc.cycle_once()
    assert ab.Busy and not ab.Done
    super_slot(nc, 3, ABORTED)
    nc.cycle_once()
    assert ab.Done and not ab.Busy and fb.CommandAborted
    st["Execute"] = False
    nc.cycle_once()
    assert not ab.Done


def test_abort_superposition_error(nc: ScriptNc) -> None:
    ab = MC_AbortSuperposition()
    drive(nc, ab, Execute=True)
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.NC_FUNCTION_NOT_ALLOWED, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert ab.Error and ab.ErrorID == ErrorCodes.NC_FUNCTION_NOT_ALLOWED and not ab.Done
