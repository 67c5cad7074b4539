"""The motion blocks against the wire contract alone (schema/README.md "Commands and their fate"):
a scripted NC answers the requests and writes the frames (NCTOPLC + NCJOBS records) cycle by
cycle, so every row of the job-record table is checked independently of the NC's motion engine.
"""
from __future__ import annotations

from typing import Any

import pytest

from nc_schema import ErrorCodes, OpModeDWord
from plc_client import (
    MC_ChangeDynParam, MC_Halt, MC_MoveAbsolute, MC_MoveAbsoluteOrRestart, MC_MoveAdditive,
    MC_MoveContinuousAbsolute, MC_MoveContinuousRelative, MC_MoveRelative, MC_MoveVelocity, MC_NewPos,
    MC_NewPosAndVelo, MC_OrientedStop,
)
from znc_testing.plc_rig import ABORTED, ACTIVE, DONE, ERROR, IDLE, MOVING, S, ScriptNc, run_move, started

MOVE = {"Position": 100.0, "Velocity": 10.0}


# ---- the table ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", [1, 18, 19, 20, 21])
def test_buffered_block_waits_then_takes_over_when_the_first_is_done(nc: ScriptNc, mode: int) -> None:
    mv1, mv2 = MC_MoveAbsolute(), MC_MoveRelative()
    run_move(nc, mv1, 5, **MOVE)
    nc.watched.append(mv2)
    p2 = started(nc, mv2, 6, Distance=10.0, Velocity=10.0, BufferMode=mode)
    assert p2.args["BufferMode"] == mode
    nc.set_jobs(active=(5, ACTIVE), buffered=6)
    for _ in range(3):
        nc.cycle_once()
        assert mv2.Busy and not mv2.Active, "a waiting command is Busy, not Active"
        assert mv1.Busy and mv1.Active and not mv1.Done
    # the buffered/blended successor took over: the first is Done in the very cycle the second is Active
    nc.set_jobs(active=(6, ACTIVE), ended=((5, DONE, 0),))
    nc.cycle_once()
    assert mv1.Done and not mv1.Busy and not mv1.Active and not mv1.CommandAborted
    assert mv2.Busy and mv2.Active
    assert not any(nc.history(mv1, "Done")[:-1])
    assert not any(nc.history(mv2, "Active")[:-1])
    # the successor ends on an idle axis: the Done rule (no monitoring bits: HasJob fell)
    nc.state(IDLE)
    nc.set_jobs(active=(6, DONE), ended=((6, DONE, 0), (5, DONE, 0)))
    nc.cycle_once()
    assert mv2.Done and mv1.Done  # both held while Execute stays TRUE


def test_waiting_command_aborted_by_an_aborting_one(nc: ScriptNc) -> None:
    mv1, mv2, mv3 = MC_MoveAbsolute(), MC_MoveAbsolute(), MC_MoveAbsolute()
    run_move(nc, mv1, 5, **MOVE)
    nc.watched.append(mv2)
    started(nc, mv2, 6, BufferMode=1, **MOVE)
    nc.set_jobs(active=(5, ACTIVE), buffered=6)
    nc.cycle_once()
    assert mv2.Busy and not mv2.Active
    nc.watched.append(mv3)
    started(nc, mv3, 7, **MOVE)  # MC_Aborting replaces both
    nc.set_jobs(active=(7, ACTIVE), ended=((6, ABORTED, 0), (5, ABORTED, 0)))
    nc.cycle_once()
    assert mv1.CommandAborted and mv2.CommandAborted
    assert mv3.Busy and mv3.Active


def test_waiting_command_aborted_by_a_stop(nc: ScriptNc) -> None:
    mv1, mv2 = MC_MoveAbsolute(), MC_Halt()
    run_move(nc, mv1, 5, **MOVE)
    nc.watched.append(mv2)
    started(nc, mv2, 6, BufferMode=1)
    nc.set_jobs(active=(5, ACTIVE), buffered=6)
    nc.cycle_once()
    nc.set_jobs(active=(7, ACTIVE), ended=((6, ABORTED, 0), (5, ABORTED, 0)))  # MC_Stop by someone else
    nc.cycle_once()
    assert mv1.CommandAborted and mv2.CommandAborted and mv2.ErrorID == 0


