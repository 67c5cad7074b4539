"""MC_SetActualPosition, MC_SetActualPositionOnTheFly, MC_SetReferenceFlag: against the wire
contract (a scripted NC: requests, Done with the reply's cycle), then against the real NcCore;
F_GetVersionTcMC."""
from __future__ import annotations

import importlib.metadata
import math
from typing import Any

import pytest

from nc_schema import ErrorCodes
from plc_client import (
    F_GetVersionTcMC, MC_MoveRelative, MC_MoveVelocity, MC_SetActualPosition, MC_SetActualPositionOnTheFly,
    MC_SetReferenceFlag,
)
from znc_testing.plc_rig import Rig, ScriptNc, powered


# ---- against the contract (scripted NC) -------------------------------------------------------------
@pytest.mark.parametrize("fb, inputs, cmd, args", [
    (MC_SetActualPosition, {"Position": 12.5}, "SetActualPosition", {"Position": 12.5}),
    (MC_SetActualPositionOnTheFly, {"ActualPosition": 3.0, "PreviousPosition": 1.0}, "SetActualPositionOnTheFly",
     {"ActualPosition": 3.0, "PreviousPosition": 1.0}),
    (MC_SetReferenceFlag, {"ReferenceFlag": True}, "SetReferenceFlag", {"ReferenceFlag": True}),
])
def test_contract_request_and_done_with_the_replys_cycle(fb: type, inputs: dict, cmd: str, args: dict) -> None:
    nc = ScriptNc()
    nc.cycle_once()
    b = fb()
    nc.watched.append(b)
    st = {"ex": True}
    nc.calls.append(lambda: b(Axis=nc.ax, Execute=st["ex"], **inputs))
    nc.cycle_once()
    p = nc.last_sent(cmd)
    assert p.args == args
    nc.port.answer(p, cycle=nc.nc_cycle + 5)  # takes effect in a frame that has not arrived yet
    nc.cycle_once()
    assert b.Busy and not b.Done
    nc.cycle_once()
    assert b.Done and not b.Busy
    st["ex"] = False
    nc.cycle_once()
    assert not b.Done
    st["ex"] = True
    nc.cycle_once()
    nc.port.answer(nc.port.sent[-1], error=ErrorCodes.MC_AXIS_CANNOT_BE_STARTED, cycle=nc.nc_cycle)
    nc.cycle_once()
    assert b.Error and b.ErrorID == 0x4B01 and not b.Done


