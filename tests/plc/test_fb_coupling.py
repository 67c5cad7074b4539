"""MC_GearIn, MC_GearInFloat, MC_GearInDyn, MC_GearOut, MC_GearOutExt against the wire contract alone:
a scripted NC (axis 1 = the slave, axis 2 = the master) answers the requests and writes the frames
(NCTOPLC + NCJOBS records) cycle by cycle."""
from __future__ import annotations

import logging
import math
from typing import Any

import pytest

from nc_schema import AxisState, CoupleState, ErrorCodes, OpModeDWord
from plc_client import (
    AXIS_REF, E_DecoupleMode, MC_GearIn, MC_GearInDyn, MC_GearInFloat, MC_GearOut, MC_GearOutExt,
)
from znc_testing.plc_rig import ABORTED, ACTIVE, DONE, ERROR, IDLE, MOVING, S, ScriptNc

SYNCHRONIZING, SYNCHRON = int(AxisState.SLAVE_SYNCHRONIZING), int(AxisState.SLAVE_SYNCHRON)
SLAVE = int(CoupleState.SLAVE)
COUPLED = int(S.Operational | S.ControlLoopClosed | S.HasJob | S.PositiveDirection)


@pytest.fixture
def gnc() -> ScriptNc:
    """A scripted NC with a slave (axis 1, ``gnc.ax``) and a master (axis 2, ``gnc.master``)."""
    t = ScriptNc(n_axes=2)
    t.master = t.axis("nc1", 2)  # type: ignore[attr-defined]
    t.cycle_once()
    return t


def drive(nc: ScriptNc, fb: Any, **inputs: Any) -> dict[str, Any]:
    """Call fb with these inputs every cycle (the test changes the dict); its outputs are checked."""
    st = dict(inputs)
    nc.calls.append(lambda: fb(**st))
    nc.watched.append(fb)
    return st


def couple(nc: ScriptNc, cmdno: int, axis_state: int = SYNCHRON) -> None:
    """The frame shows job ``cmdno`` as the slave's active coupling."""
    nc.state(COUPLED, AxisState=axis_state, CoupleState=SLAVE)
    nc.set_jobs(active=(cmdno, ACTIVE))
    assert nc.jobs is not None
    nc.jobs[0]["MasterId"], nc.jobs[0]["GearRatio"] = 2, 0.5


def decouple(nc: ScriptNc, cmdno: int, fate: int, next_cmdno: int = 0, error: int = 0) -> None:
    """Job ``cmdno`` ended with ``fate``; ``next_cmdno`` (e.g. GearOut's velocity job) runs after it."""
    nc.state(MOVING if next_cmdno else IDLE, AxisState=1 if next_cmdno else 0, CoupleState=0)
    nc.set_jobs(active=(next_cmdno, ACTIVE) if next_cmdno else (cmdno, fate), ended=((cmdno, fate, error),))
    assert nc.jobs is not None
    nc.jobs[0]["MasterId"], nc.jobs[0]["GearRatio"] = 0, 0.0


def start_gear(nc: ScriptNc, fb: Any, cmdno: int, **inputs: Any) -> dict[str, Any]:
    st = drive(nc, fb, Master=nc.master, Slave=nc.ax, Execute=True, **inputs)  # type: ignore[attr-defined]
    nc.cycle_once()
    assert fb.Busy and not fb.InGear
    nc.port.answer(nc.port.sent[-1], cycle=nc.nc_cycle, cmdno=cmdno)
    return st