def test_second_buffered_command_refused_with_the_ncs_code(nc: ScriptNc) -> None:
    mv1, mv2, mv3 = MC_MoveAbsolute(), MC_MoveAbsolute(), MC_MoveAbsolute()
    run_move(nc, mv1, 5, **MOVE)
    nc.watched += [mv2, mv3]
    started(nc, mv2, 6, BufferMode=1, **MOVE)
    nc.set_jobs(active=(5, ACTIVE), buffered=6)
    nc.calls.append(lambda: mv3(Axis=nc.ax, Execute=True, BufferMode=18, **MOVE))
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.NC_COMMAND_BUFFER_FULL, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert mv3.Error and mv3.ErrorID == 0x4292
    assert mv2.Busy and not mv2.Active and mv1.Active


def test_error_of_a_waiting_command_that_could_not_start(nc: ScriptNc) -> None:
    mv1, mv2 = MC_MoveAbsolute(), MC_MoveAbsolute()
    run_move(nc, mv1, 5, **MOVE)
    nc.watched.append(mv2)
    started(nc, mv2, 6, BufferMode=1, Position=1e9, Velocity=10.0)
    nc.set_jobs(active=(5, ACTIVE), buffered=6)
    nc.cycle_once()
    nc.state(IDLE)
    nc.set_jobs(active=(5, DONE), ended=((6, ERROR, 0x4463), (5, DONE, 0)))  # its target beyond the limit
    nc.cycle_once()
    assert mv2.Error and mv2.ErrorID == 0x4463
    assert mv1.Done  # its job ended normally on an idle axis (no monitoring bits set here)


@pytest.mark.parametrize("error_id, expect", [(0x4357, 0x4357), (0, 0x4B62)])
def test_ended_error(nc: ScriptNc, error_id: int, expect: int) -> None:
    mv = MC_MoveAbsolute()
    run_move(nc, mv, 5, **MOVE)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, ERROR, error_id),))
    nc.cycle_once()
    assert mv.Error and mv.ErrorID == expect


def test_active_job_ended_error_takes_the_ended_code(nc: ScriptNc) -> None:
    mv = MC_MoveAbsolute()
    run_move(nc, mv, 5, **MOVE)
    nc.state(IDLE, ErrorCode=0)
    nc.set_jobs(active=(5, ERROR), ended=((5, ERROR, 0x4462),))
    nc.cycle_once()
    assert mv.Error and mv.ErrorID == 0x4462


def test_pushed_out_of_the_record_is_aborted_and_unknown_is_an_error(nc: ScriptNc) -> None:
    mv1, mv2 = MC_MoveAbsolute(), MC_MoveAbsolute()
    run_move(nc, mv1, 5, **MOVE)
    nc.set_jobs(active=(11, ACTIVE), ended=((10, ABORTED, 0), (9, ABORTED, 0), (8, ABORTED, 0), (7, ABORTED, 0)))
    nc.cycle_once()
    assert mv1.CommandAborted and mv1.ErrorID == 0
    # a number the NC never handed out (newer than NewestCmdNo): lost
    nc.watched.append(mv2)
    started(nc, mv2, 20, **MOVE)
    nc.cycle_once()
    assert mv2.Error and mv2.ErrorID == ErrorCodes.MC_CMD_NOT_ACTIVE


def test_cmdno_wraps_in_the_record(nc: ScriptNc) -> None:
    mv = MC_MoveAbsolute()
    run_move(nc, mv, 65535, **MOVE)
    nc.set_jobs(active=(5, ACTIVE), newest=5, ended=tuple((k, ABORTED, 0) for k in (4, 3, 2, 1)))
    nc.cycle_once()
    assert mv.CommandAborted


def test_done_rule_on_the_idle_axis_waits_for_the_window(nc: ScriptNc) -> None:
    mv = MC_MoveAbsolute()
    nc.state(IDLE, OpModeDWord=int(OpModeDWord.OpModeTargetPosMonitoring | OpModeDWord.OpModePosAreaMonitoring))
    run_move(nc, mv, 5, **MOVE)
    nc.job_done(5, int(S.Operational | S.ControlLoopClosed | S.NotMoving | S.InPositionArea))
    nc.cycle_once(3)
    assert mv.Busy and mv.Active and not mv.Done, "DONE on an idle axis: wait for InTargetPosition"
    nc.state(IDLE)
    nc.cycle_once()
    assert mv.Done and not mv.Busy


