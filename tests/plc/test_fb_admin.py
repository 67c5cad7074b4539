"""MC_Power, MC_Reset, MC_SetOverride and the MC_Read* blocks against a real NcCore (MC_ReadAxisError's
rules also against a scripted NC)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from nc_schema import ControlDWord, ErrorCodes, MC_AxisStates
from nc_server.drives.sim import SimDrive
from plc_client import (
    AXIS_REF, MC_MoveAbsolute, MC_MoveVelocity, MC_Power, MC_ReadActualPosition, MC_ReadAxisError, MC_ReadStatus, MC_Reset,
    MC_SetOverride,
)
from znc_testing.plc_rig import IDLE, Rig, ScriptNc, StateDWord, powered


def test_power_on_and_off(rig: Rig) -> None:
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    pw = MC_Power()
    st = {"en": True, "pos": True, "neg": False}
    plc.program = lambda p: pw(Axis=ax, Enable=st["en"], Enable_Positive=st["pos"], Enable_Negative=st["neg"])
    rig.run(1)
    assert pw.Busy and not pw.Status  # claim + enables go out at the end of this cycle
    cdw = int(ax.PlcToNc["ControlDWord"])
    assert cdw == int(ControlDWord.Enable | ControlDWord.FeedEnablePlus)
    rig.run(1)
    assert pw.Status and pw.Active and not pw.Error
    assert ax.Status.StandStill and ax.Status.ControlLoopClosed and ax.Status.Operational
    assert int(rig.core.plctonc["ControlDWord"][0]) == cdw, "the NC applies this client's PLCTONC"
    assert ax.controlled
    st["en"] = False
    rig.run(2)
    assert not pw.Status and not pw.Busy and not pw.Active
    assert int(ax.PlcToNc["ControlDWord"]) == 0
    assert ax.Status.Disabled and ax.Status.MotionState == MC_AxisStates.MC_AXISSTATE_DISABLED


def test_power_override_mapping_and_range(rig: Rig) -> None:
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    pw = MC_Power()
    st = {"ov": 68.123}
    plc.program = lambda p: pw(Axis=ax, Enable=True, Override=st["ov"])
    rig.run(2)
    assert int(ax.PlcToNc["Override"]) == 681230
    assert int(rig.core.plctonc["Override"][0]) == 681230
    st["ov"] = 150.0
    rig.run(1)
    assert pw.Error and pw.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT == 0x4B06
    assert int(ax.PlcToNc["Override"]) == 681230, "an invalid override keeps the last valid one"
    st["ov"] = 0.0
    rig.run(1)
    assert not pw.Error and int(ax.PlcToNc["Override"]) == 0


def test_power_buffer_mode(rig: Rig) -> None:
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    pw = MC_Power()
    plc.program = lambda p: pw(Axis=ax, Enable=True, BufferMode=1)
    rig.run(2)
    assert pw.Error and pw.ErrorID == 0x4B64
    assert pw.Status  # still acts as MC_Aborting


def test_claim_conflict_between_clients(rig: Rig) -> None:
    ax1, pw1, _ = powered(rig, "plc1")
    plc2 = rig.plc("plc2")
    ax2 = plc2.axis("nc1", 1)
    pw2 = MC_Power()
    st = {"en": True}
    plc2.program = lambda p: pw2(Axis=ax2, Enable=st["en"], Enable_Positive=True)
    rig.run(3)
    assert pw2.Error and pw2.ErrorID == ErrorCodes.ADSERR_DEVICE_ACCESSDENIED == 0x723
    assert not pw2.Status and not pw2.Active
    # plc2's enables must not reach the NC; plc1's do
    rig.plcs["plc1"].program = lambda p: pw1(Axis=ax1, Enable=True, Enable_Positive=False, Enable_Negative=True)
    rig.run(2)
    assert int(rig.core.plctonc["ControlDWord"][0]) == int(ControlDWord.Enable | ControlDWord.FeedEnableMinus)
    # plc1 gives the axis up; plc2 retries (every claim_retry s) and gets it
    rig.plcs["plc1"].program = None
    rig.plcs["plc1"].port.send("nc1", 1, "Release")
    rig.run_until(lambda: pw2.Status, 150)
    assert not pw2.Error
    assert int(rig.core.plctonc["ControlDWord"][0]) == int(ControlDWord.Enable | ControlDWord.FeedEnablePlus)


def test_reset_clears_an_axis_error(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    rst, err, mv = MC_Reset(), MC_ReadAxisError(), MC_MoveAbsolute()
    rig.watch(rst, mv)
    st = {"rst": False, "mv": False}

    def body(p):
        err(Axis=ax, Enable=True)
        rst(Axis=ax, Execute=st["rst"])
        mv(Axis=ax, Execute=st["mv"], Position=3.0, Velocity=10.0)

    calls["body"] = body
    rig.core.fault(0, ErrorCodes.NC_POSITION_LAG)
    rig.run(2)
    assert err.Valid and err.Done and err.AxisErrorID == ErrorCodes.NC_POSITION_LAG
    assert err.Error and err.ErrorID == ErrorCodes.NC_POSITION_LAG, "TcMC 4.5: ErrorID is the axis's error code"
    assert ax.Status.ErrorStop and ax.Status.Error and ax.Status.ErrorId == 0x4550
    st["mv"] = True
    rig.run_until(lambda: not mv.Busy, 5)
    assert mv.Error and mv.ErrorID == ErrorCodes.MC_AXIS_CANNOT_BE_STARTED
    st["rst"] = True
    rig.run(1)
    assert rst.Busy
    rig.run_until(lambda: rst.Done, 5)
    assert err.AxisErrorID == 0 and ax.Status.StandStill
    assert not err.Error and err.ErrorID == 0 and err.Done
    st["mv"] = False
    rig.run(1)
    st["mv"] = True
    rig.run_until(lambda: mv.Done, 200)


def test_set_override_on_a_controlled_axis(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, so = rig.watch(MC_MoveVelocity(), MC_SetOverride())
    st = {"so": False, "ov": 50.0}

    def body(p):
        mv(Axis=ax, Execute=True, Velocity=40.0)
        so(Axis=ax, Execute=st["so"], Override=st["ov"])

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 100)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 40.0)
    st["so"] = True
    rig.run(1)
    assert so.Done and not so.Busy, "written into this cycle's PLCTONC: Done at once"
    assert int(ax.PlcToNc["Override"]) == 500000
    rig.run(60)
    assert math.isclose(float(ax.NcToPlc["SetVelo"]), 20.0, rel_tol=1e-6)
    assert so.Done  # held
    st["so"], st["ov"] = False, 101.0
    rig.run(1)
    st["so"] = True
    rig.run(1)
    assert so.Error and so.ErrorID == 0x4B06


def test_set_override_on_an_axis_not_controlled(rig: Rig) -> None:
    plc = rig.plc()
    ax = plc.axis("nc1", 2)
    so = rig.watch(MC_SetOverride())
    plc.program = lambda p: so(Axis=ax, Execute=True, Override=25.0)
    rig.run(1)
    assert so.Busy  # sent as an NC command
    rig.run_until(lambda: so.Done, 3)
    assert int(rig.core.plctonc["Override"][1]) == 250000


def test_read_blocks(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    rp, rs, mv = MC_ReadActualPosition(), MC_ReadStatus(), MC_MoveAbsolute()
    st = {"en": True}

    def body(p):
        mv(Axis=ax, Execute=True, Position=30.0, Velocity=60.0)
        rp(Axis=ax, Enable=st["en"])
        rs(Axis=ax, Enable=st["en"])

    calls["body"] = body
    rig.run(5)
    assert rp.Valid and rp.Done and rp.Busy and not rp.Error
    assert rp.Position == float(ax.NcToPlc["ActPos"]) and 0 < rp.Position < 30.0
    assert rs.Valid and rs.DiscreteMotion and not rs.StandStill and rs.Accelerating and not rs.Decelerating
    assert rs.Status.HasJob and rs.Status.MotionState == MC_AxisStates.MC_AXISSTATE_DISCRETEMOTION
    rig.run_until(lambda: ax.Status.Decelerating, 100)
    rig.run(1)
    assert rs.Decelerating and not rs.Accelerating
    rig.run_until(lambda: mv.Done, 200)
    rig.run(1)
    assert rs.StandStill and not rs.DiscreteMotion and not rs.ConstantVelocity
    assert math.isclose(rp.Position, 30.0, abs_tol=0.02)
    st["en"] = False
    rig.run(1)
    assert not rp.Valid and not rp.Busy and not rs.Valid


def test_status_flags_follow_motion_state(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv = MC_MoveVelocity()
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=10.0)
    rig.run(10)
    s = ax.Status
    flags = [s.ErrorStop, s.Disabled, s.Stopping, s.StandStill, s.DiscreteMotion, s.ContinuousMotion,
             s.SynchronizedMotion, s.Homing]
    assert flags.count(True) == 1 and s.ContinuousMotion
    assert s.Moving and s.PositiveDirection and not s.NegativeDirection and s.HasJob
    # the snapshot of this PLC cycle was taken before the NC ran its 10 cycles
    assert s.NcCycleCounter == rig.core.cycle - 10 and s.CycleCounter == ax.task.cycle and s.Valid


def test_read_axis_error_shows_the_axis_error_code(nc: ScriptNc) -> None:
    """TcMC 4.5 "The error code for an axis is displayed": while Enable, ErrorID = NCTOPLC.ErrorCode and
    Error = (ErrorCode != 0), Done TRUE (read); AxisErrorID (Tc2_MC2) the same; Valid = Done, Busy = Enable."""
    err = MC_ReadAxisError()
    st = {"Enable": True}
    nc.calls.append(lambda: err(Axis=nc.ax, **st))
    nc.cycle_once()
    assert (err.Done, err.Valid, err.Busy, err.Error, err.ErrorID, err.AxisErrorID) == (True, True, True, False, 0, 0)
    nc.state(IDLE | int(StateDWord.Error), ErrorCode=ErrorCodes.NC_POSITION_LAG)
    nc.cycle_once()
    assert err.Error and err.ErrorID == err.AxisErrorID == ErrorCodes.NC_POSITION_LAG == 0x4550
    assert err.Done and err.Valid and err.Busy
    st["Enable"] = False
    nc.cycle_once()
    assert (err.Done, err.Valid, err.Busy, err.Error, err.ErrorID, err.AxisErrorID) == (False,) * 4 + (0, 0)
    st["Enable"] = True
    nc.cycle_once()
    assert err.Error and err.ErrorID == 0x4550
    nc.state(IDLE, ErrorCode=0)  # reset
    nc.cycle_once()
    assert not err.Error and err.ErrorID == 0 and err.Done
    nc.state(IDLE | int(StateDWord.Error), ErrorCode=0x4550)
    for _ in range(nc.stale_cycles + 1):
        nc.step()  # no newer frame: the data turns stale
    assert err.Error and err.ErrorID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE, "the block's own error"
    assert not err.Done and not err.Valid and err.AxisErrorID == 0


# ---- MC_Power shows the axis's error (TcMC 4.1 "Error: Becomes TRUE, as soon as an error occurs"; MC3 MC_Power:
# "Error occurred within function block or axis already signaling an error") ------------------------------------
class HeldDrive(SimDrive):
    """A simulated drive whose motor can be jammed (``held``): it stands whatever the set-point (a real following
    error: the NC's lag monitoring raises 0x4550)."""

    held = False

    def step(self, enabled: np.ndarray, set_pos: np.ndarray, set_velo: np.ndarray, set_acc: np.ndarray) -> None:
        super().step(enabled, self.act_pos.copy() if self.held else set_pos, set_velo, set_acc)


def _frame_error(ax: AXIS_REF) -> int:
    """The axis error this cycle's frame shows (0: none)."""
    return int(ax.NcToPlc.ErrorCode) if int(ax.NcToPlc.StateDWord) & int(StateDWord.Error) else 0


def test_power_shows_a_following_error_with_enable_true_and_false_until_mc_reset() -> None:
    """A jammed motor during a move: the NC's lag monitoring raises 0x4550; MC_Power shows it (Error, ErrorID =
    the axis's code) with Enable TRUE and FALSE, Status FALSE; after MC_Reset, Error falls with the first frame
    without the error, not before nor after."""
    rig = Rig(drive_cls=HeldDrive)
    ax, pw, calls = powered(rig)
    plc = rig.plcs["plc1"]
    mv, rst = MC_MoveVelocity(), MC_Reset()
    st = {"en": True, "mv": True, "rst": False}
    seen: list[tuple[int, bool, int]] = []

    def program(p: Any) -> None:
        pw(Axis=ax, Enable=st["en"], Enable_Positive=True, Enable_Negative=True)
        mv(Axis=ax, Execute=st["mv"], Velocity=50.0)
        rst(Axis=ax, Execute=st["rst"])
        seen.append((_frame_error(ax), pw.Error, pw.ErrorID))

    plc.program = program
    rig.run_until(lambda: mv.InVelocity, 100)
    assert not pw.Error and pw.Status
    drive = rig.core.drive
    assert isinstance(drive, HeldDrive)
    drive.held = True
    rig.run_until(lambda: ax.Status.Error, 100)
    assert ax.NcToPlc.ErrorCode == ErrorCodes.NC_POSITION_LAG == 0x4550
    assert pw.Error and pw.ErrorID == 0x4550, "TcMC 4.1: MC_Power's Error shows the axis's error"
    assert pw.Busy and pw.Active and not pw.Status
    st["en"], st["mv"] = False, False  # disabled: the axis error still shows
    rig.run(3)
    assert not pw.Busy and not pw.Active and not pw.Status
    assert pw.Error and pw.ErrorID == 0x4550, "with Enable FALSE too"
    drive.held = False
    st["rst"] = True
    rig.run_until(lambda: rst.Done, 20)
    rig.run(2)
    assert not pw.Error and pw.ErrorID == 0
    # every cycle: MC_Power's error is exactly the frame's (it falls with the first frame without the error)
    assert [(e != 0, e) for e, *_ in seen] == [(err, eid) for _, err, eid in seen]
    assert any(e for e, *_ in seen) and not seen[-1][0]
    st["en"], st["rst"] = True, False
    rig.run_until(lambda: pw.Status, 10)
    assert not pw.Error


def test_power_shows_a_drive_fault_and_its_own_error_first() -> None:
    """A drive hardware error (DriveDeviceError: 0x4650 on the enabled axis) shows on MC_Power (Enable TRUE,
    then FALSE); an Override out of range (0x4B06, the block's own) takes precedence while both are there; an
    I/O data error of a disabled axis (0x4655) shows with Enable FALSE; MC_Reset clears them once the drive is
    well again."""
    rig = Rig()
    ax, pw, calls = powered(rig)
    plc = rig.plcs["plc1"]
    rst = MC_Reset()
    st = {"en": True, "ov": 100.0, "rst": False}

    def program(p: Any) -> None:
        pw(Axis=ax, Enable=st["en"], Enable_Positive=True, Enable_Negative=True, Override=st["ov"])
        rst(Axis=ax, Execute=st["rst"])

    plc.program = program
    drive = rig.core.drive  # (the simulated CiA 402 drive: a hardware fault, 0x603F 0x5000; MC_Reset: fault reset)
    drive.set_device_error(0, True)
    rig.run_until(lambda: pw.Error, 5)
    assert ax.NcToPlc.ErrorCode == ErrorCodes.NC_DRIVE_NOT_READY == 0x4650
    assert pw.ErrorID == 0x4650 and not pw.Status and pw.Active
    st["ov"] = 150.0  # the block's own error first
    rig.run(1)
    assert pw.Error and pw.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT
    st["ov"] = 100.0
    rig.run(1)
    assert pw.Error and pw.ErrorID == 0x4650
    st["en"] = False
    rig.run(2)
    assert pw.Error and pw.ErrorID == 0x4650 and not pw.Busy
    drive.set_device_error(0, False)
    st["rst"] = True
    rig.run_until(lambda: rst.Done or rst.Error, 20)
    assert rst.Done
    rig.run(1)
    assert not pw.Error and pw.ErrorID == 0
    st["rst"] = False
    drive.set_io_invalid(0, True)  # a disabled axis: 0x4655 after 3 cycles of invalid I/O data
    rig.run_until(lambda: pw.Error, 5)
    assert ax.NcToPlc.ErrorCode == ErrorCodes.NC_DRIVE_IO_DATA_INVALID and pw.ErrorID == 0x4655 and not pw.Busy
    drive.set_io_invalid(0, False)
    st["rst"] = True
    rig.run_until(lambda: rst.Done, 20)
    rig.run(1)
    assert not pw.Error


def _claimed_power(nc: ScriptNc) -> tuple[MC_Power, dict[str, Any], dict[str, int]]:
    """MC_Power on the scripted NC's axis, its inputs ``st`` (changed by the test); every Claim is answered with
    ``claim['error']`` (0: accepted) in the cycle after it went out."""
    pw = MC_Power()
    st: dict[str, Any] = {"Enable": True}
    claim = {"error": 0}
    answered: set[int] = set()

    def call() -> None:
        pw(Axis=nc.ax, **st)
        for p in nc.port.sent:
            if p.cmd == "Claim" and id(p) not in answered:
                answered.add(id(p))
                nc.port.answer(p, error=claim["error"], cycle=nc.nc_cycle)

    nc.calls.append(call)
    nc.cycle_once(2)
    assert pw.Active and pw.Status and not pw.Error
    return pw, st, claim


def test_power_error_is_the_axis_error_code_of_the_frame(nc: ScriptNc) -> None:
    """The wire contract: the StateDWord Error bit decides, ErrorID = NCTOPLC.ErrorCode (0x4B09 if a frame had the
    bit without a code), with Enable TRUE or FALSE; Status FALSE meanwhile; gone with the first frame without it."""
    pw, st, claim = _claimed_power(nc)
    nc.state(IDLE | int(StateDWord.Error), ErrorCode=ErrorCodes.NC_POSITION_LAG)
    nc.cycle_once()
    assert (pw.Error, pw.ErrorID, pw.Status, pw.Busy, pw.Active) == (True, 0x4550, False, True, True)
    st["Enable"] = False
    nc.cycle_once()
    assert (pw.Error, pw.ErrorID, pw.Status, pw.Busy, pw.Active) == (True, 0x4550, False, False, False)
    nc.state(IDLE | int(StateDWord.Error), ErrorCode=0)  # (not this NC's frames: the bit alone)
    nc.cycle_once()
    assert pw.Error and pw.ErrorID == ErrorCodes.MC_AXIS_NOT_READY
    nc.state(IDLE, ErrorCode=0x4550)  # (nor this: a code without the bit) the bit decides
    nc.cycle_once()
    assert not pw.Error and pw.ErrorID == 0
    st["Enable"] = True  # the same two with Enable TRUE (the rising edge claims again: answered in the next cycle)
    nc.state(IDLE | int(StateDWord.Error), ErrorCode=0)
    nc.cycle_once(2)
    assert (pw.Error, pw.ErrorID, pw.Status, pw.Active) == (True, ErrorCodes.MC_AXIS_NOT_READY, False, True)
    nc.state(IDLE, ErrorCode=0x4550)
    nc.cycle_once()
    assert (pw.Error, pw.ErrorID, pw.Status, pw.Active) == (False, 0, True, True)
    nc.state(IDLE | int(StateDWord.Error), ErrorCode=0x4650)
    nc.cycle_once()
    assert pw.Error and pw.ErrorID == 0x4650 and not pw.Status
    nc.state(IDLE, ErrorCode=0)  # reset
    nc.cycle_once()
    assert not pw.Error and pw.ErrorID == 0 and pw.Status


def test_power_own_errors_take_precedence_over_the_axis_error(nc: ScriptNc) -> None:
    """Override out of range (0x4B06), BufferMode (0x4B64), stale data (0x4B0F), a refused claim (0x723): the block's
    own error shows while the axis has an error too; the axis's shows again once the block's is gone. With Enable
    FALSE and stale data no error at all (the block reports its own only while Enable; the axis's is unknown)."""
    pw, st, claim = _claimed_power(nc)
    nc.state(IDLE | int(StateDWord.Error), ErrorCode=0x4550)
    nc.cycle_once()
    assert pw.ErrorID == 0x4550
    for name, bad, good, code in (("Override", 150.0, 100.0, ErrorCodes.MC_PARAMETER_NOT_CORRECT),
                                  ("BufferMode", 1, 0, ErrorCodes.MC_BUFFERMODE_NOT_SUPPORTED)):
        st[name] = bad
        nc.cycle_once()
        assert pw.Error and pw.ErrorID == code, name
        st[name] = good
        nc.cycle_once()
        assert pw.Error and pw.ErrorID == 0x4550, name
    cycle, recs, index, jobs = nc._frames["nc1"]
    take = nc._take_frames
    nc._take_frames = lambda: None  # type: ignore[method-assign]  # no newer frame: the data turns stale
    nc.cycle_once(nc.stale_cycles + 1)
    assert not nc.ax.Status.Valid
    assert pw.Error and pw.ErrorID == ErrorCodes.MC_NO_NC_CYCLE_UPDATE
    st["Enable"] = False
    nc.cycle_once()
    assert not pw.Error and pw.ErrorID == 0, "Enable FALSE on stale data: no error known"
    st["Enable"] = True
    nc._take_frames = take  # type: ignore[method-assign]
    nc.cycle_once()
    assert pw.Error and pw.ErrorID == 0x4550
    # the claim refused (another client took the axis: the NC says 0x723) while the axis has its error
    claim["error"] = ErrorCodes.ADSERR_DEVICE_ACCESSDENIED
    st["Enable"] = False
    nc.cycle_once()
    st["Enable"] = True  # (the rising edge claims again)
    nc.cycle_once(2)
    assert not pw.Active and pw.Error and pw.ErrorID == 0x723
    st["Enable"] = False  # a refused claim is no error while disabled: the axis's shows
    nc.cycle_once()
    assert pw.Error and pw.ErrorID == 0x4550


def test_a_refused_claim_stays_an_error_while_it_is_retried(nc: ScriptNc) -> None:
    """A refused claim is retried every claim_retry s while Enable stays TRUE; the refusal (0x723) stays on Error/
    ErrorID while each retry is on its way, until the NC's answer changes it: no drop to no error (or to the axis's
    error) for every retry's round trip. Once a retry is granted: Active, and the axis's error shows."""
    pw, st, claim = _claimed_power(nc)
    claim["error"] = ErrorCodes.ADSERR_DEVICE_ACCESSDENIED  # another client took the axis
    st["Enable"] = False
    nc.cycle_once()
    st["Enable"] = True  # (the rising edge claims again: refused)
    nc.cycle_once(2)
    assert pw.Error and pw.ErrorID == 0x723 and not pw.Active

    def watch(cycles: int) -> tuple[set[tuple[bool, int, bool]], int]:
        """The (Error, ErrorID, Active) seen after each of ``cycles`` cycles, and the Claims sent meanwhile."""
        sent = sum(p.cmd == "Claim" for p in nc.port.sent)
        seen = set()
        for _ in range(cycles):
            nc.cycle_once()
            seen.add((pw.Error, pw.ErrorID, pw.Active))
        return seen, sum(p.cmd == "Claim" for p in nc.port.sent) - sent

    retries = round(2.5 * nc.claim_retry / nc.cycle_time)
    seen, claims = watch(retries)
    assert claims >= 2, "retried every claim_retry"
    assert seen == {(True, 0x723, False)}, "no error for a retry's round trip"
    nc.state(IDLE | int(StateDWord.Error), ErrorCode=0x4550)  # with an axis error: 0x723 every cycle still
    seen, claims = watch(retries)
    assert claims >= 2 and seen == {(True, 0x723, False)}, "not 0x723 <-> 0x4550"
    claim["error"] = 0  # the other client let go: the next retry is granted
    for _ in range(retries):  # (a deadline: 2.5 retry periods)
        nc.cycle_once()
        if pw.Active:
            break
        assert pw.Error and pw.ErrorID == 0x723
    assert pw.Active and pw.Error and pw.ErrorID == 0x4550 and not pw.Status