# ---- MC_GearIn -----------------------------------------------------------------------------------------
def test_gear_in_request_and_in_gear_after_synchronizing(gnc: ScriptNc) -> None:
    gi = MC_GearIn()
    st = start_gear(gnc, gi, 7, RatioNumerator=-1, RatioDenominator=2, Acceleration=5.0)
    p = gnc.last_sent("GearIn")
    assert p.axis_id == 1 and p.nc == "nc1", "the request goes to the slave's key"
    assert p.args == {"Master": 2, "RatioNumerator": -1, "RatioDenominator": 2, "Acceleration": 5.0,
                      "Deceleration": 0.0, "Jerk": 0.0}
    assert all(type(v) is int for k, v in p.args.items() if k.startswith(("Master", "Ratio")))
    couple(gnc, 7, SYNCHRONIZING)
    gnc.cycle_once(3)
    assert gi.Busy and not gi.InGear, "synchronizing: not in gear yet"
    couple(gnc, 7, SYNCHRON)
    gnc.cycle_once()
    assert gi.InGear and gi.Busy and not gi.Error and not gi.CommandAborted
    # Execute falling does not end the coupling's block: it stays responsible (Busy, InGear)
    st["Execute"] = False
    gnc.cycle_once(3)
    assert gi.InGear and gi.Busy
    # MC_GearOut ends the coupling normally: InGear is the result (Execute fell: for one cycle)
    decouple(gnc, 7, DONE, next_cmdno=8)
    gnc.cycle_once()
    assert gi.InGear and not any((gi.Busy, gi.CommandAborted, gi.Error)) and gi.ErrorID == 0
    gnc.cycle_once()
    assert not any((gi.InGear, gi.Busy, gi.CommandAborted, gi.Error))
    assert len([p for p in gnc.port.sent if p.cmd == "GearIn"]) == 1


def test_gear_out_with_execute_still_true_keeps_in_gear_as_the_result(gnc: ScriptNc) -> None:
    """The coupling was successful: InGear stays TRUE (Busy FALSE) while Execute stays TRUE, like a
    Done - while Execute is TRUE one output is TRUE (PLCopen output rules)."""
    gi = MC_GearIn()
    start_gear(gnc, gi, 7)
    couple(gnc, 7)
    gnc.cycle_once()
    assert gi.InGear
    decouple(gnc, 7, DONE)  # at standstill: the coupling job itself is the last one, DONE
    gnc.cycle_once()
    assert gi.InGear and not gi.Busy and not gi.CommandAborted and not gi.Error
    gnc.cycle_once(2)
    assert gi.InGear
    assert len(gnc.port.sent) == 1, "no new command while Execute stays TRUE"


@pytest.mark.parametrize("execute_fell", [False, True])
def test_gear_in_aborted_by_another_command(gnc: ScriptNc, execute_fell: bool) -> None:
    gi = MC_GearIn()
    st = start_gear(gnc, gi, 7)
    couple(gnc, 7)
    gnc.cycle_once()
    assert gi.InGear
    if execute_fell:
        st["Execute"] = False
        gnc.cycle_once()
    decouple(gnc, 7, ABORTED, next_cmdno=8)  # e.g. MC_Stop on the slave
    gnc.cycle_once()
    assert gi.CommandAborted and not gi.InGear and not gi.Busy and gi.ErrorID == 0
    gnc.cycle_once()
    if execute_fell:
        assert not gi.CommandAborted, "TRUE for exactly one cycle when Execute fell before"
        assert gnc.history(gi, "CommandAborted").count(True) == 1
    else:
        assert gi.CommandAborted, "held while Execute stays TRUE"
        st["Execute"] = False
        gnc.cycle_once()
        assert not gi.CommandAborted


def test_gear_in_aborted_before_in_gear(gnc: ScriptNc) -> None:
    gi = MC_GearIn()
    start_gear(gnc, gi, 7)
    couple(gnc, 7, SYNCHRONIZING)
    gnc.cycle_once()
    gnc.set_jobs(active=(7, ABORTED), ended=((7, ABORTED, 0),))
    gnc.cycle_once()
    assert gi.CommandAborted and not gi.InGear


