"""MC_Home: against the wire contract (a scripted NC: the request, the cam bit, the Done rule),
then against the real NcCore (motion engine): a reference cam simulated from the axis position,
HomingState 1..6 then 0, Homed, the final position; the no-cam recipe; the modes without motion;
refusals."""
from __future__ import annotations

import math
from typing import Any

import pytest

from nc_schema import DEFAULT_HOME_POSITION, ControlDWord, ErrorCodes, MC_HomingMode, StateDWord
from nc_server.core import AxisParams
from plc_client import MC_Home, MC_MoveVelocity, MC_Stop
from znc_testing.plc_rig import ABORTED, ACTIVE, DONE, IDLE, MOVING, Rig, ScriptNc, powered

HOMED = int(StateDWord.Homed)
_CAM_BIT = int(ControlDWord.HomingSensor)
HOMING = MOVING | int(StateDWord.HomingBusy)


# ---- against the contract (scripted NC) -------------------------------------------------------------
def test_contract_request_cam_bit_and_done(nc: ScriptNc) -> None:
    home = MC_Home()
    nc.watched.append(home)
    st = {"ex": False, "cam": True}
    nc.calls.append(lambda: home(Axis=nc.ax, Execute=st["ex"], bCalibrationCam=st["cam"]))
    nc.cycle_once()
    assert int(nc.ax.PlcToNc["ControlDWord"]) & _CAM_BIT, "written while idle too"
    st["cam"] = False
    nc.cycle_once()
    assert not int(nc.ax.PlcToNc["ControlDWord"]) & _CAM_BIT
    st["ex"] = True
    nc.cycle_once()
    p = nc.last_sent("Home")
    assert p.args == {"Position": DEFAULT_HOME_POSITION, "HomingMode": 0, "BufferMode": 0}
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=5)
    nc.state(HOMING, HomingState=1)
    nc.set_jobs(active=(5, ACTIVE))
    nc.cycle_once()
    assert home.Busy and home.Active
    st["cam"] = True
    nc.state(HOMING, HomingState=3)
    nc.cycle_once()
    assert int(nc.ax.PlcToNc["ControlDWord"]) & _CAM_BIT and home.Active
    # logical end, but HomingState not yet 0: wait
    nc.job_done(5, HomingState=6)
    nc.cycle_once()
    assert home.Busy and not home.Done
    nc.state(IDLE | HOMED, HomingState=0)
    nc.cycle_once()
    assert home.Done and not home.Busy and not home.Active


def test_contract_done_without_homed_times_out(nc: ScriptNc) -> None:
    home = MC_Home()
    nc.watched.append(home)
    nc.calls.append(lambda: home(Axis=nc.ax, Execute=True, Position=3.0, HomingMode=4))
    nc.cycle_once()
    p = nc.last_sent("Home")
    assert p.args == {"Position": 3.0, "HomingMode": 4, "BufferMode": 0}
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=5)
    nc.job_done(5, HomingState=0)  # DONE, but the NC did not set Homed
    nc.cycle_once(300)
    assert home.Busy
    nc.cycle_once(301)
    assert home.Error and home.ErrorID == ErrorCodes.MC_HOMING_ERROR


def test_contract_reset_calibration_done_without_homed_and_aborted(nc: ScriptNc) -> None:
    home, other = MC_Home(), MC_Home()
    nc.watched += [home, other]
    nc.calls.append(lambda: home(Axis=nc.ax, Execute=True, HomingMode=8, BufferMode=1))
    nc.cycle_once()
    p = nc.last_sent("Home")
    assert p.args["HomingMode"] == 8 and p.args["BufferMode"] == 1
    nc.port.answer(p, cycle=nc.nc_cycle, cmdno=5)
    nc.job_done(5, HomingState=0)
    nc.cycle_once()
    assert home.Done
    nc.calls.append(lambda: other(Axis=nc.ax, Execute=True))
    nc.cycle_once()
    nc.port.answer(nc.last_sent("Home"), cycle=nc.nc_cycle, cmdno=6)
    nc.state(HOMING, HomingState=2)
    nc.set_jobs(active=(6, ACTIVE), ended=((5, DONE, 0),))
    nc.cycle_once()
    nc.state(MOVING | int(StateDWord.MotionCommandsLocked), HomingState=0)
    nc.set_jobs(active=(7, ACTIVE), ended=((6, ABORTED, 0), (5, DONE, 0)))  # an MC_Stop
    nc.cycle_once()
    assert other.CommandAborted and not other.Busy