def test_done_while_waiting_for_the_window_when_a_new_command_starts(nc: ScriptNc) -> None:
    """Ended DONE while another job is active: Done at once, not CommandAborted (the window no longer matters)."""
    mv = MC_MoveAbsolute()
    nc.state(IDLE, OpModeDWord=int(OpModeDWord.OpModeTargetPosMonitoring))
    run_move(nc, mv, 5, **MOVE)
    nc.job_done(5, int(S.Operational | S.ControlLoopClosed | S.NotMoving))
    nc.cycle_once()
    assert mv.Busy
    nc.state(MOVING)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, DONE, 0),))
    nc.cycle_once()
    assert mv.Done and not mv.CommandAborted


def test_frames_older_than_the_reply_are_not_evaluated(nc: ScriptNc) -> None:
    mv = MC_MoveAbsolute()
    nc.watched.append(mv)
    nc.calls.append(lambda: mv(Axis=nc.ax, Execute=True, **MOVE))
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], cycle=nc.nc_cycle + 25, cmdno=5)  # takes effect 2.5 PLC cycles later
    nc.set_jobs(active=(4, ACTIVE), newest=4)
    nc.cycle_once(2)
    assert mv.Busy and not mv.Active and not mv.Error
    nc.set_jobs(active=(5, ACTIVE), ended=((4, ABORTED, 0),))
    nc.cycle_once(2)
    assert mv.Busy and mv.Active


# ---- fallback: no job records ----------------------------------------------------------------------------
def test_fallback_without_job_records() -> None:
    nc = ScriptNc(jobs=False)
    nc.cycle_once()
    mv1, mv2 = MC_MoveAbsolute(), MC_MoveAbsolute()
    nc.watched += [mv1, mv2]
    started(nc, mv1, 5, **MOVE)
    nc.state(MOVING, CmdNo=5, CmdState=ACTIVE)
    nc.cycle_once()
    assert mv1.Active
    started(nc, mv2, 6, BufferMode=1, **MOVE)
    nc.state(MOVING | int(S.CmdBuffered))
    nc.cycle_once()
    assert mv2.Busy and not mv2.Active and not mv2.Error, "CmdBuffered: the older CmdNo is the active one"
    nc.state(MOVING, CmdNo=6, CmdState=ACTIVE)
    nc.cycle_once()
    # without job records a successor cannot be told from an aborting command
    assert mv1.CommandAborted and mv2.Active
    nc.state(IDLE, CmdNo=6, CmdState=DONE)
    nc.cycle_once()
    assert mv2.Done


def test_fallback_lost_command_is_an_error() -> None:
    nc = ScriptNc(jobs=False)
    nc.cycle_once()
    mv = MC_MoveAbsolute()
    nc.watched.append(mv)
    started(nc, mv, 5, **MOVE)
    nc.state(IDLE, CmdNo=4, CmdState=DONE)
    nc.cycle_once()
    assert mv.Error and mv.ErrorID == ErrorCodes.MC_CMD_NOT_ACTIVE


# ---- velocity / continuous ----------------------------------------------------------------------------------
def test_velocity_job_taken_over_by_a_buffered_successor_is_in_velocity(nc: ScriptNc) -> None:
    mv = MC_MoveVelocity()
    run_move(nc, mv, 5, Velocity=10.0)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, DONE, 0),))
    nc.cycle_once()
    assert mv.InVelocity and not mv.CommandAborted