def test_gear_in_job_error_and_axis_error(gnc: ScriptNc) -> None:
    gi = MC_GearIn()
    start_gear(gnc, gi, 7)
    couple(gnc, 7)
    gnc.cycle_once()
    decouple(gnc, 7, ERROR, error=ErrorCodes.NC_POSITION_LAG)
    gnc.cycle_once()
    assert gi.Error and gi.ErrorID == ErrorCodes.NC_POSITION_LAG and not gi.InGear and not gi.Busy

    gi2 = MC_GearIn()
    gnc.calls.clear()
    start_gear(gnc, gi2, 9)
    couple(gnc, 9)
    gnc.cycle_once()
    assert gi2.InGear
    gnc.state(COUPLED | int(S.Error), AxisState=SYNCHRON, CoupleState=SLAVE, ErrorCode=0x4550)
    gnc.cycle_once()
    assert gi2.Error and gi2.ErrorID == 0x4550 and not gi2.InGear


def test_gear_in_refused_by_the_nc(gnc: ScriptNc) -> None:
    gi = MC_GearIn()
    drive(gnc, gi, Master=gnc.master, Slave=gnc.ax, Execute=True)  # type: ignore[attr-defined]
    gnc.cycle_once()
    gnc.port.answer(gnc.port.sent[-1], error=ErrorCodes.MC_AXIS_PROTECTED, cycle=gnc.nc_cycle)
    gnc.cycle_once()
    assert gi.Error and gi.ErrorID == 0x4B08 and not gi.Busy


def test_gear_in_reply_timeout(gnc: ScriptNc) -> None:
    gi = MC_GearIn(timeout=0.05)
    drive(gnc, gi, Master=gnc.master, Slave=gnc.ax, Execute=True)  # type: ignore[attr-defined]
    gnc.cycle_once(7)
    assert gi.Error and gi.ErrorID == ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT
    assert gnc.port.sent[-1].abandoned


@pytest.mark.parametrize("num, den", [
    (1, 0), (40000, 1), (-40000, 1), (1, 70000), (1, -1), (1.5, 2), (2.0, 1), (True, 1), (1, True),
    ("1", 2), (None, 2), (1, float("nan")),
])
def test_gear_in_invalid_ratio_is_refused_locally(gnc: ScriptNc, num: Any, den: Any) -> None:
    gi = MC_GearIn()
    drive(gnc, gi, Master=gnc.master, Slave=gnc.ax, Execute=True,  # type: ignore[attr-defined]
          RatioNumerator=num, RatioDenominator=den)
    gnc.cycle_once(2)
    assert gi.Error and gi.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT == 0x4B06
    assert not gnc.port.sent, "nothing may be sent"


@pytest.mark.parametrize("ratio", [float("nan"), float("inf"), "1", True, None])
def test_gear_in_float_invalid_ratio(gnc: ScriptNc, ratio: Any) -> None:
    gi = MC_GearInFloat()
    drive(gnc, gi, Master=gnc.master, Slave=gnc.ax, Execute=True, GearRatio=ratio)  # type: ignore[attr-defined]
    gnc.cycle_once()
    assert gi.Error and gi.ErrorID == 0x4B06 and not gnc.port.sent


def test_gear_in_nan_dynamics_refused(gnc: ScriptNc) -> None:
    gi = MC_GearIn()
    drive(gnc, gi, Master=gnc.master, Slave=gnc.ax, Execute=True, Jerk=float("nan"))  # type: ignore[attr-defined]
    gnc.cycle_once()
    assert gi.Error and gi.ErrorID == 0x4B06 and not gnc.port.sent


def test_gear_in_float_main_path(gnc: ScriptNc) -> None:
    gi = MC_GearInFloat()
    start_gear(gnc, gi, 11, GearRatio=0.25)
    assert gnc.last_sent("GearInFloat").args["GearRatio"] == 0.25
    couple(gnc, 11)
    gnc.cycle_once()
    assert gi.InGear and gi.Busy
    decouple(gnc, 11, ABORTED, next_cmdno=12)
    gnc.cycle_once()
    assert gi.CommandAborted and not gi.InGear


