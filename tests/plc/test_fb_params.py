"""The parameter blocks (TcMC 4.6-4.11) and MC_ReadParameterSet / MC_ReadAxisComponents: against a real
NcCore (Rig) and a scripted NC (ScriptNc: what the block sends, timeouts, refusals)."""
from __future__ import annotations

import math

import pytest

from nc_schema import ErrorCodes as E, OpModeDWord, encode_parameter_set
from plc_client import (
    E_ReadMode, MC_ReadAxisComponents, MC_ReadBoolParameter, MC_ReadParameter, MC_ReadParameterSet,
    MC_WriteBoolParameter, MC_WriteParameter, ST_AxisComponents, ST_AxisParameterSet,
)
from znc_testing.plc_rig import Rig, ScriptNc, powered


def _program(rig: Rig, calls: dict) -> None:
    plc = rig.plc()
    ax = plc.axis("nc1", 1)
    calls["ax"] = ax
    plc.program = lambda p: [f(ax) for f in list(calls.get("fbs", []))]


# ---- MC_ReadParameter / MC_ReadBoolParameter --------------------------------------------------------------------
def test_read_parameter_once(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    rp = MC_ReadParameter()
    st = {"en": True, "n": 1003}
    calls["body"] = lambda p: rp(Axis=ax, Enable=st["en"], ParameterNumber=st["n"])
    rig.run_until(lambda: rp.Done, 10)
    assert rp.Value == 1000.0 and not rp.Error and rp.ErrorID == 0 and isinstance(rp.Value, float)
    st["n"] = 1001  # ReadMode_Once: latched on the rising edge, not read again
    rig.run(5)
    assert rp.Done and rp.Value == 1000.0
    st["en"] = False
    rig.run(1)
    assert not rp.Done and not rp.Error and rp.Value == 1000.0, "Enable FALSE keeps the last value"
    st["en"] = True
    rig.run_until(lambda: rp.Done, 10)
    assert rp.Value == 50.0  # AxisVeloManSlow


def test_read_parameter_cyclic_follows_writes(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    rp, wp = MC_ReadParameter(), MC_WriteParameter()
    st = {"v": 300.0, "w": False}
    calls["body"] = lambda p: (rp(Axis=ax, Enable=True, ParameterNumber=1003, ReadMode=E_ReadMode.ReadMode_Cyclic),
                               wp(Axis=ax, Enable=st["w"], ParameterNumber=1003, Value=st["v"]))
    rig.run_until(lambda: rp.Done, 10)
    assert rp.Value == 1000.0
    st["w"] = True
    rig.run_until(lambda: wp.Done, 10)
    rig.run_until(lambda: rp.Value == 300.0, 10)
    assert rp.Done and not rp.Error
    st["v"] = 400.0  # Enable stays TRUE: the new value is written, the cyclic read follows
    rig.run_until(lambda: rp.Value == 400.0, 20)
    assert wp.Done and rig.core.params[0].AxisVeloMax == 400.0


def test_read_errors(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    unknown, mode, boolp, notint = MC_ReadParameter(), MC_ReadParameter(), MC_ReadBoolParameter(), MC_ReadParameter()
    calls["body"] = lambda p: (unknown(Axis=ax, Enable=True, ParameterNumber=4711),
                               mode(Axis=ax, Enable=True, ParameterNumber=1003, ReadMode=3),
                               boolp(Axis=ax, Enable=True, ParameterNumber=1003),
                               notint(Axis=ax, Enable=True, ParameterNumber=1003.0))
    rig.run(3)
    assert unknown.Error and unknown.ErrorID == E.ADSERR_DEVICE_INVALIDOFFSET and not unknown.Done
    assert mode.Error and mode.ErrorID == E.MC_INVALID_MODE
    assert boolp.Error and boolp.ErrorID == E.MC_COMMAND_NOT_PERMITTED == 0x4B05
    assert notint.Error and notint.ErrorID == E.MC_PARAMETER_NOT_CORRECT


def test_read_bool_parameter(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    rb, rl = MC_ReadBoolParameter(), MC_ReadParameter()
    calls["body"] = lambda p: (rb(Axis=ax, Enable=True, ParameterNumber=1022), rl(Axis=ax, Enable=True, ParameterNumber=1022))
    rig.run_until(lambda: rb.Done, 10)
    assert rb.Value is True
    assert rl.Error and rl.ErrorID == 0x4B05, "MC_ReadParameter on a BOOL parameter: the types do not coincide"


def test_read_once_sends_one_request_cyclic_one_at_a_time(nc: ScriptNc) -> None:
    once, cyc = MC_ReadParameter(), MC_ReadParameter()
    nc.calls.append(lambda: once(Axis=nc.ax, Enable=True, ParameterNumber=1003))
    nc.cycle_once()
    p = nc.last_sent("ReadParameter")
    assert p.args == {"ParameterNumber": 1003}
    nc.port.answer(p, cycle=nc.nc_cycle, value=250.0)
    nc.cycle_once(3)
    assert once.Done and once.Value == 250.0
    assert len([q for q in nc.port.sent if q.cmd == "ReadParameter"]) == 1
    nc.calls.append(lambda: cyc(Axis=nc.ax, Enable=True, ParameterNumber=1004, ReadMode=2))
    nc.cycle_once(3)
    mine = [q for q in nc.port.sent if q.cmd == "ReadParameter" and q.args["ParameterNumber"] == 1004]
    assert len(mine) == 1, "one request outstanding at a time"
    nc.port.answer(mine[0], cycle=nc.nc_cycle, value=1.0)
    nc.cycle_once(2)
    mine = [q for q in nc.port.sent if q.cmd == "ReadParameter" and q.args["ParameterNumber"] == 1004]
    assert cyc.Done and cyc.Value == 1.0 and len(mine) == 2
    nc.port.answer(mine[1], error=E.ADSERR_DEVICE_INVALIDOFFSET, cycle=nc.nc_cycle)
    nc.cycle_once(2)
    assert cyc.Error and not cyc.Done and cyc.ErrorID == 0x703
    mine = [q for q in nc.port.sent if q.cmd == "ReadParameter" and q.args["ParameterNumber"] == 1004]
    nc.port.answer(mine[-1], cycle=nc.nc_cycle, value=2.0)
    nc.cycle_once(2)
    assert cyc.Done and not cyc.Error and cyc.Value == 2.0, "a cyclic read recovers by itself"


def test_read_timeout_and_stale_data(nc: ScriptNc) -> None:
    rp = MC_ReadParameter(timeout=0.05)
    nc.calls.append(lambda: rp(Axis=nc.ax, Enable=True, ParameterNumber=1003))
    nc.cycle_once(10)
    assert rp.Error and rp.ErrorID == E.ADSERR_CLIENT_SYNCTIMEOUT
    frozen = nc.nc_cycle
    for _ in range(30):  # the NC's frames stop advancing: the data goes stale
        nc.step()
        nc.nc_cycle = frozen
    assert not nc.ax.Status.Valid
    stale = MC_ReadParameter()
    nc.calls.append(lambda: stale(Axis=nc.ax, Enable=True, ParameterNumber=1003))
    n = len(nc.port.sent)
    nc.step()
    assert stale.Error and stale.ErrorID == E.MC_NO_NC_CYCLE_UPDATE and len(nc.port.sent) == n


# ---- MC_WriteParameter / MC_WriteBoolParameter ------------------------------------------------------------------
def test_write_parameter_enable_and_its_effect(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    wb = MC_WriteBoolParameter()
    bit = int(OpModeDWord.OpModePosAreaMonitoring)
    assert int(ax.NcToPlc["OpModeDWord"]) & bit
    st = {"en": True}
    seen = []
    calls["body"] = lambda p: (wb(Axis=ax, Enable=st["en"], ParameterNumber=1022, Value=False),
                               seen.append((wb.Done, int(ax.NcToPlc["OpModeDWord"]) & bit)))
    rig.run_until(lambda: wb.Done, 10)
    assert all(not b for d, b in seen if d), "Done only when the frame shows the effect"
    rig.run(3)
    assert wb.Done and rig.core.params[0].AxisEnPositionRangeMonitoring is False
    st["en"] = False
    rig.run(1)
    assert not wb.Done and not wb.Error


def test_write_parameter_refusals(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    ro, rng, typ, nan, bv = (MC_WriteParameter(), MC_WriteParameter(), MC_WriteParameter(), MC_WriteParameter(),
                             MC_WriteBoolParameter())
    calls["body"] = lambda p: (ro(Axis=ax, Enable=True, ParameterNumber=1000, Value=5.0),
                               rng(Axis=ax, Enable=True, ParameterNumber=1003, Value=-1.0),
                               typ(Axis=ax, Enable=True, ParameterNumber=1015, Value=1.0),
                               nan(Axis=ax, Enable=True, ParameterNumber=1003, Value=math.nan),
                               bv(Axis=ax, Enable=True, ParameterNumber=1015, Value=1))
    rig.run(4)
    assert ro.Error and ro.ErrorID == E.ADSERR_DEVICE_INVALIDACCESS
    assert rng.Error and rng.ErrorID == E.ADSERR_DEVICE_INVALIDPARM
    assert typ.Error and typ.ErrorID == E.MC_COMMAND_NOT_PERMITTED
    assert nan.Error and nan.ErrorID == E.MC_PARAMETER_NOT_CORRECT
    assert bv.Error and bv.ErrorID == E.MC_PARAMETER_NOT_CORRECT  # an INT is not a BOOL
    assert rig.core.params[0].AxisVeloMax == 1000.0


def test_write_parameter_execute_edge(nc: ScriptNc) -> None:
    """Tc2_MC2's Execute: one write on the rising edge; Done for one cycle when Execute fell before."""
    wp = MC_WriteParameter()
    st = {"ex": True, "v": 10.0}
    nc.calls.append(lambda: wp(Axis=nc.ax, Execute=st["ex"], ParameterNumber=1001, Value=st["v"]))
    nc.watched.append(wp)
    nc.cycle_once()
    p = nc.last_sent("WriteParameter")
    assert p.args == {"ParameterNumber": 1001, "Value": 10.0} and wp.Busy
    st["v"] = 11.0  # no second write: the inputs were latched
    st["ex"] = False
    nc.cycle_once()
    nc.port.answer(p, cycle=nc.nc_cycle)
    nc.cycle_once(3)
    assert len([q for q in nc.port.sent if q.cmd == "WriteParameter"]) == 1
    assert nc.history(wp, "Done")[-4:] == [False, True, False, False], "Done for exactly one cycle"
    assert not wp.Busy
    st["ex"] = True
    nc.cycle_once()
    p2 = nc.last_sent("WriteParameter")
    assert p2.args["Value"] == 11.0
    nc.port.answer(p2, error=E.NC_VELOCITY_NOT_ALLOWED, cycle=nc.nc_cycle)
    nc.cycle_once(3)
    assert wp.Error and wp.ErrorID == 0x4221, "held while Execute stays TRUE"


def test_write_enable_writes_again_on_a_change_only(nc: ScriptNc) -> None:
    wp = MC_WriteParameter()
    st = {"v": 1.0}
    nc.calls.append(lambda: wp(Axis=nc.ax, Enable=True, ParameterNumber=1013, Value=st["v"]))
    nc.cycle_once()
    nc.port.answer(nc.last_sent("WriteParameter"), cycle=nc.nc_cycle)
    nc.cycle_once(5)
    assert wp.Done and len([q for q in nc.port.sent if q.cmd == "WriteParameter"]) == 1
    st["v"] = 2.0
    nc.cycle_once()
    assert not wp.Done and nc.last_sent("WriteParameter").args["Value"] == 2.0


# ---- MC_ReadParameterSet / MC_ReadAxisComponents ----------------------------------------------------------------
def test_read_parameter_set(rig: Rig) -> None:
    ax, _, calls = powered(rig)
    mine = ST_AxisParameterSet()
    rps, own = MC_ReadParameterSet(), MC_ReadParameterSet()
    calls["body"] = lambda p: (rps(Axis=ax, Execute=True, Parameter=mine), own(Axis=ax, Execute=True))
    rig.run_until(lambda: rps.Done and own.Done, 10)
    assert rps.Parameter is mine and not rps.Busy and not rps.Error
    assert mine.AxisId == 1 and mine.sAxisName == "A1" and mine.fVeloMaximum == 1000.0
    assert mine.fAcceleration == 5000.0 and mine.bEnablePositionAreaControl == 1 and mine.nEncType == 1
    assert own.Parameter == mine and own.Parameter is not mine
    raw = mine.to_bytes()
    assert len(raw) == 1024 and raw == encode_parameter_set(mine.as_dict())
    assert ST_AxisParameterSet.from_bytes(raw) == mine


def test_read_axis_components(rig: Rig) -> None:
    ax, _, calls = powered(rig, axis_id=2)
    rac = MC_ReadAxisComponents()
    calls["body"] = lambda p: rac(Axis=ax, Execute=True)
    rig.run_until(lambda: rac.Done, 10)
    c = rac.AxisComponents
    assert isinstance(c, ST_AxisComponents)
    assert c.EncoderIDs == [2] + [0] * 8 and c.ControllerIDs == [2] + [0] * 8 and c.DriveIDs == [2] + [0] * 8
    assert len(c.to_bytes()) == 108


def test_read_parameter_set_wrong_in_out_and_refusal(nc: ScriptNc) -> None:
    bad = MC_ReadParameterSet()
    nc.calls.append(lambda: bad(Axis=nc.ax, Execute=True, Parameter={"AxisId": 1}))
    nc.cycle_once()
    assert bad.Error and bad.ErrorID == E.MC_PARAMETER_NOT_CORRECT
    rps = MC_ReadParameterSet()
    nc.calls.append(lambda: rps(Axis=nc.ax, Execute=True))
    nc.cycle_once()
    nc.port.answer(nc.last_sent("ReadParameterSet"), error=E.NC_AXIS_ID_NOT_ALLOWED, cycle=nc.nc_cycle)
    nc.cycle_once(2)
    assert rps.Error and rps.ErrorID == 0x4012 and not rps.Busy


@pytest.mark.parametrize("fb", [MC_ReadParameter, MC_ReadBoolParameter, MC_WriteParameter, MC_WriteBoolParameter,
                                MC_ReadParameterSet, MC_ReadAxisComponents])
def test_unknown_input_is_a_program_bug(fb) -> None:
    with pytest.raises(TypeError):
        fb()(NoSuchInput=1)