@pytest.mark.parametrize("cls, inputs", [
    (MC_MoveContinuousAbsolute, {"Position": 50.0}),
    (MC_MoveContinuousRelative, {"Distance": 50.0}),
])
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_in_end_velocity_once_the_target_is_passed(nc: ScriptNc, cls: Any, inputs: dict, direction: float) -> None:
    fb = cls()
    inputs = {k: v * direction for k, v in inputs.items()}
    run_move(nc, fb, 5, Velocity=20.0, EndVelocity=5.0, **inputs)
    p = nc.last_sent(cls.CMD)
    assert p.args["EndVelocity"] == 5.0 and p.args["BufferMode"] == 0
    cv = MOVING | int(S.ConstantVelocity) | int(S.ContinuousMotion)
    # approaching the target at constant velocity: not yet
    nc.state(cv, SetPos=10.0 * direction, SetVelo=20.0 * direction, TargetPos=50.0 * direction)
    nc.cycle_once(2)
    assert fb.Busy and fb.Active and not fb.InEndVelocity
    # at the target, decelerating to the end velocity (not constant)
    nc.state(MOVING, SetPos=50.0 * direction, SetVelo=7.0 * direction, TargetPos=50.0 * direction)
    nc.cycle_once()
    assert not fb.InEndVelocity
    # past it at the end velocity (the override may scale it: only the direction counts)
    nc.state(cv, SetPos=51.0 * direction, SetVelo=2.5 * direction, TargetPos=50.0 * direction)
    nc.cycle_once()
    assert fb.InEndVelocity and not fb.Busy and not fb.Active
    # Tc2_MC2: finished, no further monitoring: a later command is no CommandAborted
    nc.set_jobs(active=(6, ACTIVE), ended=((5, ABORTED, 0),))
    nc.cycle_once()
    assert fb.InEndVelocity and not fb.CommandAborted


def test_continuous_move_aborted_before_the_target(nc: ScriptNc) -> None:
    fb = MC_MoveContinuousAbsolute()
    run_move(nc, fb, 5, Position=50.0, Velocity=20.0, EndVelocity=5.0)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, ABORTED, 0),))
    nc.cycle_once()
    assert fb.CommandAborted and not fb.InEndVelocity


def test_continuous_move_with_end_velocity_zero_ends_by_the_done_rule(nc: ScriptNc) -> None:
    fb = MC_MoveContinuousRelative()
    run_move(nc, fb, 5, Distance=50.0, Velocity=20.0, EndVelocity=0.0)
    nc.job_done(5, SetPos=50.0, SetVelo=0.0, TargetPos=50.0)
    nc.cycle_once()
    assert fb.InEndVelocity


# ---- MC_MoveAbsoluteOrRestart ------------------------------------------------------------------------------
def test_or_restart_follows_the_new_command_without_command_aborted(nc: ScriptNc) -> None:
    mv = MC_MoveAbsoluteOrRestart()
    run_move(nc, mv, 5, Position=100.0, Velocity=10.0)
    nc.calls[:] = [lambda: mv(Axis=nc.ax, Execute=False)]
    nc.cycle_once()
    assert mv.Busy and mv.Active
    nc.calls[:] = [lambda: mv(Axis=nc.ax, Execute=True, Position=40.0, Velocity=30.0)]
    n = len(nc.port.sent)
    nc.cycle_once()
    assert len(nc.port.sent) == n + 1, "a rising edge while Busy sends a new command"
    p = nc.port.sent[-1]
    assert p.cmd == "MoveAbsoluteOrRestart" and p.args["Position"] == 40.0 and p.args["Velocity"] == 30.0
    assert mv.Busy and mv.Active
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=6)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, ABORTED, 0),))
    nc.cycle_once(3)
    assert mv.Busy and mv.Active and not mv.CommandAborted
    nc.state(IDLE)
    nc.set_jobs(active=(6, DONE), ended=((6, DONE, 0), (5, ABORTED, 0)))
    nc.cycle_once()
    assert mv.Done
    assert not any(nc.history(mv, "CommandAborted"))


def test_or_restart_while_the_first_reply_is_still_on_its_way(nc: ScriptNc) -> None:
    mv = MC_MoveAbsoluteOrRestart()
    nc.watched.append(mv)
    ex = {"v": True, "pos": 100.0}
    nc.calls.append(lambda: mv(Axis=nc.ax, Execute=ex["v"], Position=ex["pos"], Velocity=10.0))
    nc.cycle_once()
    p1 = nc.port.sent[-1]
    ex["v"] = False
    nc.cycle_once()
    ex["v"], ex["pos"] = True, 30.0
    nc.cycle_once()
    p2 = nc.port.sent[-1]
    assert p2 is not p1 and p2.args["Position"] == 30.0
    nc.port.answer(p1, cycle=nc.nc_cycle, cmdno=5)
    nc.port.answer(p2, cycle=nc.nc_cycle, cmdno=6)
    nc.state(MOVING)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, ABORTED, 0),))
    nc.cycle_once(2)
    assert mv.Busy and mv.Active and not mv.CommandAborted
    assert not nc._orphans, "the dropped first request is no late acceptance (no Halt)"
    assert [q.cmd for q in nc.port.sent].count("Halt") == 0