@pytest.mark.parametrize("which, code", [
    ("no master", ErrorCodes.MC_NO_NC_CYCLE_UPDATE),
    ("master on another NC without frames", ErrorCodes.MC_NO_NC_CYCLE_UPDATE),  # (with frames: MasterNc is sent)
    ("master not in the frames", ErrorCodes.NC_AXIS_ID_NOT_ALLOWED),
    ("no slave", ErrorCodes.MC_NO_NC_CYCLE_UPDATE),
    ("slave on an NC without frames", ErrorCodes.MC_NO_NC_CYCLE_UPDATE),
])
def test_gear_in_axis_problems(gnc: ScriptNc, which: str, code: int) -> None:
    gi = MC_GearIn()
    master: Any = gnc.master  # type: ignore[attr-defined]
    slave: Any = gnc.ax
    if which == "no master":
        master = None
    elif which == "master on another NC without frames":
        master = AXIS_REF(nc="nc2", axis_id=2)
    elif which == "master not in the frames":
        master = AXIS_REF(nc="nc1", axis_id=3)
    elif which == "no slave":
        slave = None
    else:
        slave = AXIS_REF(nc="nc9", axis_id=1)
    drive(gnc, gi, Master=master, Slave=slave, Execute=True)
    gnc.cycle_once(2)
    assert gi.Error and gi.ErrorID == code and not gnc.port.sent


def test_gear_in_stale_slave_while_coupled(gnc: ScriptNc) -> None:
    gi = MC_GearIn()
    start_gear(gnc, gi, 7)
    couple(gnc, 7)
    gnc.cycle_once()
    assert gi.InGear
    for _ in range(gnc.stale_cycles + 1):  # the NC's cycle stops advancing
        gnc.nc_cycle -= 10
        gnc.cycle_once()
        if gi.Error:
            break
    assert gi.Error and gi.ErrorID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE and not gi.InGear


def test_gear_in_rising_edge_while_busy_ignored(gnc: ScriptNc) -> None:
    gi = MC_GearIn()
    st = start_gear(gnc, gi, 7)
    couple(gnc, 7)
    gnc.cycle_once()
    st["Execute"] = False
    gnc.cycle_once()
    st.update(Execute=True, RatioNumerator=3)
    gnc.cycle_once(2)
    assert len(gnc.port.sent) == 1 and gi.InGear and gi.Busy


def test_gear_in_without_job_records() -> None:
    nc = ScriptNc(jobs=False, n_axes=2)
    nc.master = nc.axis("nc1", 2)  # type: ignore[attr-defined]
    nc.cycle_once()
    gi = MC_GearIn()
    start_gear(nc, gi, 7)
    nc.state(COUPLED, AxisState=SYNCHRON, CoupleState=SLAVE, CmdNo=7, CmdState=ACTIVE)
    nc.cycle_once()
    assert gi.InGear and gi.Busy
    nc.state(MOVING, AxisState=1, CoupleState=0, CmdNo=8, CmdState=ACTIVE)
    nc.cycle_once()
    assert gi.CommandAborted, "without job records a newer command cannot be told apart: CommandAborted"


def test_axis_keyword_and_wrong_types_are_program_errors(gnc: ScriptNc) -> None:
    with pytest.raises(TypeError, match="Slave"):
        MC_GearIn()(Axis=gnc.ax, Execute=False)
    with pytest.raises(TypeError, match="Master"):
        MC_GearIn()(Master="axis 2", Slave=gnc.ax)
    with pytest.raises(TypeError, match="Slave"):
        MC_GearOut()(Axis=gnc.ax)
    with pytest.raises(TypeError, match="Slave"):
        MC_GearOutExt()(Slave=1)
    gi = MC_GearIn()
    gi(Master=gnc.master, Slave=gnc.ax)  # type: ignore[attr-defined]
    assert gi.Master is gnc.master and gi.Slave is gnc.ax  # type: ignore[attr-defined]