# ---- against the real NC ------------------------------------------------------------------------------
CAM_AT = -3.5        #: the cam is occupied below this position (the search runs in negative direction)


def record_nc_steps(rig: Rig, axis_id: int = 1) -> list[tuple[int, float, bool]]:
    """(HomingState, ActPos, Homed) after every NC step (the PLC samples only every 10th)."""
    seen: list[tuple[int, float, bool]] = []
    step = rig.core.step

    def recording_step(*a: Any, **k: Any) -> None:
        step(*a, **k)
        r = rig.rec(axis_id)
        seen.append((int(r["HomingState"]), float(r["ActPos"]), bool(int(r["StateDWord"]) & 2)))

    rig.core.step = recording_step  # type: ignore[method-assign]
    return seen


def dedup(values: list[int]) -> list[int]:
    out: list[int] = []
    for v in values:
        if not out or out[-1] != v:
            out.append(v)
    return out


@pytest.mark.parametrize("position", [100.0, DEFAULT_HOME_POSITION])
def test_homing_with_a_cam(rig: Rig, position: float) -> None:
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    seen = record_nc_steps(rig)
    calls["body"] = lambda p: home(Axis=ax, Execute=True, Position=position, bCalibrationCam=ax.ActPos < CAM_AT)
    rig.run(1)
    assert home.Busy and not home.Active
    rig.run_until(lambda: home.Active, 5)
    assert ax.Status.Homing and ax.Status.HomingBusy
    rig.run_until(lambda: not home.Busy, 2000)
    assert home.Done, f"ErrorID 0x{home.ErrorID:X}"
    states = dedup([s for s, _, _ in seen])
    assert states == [0, 1, 2, 3, 4, 5, 6, 0] or states == [1, 2, 3, 4, 5, 6, 0], states
    assert min(p for _, p, _ in seen) < CAM_AT, "the search went to the cam in negative direction"
    ref = AxisParams().AxisCalibrationValue if position == DEFAULT_HOME_POSITION else position
    st = ax.Status
    assert st.Homed and not st.HomingBusy and st.StandStill and int(ax.NcToPlc["HomingState"]) == 0
    # the sync pulse after leaving the cam (positive direction) is at -3.0 (pulses every 1 u at 0):
    # the latch there became the reference position; the axis stands a braking distance beyond it
    before = [p for s, p, _ in seen if s == 6][-1]  # last old-coordinate position before the set
    assert before > -3.0
    assert math.isclose(ax.ActPos, ref + (before - (-3.0)), abs_tol=0.01)
    assert 0.0 <= ax.ActPos - ref < 0.2  # the braking distance from AxisCalibrationVelocityBackward (5 u/s)
    rig.run(10)
    assert home.Done, "Done held while Execute stays TRUE"


def test_homing_without_cam_recipe(rig: Rig) -> None:
    """TcMC 3.14 note: cam TRUE first, FALSE once HomingState >= 4: homing on the sync pulse alone."""
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    seen = record_nc_steps(rig)
    st = {"ex": False}

    def body(p: Any) -> None:
        cam = int(ax.NcToPlc["HomingState"]) < 4 if home.Busy else True
        home(Axis=ax, Execute=st["ex"], Position=10.0, bCalibrationCam=cam)

    calls["body"] = body
    rig.run(2)  # the cam first (it reaches the NC with this PLC's PLCTONC frames) ...
    st["ex"] = True  # ... then the command
    rig.run_until(lambda: not home.Busy, 2000)
    assert home.Done and ax.Status.Homed
    states = dedup([s for s, _, _ in seen])
    # the cam was occupied at the start: straight to 3 (at rest, 3 - "wait until stopped" - may pass
    # within the command's own cycle and never show in a frame), no search (1, 2)
    assert states in ([0, 3, 4, 5, 6, 0], [0, 4, 5, 6, 0]), states
    assert min(p for _, p, _ in seen) >= -1e-9, "no search towards the cam: off it towards the sync pulse"
    assert 0.0 <= ax.ActPos - 10.0 < 0.2