def test_ordinary_block_ignores_a_retrigger(nc: ScriptNc) -> None:
    mv = MC_MoveAbsolute()
    run_move(nc, mv, 5, **MOVE)
    n = len(nc.port.sent)
    nc.calls[:] = [lambda: mv(Axis=nc.ax, Execute=False)]
    nc.cycle_once()
    nc.calls[:] = [lambda: mv(Axis=nc.ax, Execute=True)]
    nc.cycle_once()
    assert len(nc.port.sent) == n


# ---- amendments ----------------------------------------------------------------------------------------------
def test_new_pos_done_on_acceptance_and_the_move_ends_done(nc: ScriptNc) -> None:
    mv, np_ = MC_MoveAbsolute(), MC_NewPos()
    run_move(nc, mv, 5, **MOVE)
    nc.watched.append(np_)
    nc.calls.append(lambda: np_(Axis=nc.ax, Execute=True, NewPos=60.0))
    nc.cycle_once()
    p = nc.last_sent("NewPos")
    assert p.args == {"NewPos": 60.0}
    assert np_.Busy and not np_.Done
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=5)  # the amended job keeps its number
    nc.state(MOVING | int(S.NewTargetPos), TargetPos=60.0)
    nc.set_jobs(active=(5, ACTIVE), flags=1)
    nc.cycle_once()
    assert np_.Done and not np_.Busy
    assert mv.Busy and mv.Active
    nc.state(IDLE, TargetPos=60.0, SetPos=60.0)
    nc.set_jobs(active=(5, DONE), ended=((5, DONE, 0),), flags=1)
    nc.cycle_once()
    assert mv.Done and not mv.CommandAborted


@pytest.mark.parametrize("cls, inputs", [(MC_NewPos, {"NewPos": 1.0}), (MC_NewPosAndVelo, {"NewPos": 1.0})])
def test_amendment_refused(nc: ScriptNc, cls: Any, inputs: dict) -> None:
    fb = cls()
    nc.watched.append(fb)
    nc.calls.append(lambda: fb(Axis=nc.ax, Execute=True, **inputs))
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.MC_AXIS_NOT_MOVING, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == 0x4B03
    nc.calls[:] = [lambda: fb(Axis=nc.ax, Execute=False)]
    nc.cycle_once()
    assert not fb.Error and fb.ErrorID == 0


def test_new_pos_and_velo_arguments_and_mode(nc: ScriptNc) -> None:
    fb = MC_NewPosAndVelo()
    nc.watched.append(fb)
    nc.calls.append(lambda: fb(Axis=nc.ax, Execute=True, Mode=9, NewPos=5.0, NewVelo=2.0, ActivationPos=3.0))
    nc.cycle_once()
    p = nc.last_sent("NewPosAndVelo")
    assert p.args == {"Mode": 9, "NewPos": 5.0, "NewVelo": 2.0, "ActivationPos": 3.0}
    assert type(p.args["Mode"]) is int
    assert MC_NewPosAndVelo().Mode == 3  # CHANGE_POSANDVELO