# ---- MC_GearInDyn --------------------------------------------------------------------------------------
def test_gear_in_dyn_ratio_written_every_cycle_once_accepted(gnc: ScriptNc) -> None:
    gd = MC_GearInDyn()
    at_send: list[float] = []
    orig = gnc.port._transmit

    def spy(pending: Any, payload: bytes) -> None:
        at_send.append(float(gnc.ax.PlcToNc["GearRatio1"]))
        orig(pending, payload)

    gnc.port._transmit = spy  # type: ignore[method-assign]
    st = start_gear(gnc, gd, 7, GearRatio=0.5, Acceleration=100.0)
    assert at_send == [0.0], "a request not accepted yet changes nothing (the NC starts with its GearRatio)"
    p = gnc.last_sent("GearInDyn")
    assert p.args == {"Master": 2, "GearRatio": 0.5, "Acceleration": 100.0, "Deceleration": 0.0, "Jerk": 0.0}
    couple(gnc, 7)
    gnc.cycle_once()
    assert gnc.ax.PlcToNc["GearRatio1"] == 0.5
    for r in (0.6, 0.7, -1.25, 2.0):
        st["GearRatio"] = r
        gnc.cycle_once()
        assert gnc.ax.PlcToNc["GearRatio1"] == r
    assert gd.InGear and gd.Busy
    st["GearRatio"] = float("nan")  # not written: the last ratio stays
    gnc.cycle_once()
    assert gnc.ax.PlcToNc["GearRatio1"] == 2.0 and gd.InGear
    st["GearRatio"] = 3.0
    gnc.cycle_once()
    assert gnc.ax.PlcToNc["GearRatio1"] == 3.0
    # the falling edge ends the block; the coupling stays at the last ratio
    st.update(Execute=False, GearRatio=9.0)
    gnc.cycle_once()
    assert not any((gd.InGear, gd.Busy, gd.CommandAborted, gd.Error))
    assert gnc.ax.PlcToNc["GearRatio1"] == 3.0, "not written after the falling edge"
    assert [p.cmd for p in gnc.port.sent] == ["GearInDyn"], "no decoupling from the block"
    decouple(gnc, 7, ABORTED, next_cmdno=8)
    gnc.cycle_once()
    assert not gd.CommandAborted, "a decoupling after the falling edge is not the block's"


@pytest.mark.parametrize("fate", [DONE, ABORTED])
def test_gear_in_dyn_decoupled_while_execute_true_is_aborted(gnc: ScriptNc, fate: int) -> None:
    gd = MC_GearInDyn()
    st = start_gear(gnc, gd, 7, GearRatio=1.0)
    couple(gnc, 7)
    gnc.cycle_once()
    assert gd.InGear
    decouple(gnc, 7, fate, next_cmdno=8)
    gnc.cycle_once()
    assert gd.CommandAborted and not gd.InGear and not gd.Busy
    st["GearRatio"] = 4.0
    gnc.cycle_once()
    assert gnc.ax.PlcToNc["GearRatio1"] == 1.0, "no more writes once the coupling ended"
    assert gd.CommandAborted


def test_gear_in_dyn_execute_fell_before_the_reply(gnc: ScriptNc) -> None:
    gd = MC_GearInDyn()
    st = drive(gnc, gd, Master=gnc.master, Slave=gnc.ax, Execute=True, GearRatio=1.0)  # type: ignore[attr-defined]
    gnc.cycle_once()
    st["Execute"] = False
    gnc.cycle_once()
    assert gd.Busy, "waits for the reply"
    gnc.port.answer(gnc.port.sent[-1], error=ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, cycle=gnc.nc_cycle)
    gnc.cycle_once()
    assert gd.Error and gd.ErrorID == 0x4B01
    gnc.cycle_once()
    assert not gd.Error and gnc.history(gd, "Error").count(True) == 1