def test_cam_bit_written_every_cycle(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    home = MC_Home()
    st = {"cam": False}
    calls["body"] = lambda p: home(Axis=ax, Execute=False, bCalibrationCam=st["cam"])
    rig.run(2)
    assert not int(ax.PlcToNc["ControlDWord"]) & _CAM_BIT
    st["cam"] = True
    rig.run(2)
    cdw = int(ax.PlcToNc["ControlDWord"])
    assert cdw & _CAM_BIT and cdw & int(ControlDWord.Enable), "MC_Power keeps the cam bit, the cam keeps Enable"
    assert int(rig.core.plctonc["ControlDWord"][0]) & _CAM_BIT, "the NC applies it (this PLC holds the axis)"
    st["cam"] = False
    rig.run(2)
    assert not int(rig.core.plctonc["ControlDWord"][0]) & _CAM_BIT


@pytest.mark.parametrize("mode, homed_before, homed_after, pos_after", [
    (MC_HomingMode.MC_Direct, False, True, 42.0),
    (MC_HomingMode.MC_ForceCalibration, False, True, 0.0),
    (MC_HomingMode.MC_ResetCalibration, True, False, 0.0),
])
def test_modes_without_motion(mode: int, homed_before: bool, homed_after: bool, pos_after: float) -> None:
    rig = Rig(params=AxisParams(Homed=homed_before))
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    calls["body"] = lambda p: home(Axis=ax, Execute=True, Position=42.0, HomingMode=int(mode))
    rig.run_until(lambda: not home.Busy, 50)
    assert home.Done, f"ErrorID 0x{home.ErrorID:X}"
    assert ax.Status.Homed is homed_after
    assert math.isclose(ax.ActPos, pos_after, abs_tol=1e-6)
    assert ax.Status.StandStill


def test_home_refused_on_a_moving_axis(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, home = rig.watch(MC_MoveVelocity(), MC_Home())
    st = {"home": False}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Velocity=20.0)
        home(Axis=ax, Execute=st["home"])

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 100)
    st["home"] = True
    rig.run_until(lambda: not home.Busy, 5)
    assert home.Error and home.ErrorID == ErrorCodes.MC_AXIS_CANNOT_BE_STARTED
    assert ax.Status.ContinuousMotion, "the refused Home does not touch the running motion"


def test_home_refused_on_a_disabled_axis() -> None:
    rig = Rig()
    plc = rig.plc("plc1")
    ax = plc.axis("nc1", 1)
    home = rig.watch(MC_Home())
    plc.program = lambda p: home(Axis=ax, Execute=True)
    rig.run_until(lambda: not home.Busy, 5)
    assert home.Error and home.ErrorID in (ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, ErrorCodes.NC_NO_ENABLE)
    assert not ax.Status.Homed


def test_stop_aborts_homing(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    home, stop = rig.watch(MC_Home(), MC_Stop())
    st = {"stop": False}

    def body(p: Any) -> None:
        home(Axis=ax, Execute=True, bCalibrationCam=ax.ActPos < CAM_AT)
        stop(Axis=ax, Execute=st["stop"])

    calls["body"] = body
    rig.run_until(lambda: home.Active, 5)
    rig.run(5)
    st["stop"] = True
    rig.run_until(lambda: home.CommandAborted, 10)
    assert not home.Busy and not home.Active
    rig.run_until(lambda: stop.Done, 100)
    assert not ax.Status.Homed and int(ax.NcToPlc["HomingState"]) == 0


def test_invalid_homing_mode_type(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    home = rig.watch(MC_Home())
    before = int(rig.rec()["CmdNo"])
    calls["body"] = lambda p: home(Axis=ax, Execute=True, HomingMode="direct")
    rig.run(1)
    assert home.Error and home.ErrorID == ErrorCodes.MC_INVALID_MODE
    rig.run(2)
    assert int(rig.rec()["CmdNo"]) == before