@pytest.mark.parametrize("cls, inputs, code", [
    (MC_NewPosAndVelo, {"Mode": 1.0}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
    (MC_NewPosAndVelo, {"Mode": True}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
    (MC_NewPosAndVelo, {"NewVelo": float("nan")}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
    (MC_NewPos, {"NewPos": "x"}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
    (MC_ChangeDynParam, {"Jerk": float("inf")}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
    (MC_OrientedStop, {"Position": float("nan")}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
    (MC_MoveContinuousAbsolute, {"EndVelocity": None}, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
    (MC_MoveAdditive, {"BufferMode": 1.5}, ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED),
    (MC_Halt, {"BufferMode": False}, ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED),
])
def test_bad_inputs_refused_locally(nc: ScriptNc, cls: Any, inputs: dict, code: int) -> None:
    fb = cls()
    nc.watched.append(fb)
    nc.calls.append(lambda: fb(Axis=nc.ax, Execute=True, **inputs))
    nc.cycle_once()
    assert fb.Error and fb.ErrorID == code
    assert not nc.port.sent


def test_change_dyn_param_done_at_the_destination(nc: ScriptNc) -> None:
    mv, cd = MC_MoveAbsolute(), MC_ChangeDynParam()
    run_move(nc, mv, 5, **MOVE)
    nc.watched.append(cd)
    nc.calls.append(lambda: cd(Axis=nc.ax, Execute=True, Acceleration=5.0, Deceleration=6.0, Jerk=70.0))
    nc.cycle_once()
    p = nc.last_sent("ChangeDynParam")
    assert p.args == {"Acceleration": 5.0, "Deceleration": 6.0, "Jerk": 70.0}
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=5)
    nc.cycle_once(3)
    assert cd.Busy and not cd.Done, "Done when the axis is at its destination, not on the reply"
    assert not hasattr(cd, "Active") or not cd.Active
    nc.job_done(5)
    nc.cycle_once()
    assert cd.Done and mv.Done


def test_change_dyn_param_retriggered_and_on_continuous_motion(nc: ScriptNc) -> None:
    mv, cd = MC_MoveVelocity(), MC_ChangeDynParam()
    run_move(nc, mv, 5, Velocity=10.0)
    nc.watched.append(cd)
    ex = {"v": True, "acc": 5.0}
    nc.calls.append(lambda: cd(Axis=nc.ax, Execute=ex["v"], Acceleration=ex["acc"]))
    nc.cycle_once()
    p1 = nc.last_sent("ChangeDynParam")
    ex["v"] = False
    nc.cycle_once()
    ex["v"], ex["acc"] = True, 9.0
    nc.cycle_once()
    p2 = nc.last_sent("ChangeDynParam")
    assert p2 is not p1 and p2.args["Acceleration"] == 9.0, "re-triggered during the movement"
    nc.port.answer(p1, cycle=nc.nc_cycle, cmdno=5)
    nc.port.answer(p2, cycle=nc.nc_cycle, cmdno=5)
    nc.cycle_once()
    assert cd.Busy
    nc.state(MOVING | int(S.ContinuousMotion) | int(S.ConstantVelocity))
    nc.cycle_once()
    assert cd.Done and not cd.Busy


def test_change_dyn_param_job_aborted(nc: ScriptNc) -> None:
    mv, cd = MC_MoveAbsolute(), MC_ChangeDynParam()
    run_move(nc, mv, 5, **MOVE)
    nc.watched.append(cd)
    nc.calls.append(lambda: cd(Axis=nc.ax, Execute=True))
    nc.cycle_once()
    nc.port.answer(nc.last_sent("ChangeDynParam"), cycle=nc.nc_cycle, cmdno=5)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, ABORTED, 0),))
    nc.cycle_once()
    assert cd.CommandAborted and mv.CommandAborted


def test_oriented_stop_reports_the_ncs_refusal_and_is_done_at_standstill(nc: ScriptNc) -> None:
    mv, os_ = MC_MoveVelocity(), MC_OrientedStop()
    run_move(nc, mv, 5, Velocity=10.0)
    nc.watched.append(os_)
    nc.calls.append(lambda: os_(Axis=nc.ax, Execute=True, Position=360.0))
    nc.cycle_once()
    p = nc.last_sent("OrientedStop")
    assert p.args == {"Position": 360.0, "Deceleration": 0.0, "Jerk": 0.0}
    nc.port.answer(p, error=0x4281, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert os_.Error and os_.ErrorID == 0x4281
    nc.calls[-1] = lambda: os_(Axis=nc.ax, Execute=False)
    nc.cycle_once()
    nc.calls[-1] = lambda: os_(Axis=nc.ax, Execute=True, Position=90.0)
    nc.cycle_once()
    nc.port.answer(nc.last_sent("OrientedStop"), cycle=nc.nc_cycle, cmdno=6)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, ABORTED, 0),))
    nc.cycle_once()
    assert os_.Busy and os_.Active
    nc.state(IDLE)
    nc.set_jobs(active=(6, DONE), ended=((6, DONE, 0), (5, ABORTED, 0)))
    nc.cycle_once()
    assert os_.Done