# ---- against the real NC ------------------------------------------------------------------------------
def test_set_actual_position_at_standstill(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    sp = rig.watch(MC_SetActualPosition())
    seen: dict = {}

    def body(p: Any) -> None:
        sp(Axis=ax, Execute=True, Position=50.0)
        if sp.Done and "pos" not in seen:
            seen["pos"] = ax.ActPos  # the effect is visible in the cycle Done appears

    calls["body"] = body
    rig.run(1)
    assert sp.Busy and not sp.Done
    rig.run_until(lambda: sp.Done, 5)
    assert math.isclose(seen["pos"], 50.0, abs_tol=1e-9)
    assert math.isclose(float(ax.NcToPlc["SetPos"]), 50.0, abs_tol=1e-9) and ax.Status.StandStill
    rig.run(5)
    assert sp.Done and not sp.CommandAborted
    calls["body"] = lambda p: sp(Axis=ax, Execute=False)
    rig.run(1)
    assert not sp.Done and "Busy" not in sp._OUTPUTS


def test_set_actual_position_refused_while_moving(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, sp = rig.watch(MC_MoveVelocity(), MC_SetActualPosition())
    st = {"sp": False}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Velocity=20.0)
        sp(Axis=ax, Execute=st["sp"], Position=0.0)

    calls["body"] = body
    rig.run_until(lambda: mv.InVelocity, 100)
    st["sp"] = True
    rig.run_until(lambda: not sp.Busy, 5)
    assert sp.Error and sp.ErrorID == ErrorCodes.MC_AXIS_CANNOT_BE_STARTED


def test_set_actual_position_on_the_fly_shifts_the_running_move(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mv, fly = rig.watch(MC_MoveRelative(), MC_SetActualPositionOnTheFly())
    st = {"fly": False}

    def body(p: Any) -> None:
        mv(Axis=ax, Execute=True, Distance=40.0, Velocity=50.0)
        fly(Axis=ax, Execute=st["fly"], ActualPosition=1000.0, PreviousPosition=0.0)

    calls["body"] = body
    rig.run_until(lambda: ax.ActPos > 10.0, 100)
    st["fly"] = True
    rig.run(1)
    assert fly.Busy
    rig.run_until(lambda: fly.Done, 5)
    assert ax.ActPos > 1000.0 and mv.Busy, "shifted by +1000 while the move goes on"
    rig.run_until(lambda: mv.Done, 300)
    assert math.isclose(ax.ActPos, 1040.0, abs_tol=0.02), "same distance, shifted end"


def test_set_actual_position_on_the_fly_at_rest_sets_the_position(rig: Rig) -> None:
    """schema/README.md: on an axis at rest SetActualPositionOnTheFly simply shifts the position."""
    ax, _, calls = powered(rig)
    fly = rig.watch(MC_SetActualPositionOnTheFly())
    before = ax.ActPos
    calls["body"] = lambda p: fly(Axis=ax, Execute=True, ActualPosition=5.0, PreviousPosition=0.0)
    rig.run_until(lambda: not fly.Busy, 5)
    assert fly.Done and not fly.Error
    assert math.isclose(ax.ActPos, before + 5.0, abs_tol=1e-6)


def test_set_reference_flag(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    ref = rig.watch(MC_SetReferenceFlag())
    st = {"ex": True, "flag": True}
    calls["body"] = lambda p: ref(Axis=ax, Execute=st["ex"], ReferenceFlag=st["flag"])
    assert not ax.Status.Homed
    rig.run_until(lambda: ref.Done, 5)
    assert ax.Status.Homed, "the Homed bit is visible when Done is"
    st.update(ex=False)
    rig.run(1)
    st.update(ex=True, flag=False)
    rig.run_until(lambda: ref.Done, 5)
    assert not ax.Status.Homed
    st.update(ex=False)
    rig.run(1)
    st.update(ex=True, flag=1)  # not a BOOL
    rig.run(1)
    assert ref.Error and ref.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT


def test_bad_values_and_timeout(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    sp = rig.watch(MC_SetActualPosition())
    st = {"ex": True, "pos": float("nan")}
    calls["body"] = lambda p: sp(Axis=ax, Execute=st["ex"], Position=st["pos"])
    rig.run(1)
    assert sp.Error and sp.ErrorID == ErrorCodes.MC_PARAMETER_NOT_CORRECT
    st.update(ex=False)
    rig.run(1)
    plc = rig.plcs["plc1"]
    plc.port.hold = True  # the NC executes, its replies never arrive
    st.update(ex=True, pos=7.0)
    rig.run_until(lambda: not sp.Busy, 200)
    assert sp.Error and sp.ErrorID == ErrorCodes.ADSERR_CLIENT_SYNCTIMEOUT
    plc.port.hold = False
    plc.port.release_held()
    rig.run(2)


def test_version() -> None:
    text = importlib.metadata.version("zenoh-nc")
    parts = [int("".join(c for c in x if c.isdigit()) or 0) for x in text.split(".")[:3]]
    assert [F_GetVersionTcMC(i) for i in (1, 2, 3)] == parts + [0] * (3 - len(parts))
    assert F_GetVersionTcMC(0) == 0 and F_GetVersionTcMC(4) == 0 and F_GetVersionTcMC(True) == 0


@pytest.mark.parametrize("fb", [MC_SetActualPosition, MC_SetActualPositionOnTheFly, MC_SetReferenceFlag])
def test_unknown_inputs_raise(fb: type) -> None:
    with pytest.raises(TypeError):
        fb()(Execute=True, Velocity=1.0)
