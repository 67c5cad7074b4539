"""The PLC task: stale data, timeouts and late replies, binding, NC restart."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nc_schema import CmdState, ErrorCodes, NCTOPLC_DTYPE, decode_plc_frame, encode_plc_frame
from nc_sim import InProcessPlc, run_cycles
from plc_client import (
    AXIS_REF, MC_GearIn, MC_MoveAbsolute, MC_MoveVelocity, MC_Power, MC_ReadActualPosition, MC_Reset, MC_Stop,
)
from plc_client.task import PlcTask
from znc_testing.plc_rig import Rig, powered


def test_stale_data_gives_4b0f(rig: Rig) -> None:
    ax, pw, calls = powered(rig)
    mv, rp, mv2 = MC_MoveVelocity(), MC_ReadActualPosition(), MC_MoveAbsolute()
    rig.watch(mv, mv2)
    st = {"mv2": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=10.0)
        rp(Axis=ax, Enable=True)
        mv2(Axis=ax, Execute=st["mv2"], Position=0.0, Velocity=1.0)

    calls["body"] = body
    rig.run_until(lambda: mv.Active, 5)
    stale = ax.task.stale_cycles
    assert stale == 20  # 0.2 s at 10 ms
    rig.nc_running = False  # the NC stops producing frames
    n = rig.run_until(lambda: not ax.Status.Valid, 50)
    assert n == stale + 1  # the first cycle still sees the last fresh frame
    assert mv.Error and mv.ErrorID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE == 0x4B0F
    assert rp.Error and rp.ErrorID == 0x4B0F and not rp.Valid
    assert pw.Error and pw.ErrorID == 0x4B0F and not pw.Status
    cmdno = int(rig.rec()["CmdNo"])
    st["mv2"] = True
    rig.run(1)
    assert mv2.Error and mv2.ErrorID == 0x4B0F
    assert int(rig.rec()["CmdNo"]) == cmdno, "no command on stale data"
    # the NC comes back: data valid again, the blocks recover
    rig.nc_running = True
    rig.run(2)
    assert ax.Status.Valid and rp.Valid and not rp.Error and pw.Status and not pw.Error


def test_timeout_and_late_acceptance_halts_the_axis(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    plc = ax.task
    assert isinstance(plc, InProcessPlc)
    mv = MC_MoveVelocity(timeout=0.5)
    rig.watch(mv)
    plc.port.hold = True  # the NC executes but its replies never arrive
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=20.0)
    n = rig.run_until(lambda: not mv.Busy, 100)
    assert mv.Error and mv.ErrorID == ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT == 0x745
    assert n in (51, 52)  # sent in cycle 1: the error comes 0.5 s (50 cycles) later
    assert ax.Status.ContinuousMotion  # the NC did accept it
    # the late reply arrives: the command is still the axis's active one -> the task halts it
    plc.port.hold = False
    plc.port.release_held()
    rig.run(2)
    assert int(rig.rec()["CmdState"]) == CmdState.ACTIVE and ax.Status.DiscreteMotion  # Halt running
    rig.run_until(lambda: ax.Status.StandStill, 100)
    assert mv.Error and mv.ErrorID == 0x745  # the block's result does not change


def test_late_acceptance_of_a_coupling_decouples_the_slave(rig: Rig) -> None:
    """A late-accepted GearIn is undone with GearOut: a Halt to a coupled slave would be refused (0x4266)."""
    ax, _, calls = powered(rig)
    plc = ax.task
    slave = plc.axis("nc1", 2)
    gi, pw2 = MC_GearIn(timeout=0.3), MC_Power()
    st = {"go": False}

    def body(p):
        pw2(Axis=slave, Enable=True, Enable_Positive=True, Enable_Negative=True)
        gi(Master=ax, Slave=slave, Execute=st["go"], RatioNumerator=1, RatioDenominator=2)

    calls["body"] = body
    rig.run_until(lambda: pw2.Status, 10)
    plc.port.hold = True
    st["go"] = True
    rig.run_until(lambda: gi.Error, 100)
    assert gi.ErrorID == 0x745
    assert int(rig.rec(2)["CoupleState"]) == 3, "the NC did couple the slave"
    plc.port.hold = False
    plc.port.release_held()
    rig.run_until(lambda: int(rig.rec(2)["CoupleState"]) == 0, 20)
    assert int(rig.rec(1)["CoupleState"]) == 0


def test_late_reply_of_a_superseded_command_is_left_alone(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    plc = ax.task
    mv, mv2 = MC_MoveVelocity(timeout=0.1), MC_MoveAbsolute()
    plc.port.hold = True
    st = {"mv2": False}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=20.0)
        mv2(Axis=ax, Execute=st["mv2"], Position=50.0, Velocity=20.0)

    calls["body"] = body
    rig.run_until(lambda: mv.Error, 20)
    plc.port.hold = False
    st["mv2"] = True
    rig.run(1)
    plc.port.release_held()
    rig.run_until(lambda: mv2.Done, 500)
    assert math.isclose(ax.ActPos, 50.0, abs_tol=0.02)


def test_reset_and_stop_time_out_without_reply(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    ax.task.port.hold = True
    rst, stop = MC_Reset(timeout=0.05), MC_Stop(timeout=0.05)
    calls["body"] = lambda p: (rst(Axis=ax, Execute=True), stop(Axis=ax, Execute=True))
    rig.run(10)
    assert rst.Error and rst.ErrorID == 0x745 and stop.Error and stop.ErrorID == 0x745


def test_unknown_axis_and_unbound_axis() -> None:
    rig = Rig()
    plc = rig.plc()
    ghost = AXIS_REF(nc="nc1", axis_id=99)
    other_nc = AXIS_REF(nc="nc2", axis_id=1)
    rp1, rp2 = MC_ReadActualPosition(), MC_ReadActualPosition()
    plc.program = lambda p: (rp1(Axis=ghost, Enable=True), rp2(Axis=other_nc, Enable=True))
    rig.run(2)
    assert ghost.task is plc, "bound on first use inside the cycle"
    assert rp1.Error and rp1.ErrorID == ErrorCodes.NC_AXIS_ID_NOT_ALLOWED
    assert rp2.Error and rp2.ErrorID == 0x4B0F
    # outside any PLC cycle an unbound AXIS_REF cannot be bound: 0x4B0F, no exception
    loose = AXIS_REF(nc="nc1", axis_id=1)
    rp3 = MC_ReadActualPosition()(Axis=loose, Enable=True)
    assert rp3.Error and rp3.ErrorID == 0x4B0F


def test_bad_call_style_raises_typeerror(rig: Rig) -> None:
    mv = MC_MoveAbsolute()
    with pytest.raises(TypeError):
        mv(Axis=AXIS_REF(), Excute=True)
    with pytest.raises(TypeError):
        mv(Axis="nc1/1")
    with pytest.raises(ValueError):
        AXIS_REF(axis_id=0)


def test_nc_restart_is_detected(rig: Rig) -> None:
    ax, pw, calls = powered(rig)
    mv = MC_MoveVelocity()
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=5.0)
    rig.run_until(lambda: mv.Active, 5)
    # replace the core by a fresh one (cycle counter back to 0), as after an NC restart
    from nc_server.core import AxisConfig, NcCore
    new = NcCore([AxisConfig(AxisId=1), AxisConfig(AxisId=2)], cycle_time=0.001)
    plc = ax.task
    from nc_sim import InProcessPort
    plc.core = new
    plc.port = InProcessPort(new, client_id=plc.client_id)  # the new instance's server side
    plc.port.clock = lambda: plc.now
    rig.core = new
    rig.run(1)
    assert ax.nc_epoch == 1
    assert mv.Error and mv.ErrorID == 0x4B0F
    rig.run_until(lambda: pw.Status, 5)  # claimed again on the new instance
    assert not ax.Status.HasJob and ax.Status.StandStill  # nothing moves by itself


def test_program_forms_and_frame_publication() -> None:
    rig = Rig()
    calls: list[int] = []

    class Prog:
        def __init__(self) -> None:
            self.ax = AXIS_REF("nc1", 2)
            self.pw = MC_Power()

        def cycle(self) -> None:
            calls.append(1)
            self.pw(Axis=self.ax, Enable=True)

    prog = Prog()
    plc = rig.plc(program=prog)
    run_cycles(rig.core, plc, 3, nc_steps=10)
    assert len(calls) == 3 and prog.pw.Status
    # the PLCTONC frame a zenoh runtime would publish for this axis
    frame = encode_plc_frame(plc.cycle, [2], np.stack([prog.ax._plctonc[0]]))
    h, recs = decode_plc_frame(frame)
    assert int(recs[0]["AxisId"]) == 2 and int(recs[0]["PlcToNc"]["ControlDWord"]) == 1


def test_axis_ref_snapshot_is_read_only(rig: Rig) -> None:
    ax, _, _ = powered(rig)
    with pytest.raises(ValueError):
        ax.NcToPlc["ActPos"] = 5.0
    assert ax.NcToPlc.dtype == NCTOPLC_DTYPE
    ax.PlcToNc["Override"] = 5  # writable
    assert int(ax._plctonc["Override"][0]) == 5


def test_task_argument_validation() -> None:
    with pytest.raises(ValueError):
        PlcTask(cycle_time=0)
    with pytest.raises(ValueError):
        PlcTask(stale_cycles=0)
    with pytest.raises(TypeError):
        PlcTask(program=42)


def test_claim_dropped_silently_by_the_nc_is_claimed_again(rig: Rig) -> None:
    """Review regression: the NC's watchdog may release the claim of an axis that already had an
    error (its 0x8F0x never shows: the first error sticks). The task must not believe it still
    holds the axis forever: MC_Power claims again and gets the axis back after MC_Reset."""
    ax, pw, calls = powered(rig)
    plc = ax.task
    core = rig.core
    i = core.index(1)
    core.fault(i, ErrorCodes.NC_SOFT_LIMIT_MAX_POSITIONING)  # an axis error first ...
    assert plc.port.claims.release(1, plc.client_id)           # ... then the NC drops the claim
    core.set_plctonc(i, core.default_plctonc())
    rs = MC_Reset()
    calls["body"] = lambda p: rs(Axis=ax, Execute=True)
    rig.run_until(lambda: rs.Done, 20)
    assert not plc.port.holds_claim(1)
    n = rig.run_until(lambda: pw.Status, 300)  # within claim_retry (1 s = 100 PLC cycles) + a few
    assert plc.port.holds_claim(1) and not pw.Error and n <= 150