def test_gear_in_dyn_invalid_start_ratio(gnc: ScriptNc) -> None:
    gd = MC_GearInDyn()
    drive(gnc, gd, Master=gnc.master, Slave=gnc.ax, Execute=True, GearRatio=float("inf"))  # type: ignore[attr-defined]
    gnc.cycle_once(2)
    assert gd.Error and gd.ErrorID == 0x4B06 and not gnc.port.sent
    assert gnc.ax.PlcToNc["GearRatio1"] == 0.0


def test_gear_in_dyn_warns_when_the_slave_is_not_controlled(gnc: ScriptNc, caplog: Any) -> None:
    gd = MC_GearInDyn()
    with caplog.at_level(logging.WARNING, logger="plc_client.fb.coupling"):
        start_gear(gnc, gd, 7, GearRatio=1.0)
    assert "GearRatio1" in caplog.text


# ---- MC_GearOut ----------------------------------------------------------------------------------------
def test_gear_out_done_once_shown(gnc: ScriptNc) -> None:
    go = MC_GearOut()
    st = drive(gnc, go, Slave=gnc.ax, Execute=True)
    gnc.cycle_once()
    p = gnc.last_sent("GearOut")
    assert p.axis_id == 1 and p.args == {}
    gnc.port.answer(p, cycle=gnc.nc_cycle + 15, cmdno=8)
    gnc.cycle_once(2)
    assert go.Busy and not go.Done, "the reply's cycle is not in the frame yet"
    gnc.cycle_once()
    assert go.Done and not go.Busy
    st["Execute"] = False
    gnc.cycle_once()
    assert not go.Done


def test_gear_out_not_coupled(gnc: ScriptNc) -> None:
    go = MC_GearOut()
    drive(gnc, go, Slave=gnc.ax, Execute=True)
    gnc.cycle_once()
    gnc.port.answer(gnc.port.sent[-1], error=ErrorCodes.MC_COMMAND_NOT_PERMITTED, cycle=gnc.nc_cycle)
    gnc.cycle_once()
    assert go.Error and go.ErrorID == 0x4B05 and not go.Done


# ---- MC_GearOutExt -------------------------------------------------------------------------------------
def start_out_ext(nc: ScriptNc, fb: MC_GearOutExt, cmdno: int | None, **inputs: Any) -> dict[str, Any]:
    st = drive(nc, fb, Slave=nc.ax, Execute=True, **inputs)
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], cycle=nc.nc_cycle, cmdno=cmdno)
    return st


def test_gear_out_ext_stop_done_at_standstill(gnc: ScriptNc) -> None:
    fb = MC_GearOutExt()
    start_out_ext(gnc, fb, 9, Mode=E_DecoupleMode.MC_DECOUPLEMODE_STOP, Deceleration=50.0)
    p = gnc.last_sent("GearOutExt")
    assert p.args == {"Mode": 0, "Position": 0.0, "Velocity": 0.0, "Acceleration": 0.0, "Deceleration": 50.0,
                      "Jerk": 0.0}
    assert type(p.args["Mode"]) is int
    gnc.state(MOVING)
    gnc.set_jobs(active=(9, ACTIVE), ended=((7, DONE, 0),))
    gnc.cycle_once(2)
    assert fb.Busy and not fb.Done
    gnc.job_done(9)
    gnc.cycle_once()
    assert fb.Done and not fb.Busy


def test_gear_out_ext_endless_done_at_constant_velocity(gnc: ScriptNc) -> None:
    fb = MC_GearOutExt()
    start_out_ext(gnc, fb, 9, Mode=3, Velocity=20.0)
    gnc.state(MOVING)
    gnc.set_jobs(active=(9, ACTIVE))
    gnc.cycle_once()
    assert fb.Busy and not fb.Done
    gnc.state(MOVING | int(S.ConstantVelocity) | int(S.ContinuousMotion))
    gnc.cycle_once()
    assert fb.Done and not fb.Busy
    gnc.set_jobs(active=(10, ACTIVE), ended=((9, ABORTED, 0),))
    gnc.cycle_once()
    assert fb.Done and not fb.CommandAborted, "finished: no monitoring afterwards"


def test_gear_out_ext_endless_job_done_by_itself_is_aborted(gnc: ScriptNc) -> None:
    fb = MC_GearOutExt()
    start_out_ext(gnc, fb, 9, Mode=2)
    gnc.state(MOVING)
    gnc.set_jobs(active=(9, ACTIVE))
    gnc.cycle_once()
    gnc.job_done(9)
    gnc.cycle_once()
    assert fb.CommandAborted


def test_gear_out_ext_newpos_waits_for_the_target_window(gnc: ScriptNc) -> None:
    fb = MC_GearOutExt()
    start_out_ext(gnc, fb, 9, Mode=4, Position=100.0, Velocity=10.0)
    gnc.state(MOVING, OpModeDWord=int(OpModeDWord.OpModeTargetPosMonitoring))
    gnc.set_jobs(active=(9, ACTIVE))
    gnc.cycle_once()
    not_in_target = int(S.Operational | S.ControlLoopClosed | S.NotMoving)
    gnc.state(not_in_target)
    gnc.set_jobs(active=(9, DONE), ended=((9, DONE, 0),))
    gnc.cycle_once(3)
    assert fb.Busy and not fb.Done, "the target rule of appendix 7.1"
    gnc.state(not_in_target | int(S.InTargetPosition) | int(S.InPositionArea))
    gnc.cycle_once()
    assert fb.Done


def test_gear_out_ext_at_standstill_done_once_shown(gnc: ScriptNc) -> None:
    fb = MC_GearOutExt()
    drive(gnc, fb, Slave=gnc.ax, Execute=True, Mode=4, Position=1.0, Velocity=1.0)
    gnc.cycle_once()
    gnc.port.answer(gnc.port.sent[-1], cycle=gnc.nc_cycle + 5, cmdno=0)
    gnc.cycle_once()
    assert fb.Busy and not fb.Done
    gnc.cycle_once()
    assert fb.Done and not fb.Error


@pytest.mark.parametrize("execute_fell", [False, True])
def test_gear_out_ext_aborted_and_error(gnc: ScriptNc, execute_fell: bool) -> None:
    fb = MC_GearOutExt()
    st = start_out_ext(gnc, fb, 9, Mode=5, Position=10.0, Velocity=5.0)
    gnc.state(MOVING)
    gnc.set_jobs(active=(9, ACTIVE))
    gnc.cycle_once()
    if execute_fell:
        st["Execute"] = False
        gnc.cycle_once()
        assert fb.Busy
    gnc.set_jobs(active=(10, ACTIVE), ended=((9, ABORTED, 0),))
    gnc.cycle_once()
    assert fb.CommandAborted and not fb.Busy
    gnc.cycle_once()
    assert fb.CommandAborted is (not execute_fell)

    fb2 = MC_GearOutExt()
    gnc.calls.clear()
    start_out_ext(gnc, fb2, 11, Mode=4, Position=1e9, Velocity=5.0)
    gnc.set_jobs(active=(11, ERROR), ended=((11, ERROR, ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING),))
    gnc.cycle_once()
    assert fb2.Error and fb2.ErrorID == ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING


@pytest.mark.parametrize("mode", [7, -1, True, 1.0, "STOP", None])
def test_gear_out_ext_invalid_mode(gnc: ScriptNc, mode: Any) -> None:
    fb = MC_GearOutExt()
    drive(gnc, fb, Slave=gnc.ax, Execute=True, Mode=mode)
    gnc.cycle_once()
    assert fb.Error and fb.ErrorID == ErrorCodes.MC_INVALID_MODE == 0x4B04 and not gnc.port.sent


def test_gear_out_ext_nan_input(gnc: ScriptNc) -> None:
    fb = MC_GearOutExt()
    drive(gnc, fb, Slave=gnc.ax, Execute=True, Mode=4, Position=math.nan)
    gnc.cycle_once()
    assert fb.Error and fb.ErrorID == 0x4B06 and not gnc.port.sent
