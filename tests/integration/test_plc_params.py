"""The parameter blocks, MC_ReadParameterSet / MC_ReadAxisComponents and MC_PowerStepper through real
``nc-server`` and ``plc-run`` processes (commands as zenoh queries, status as the NC's frames); the simulated
stepper is stalled from a separate zenoh client (SimStall)."""
from __future__ import annotations

import math
from typing import Callable

from nc_schema import decode_parameter_set, encode_parameter_set
from nc_server.server import config as server_config
from znc_testing.plc_harness import NC_ARGS, T, PlcProcess, power_on
from znc_testing import NcServerProcess, NcTestClient


def test_read_and_write_parameters(plc: PlcProcess) -> None:
    power_on(plc)
    plc.set("rp", "MC_ReadParameter", Enable=True, ParameterNumber=1003)
    r = plc.wait("rp", lambda r: r.o["Done"], T)
    assert r.o["Value"] == 500.0 and not r.o["Error"]  # AxisVeloMax of axis 1 in the default config
    plc.set("rb", "MC_ReadBoolParameter", Enable=True, ParameterNumber=1015)
    assert plc.wait("rb", lambda r: r.o["Done"], T).o["Value"] is True
    plc.set("cyc", "MC_ReadParameter", Enable=True, ParameterNumber=1003, ReadMode=2)
    plc.wait("cyc", lambda r: r.o["Done"] and r.o["Value"] == 500.0, T)
    plc.set("wp", "MC_WriteParameter", Enable=True, ParameterNumber=1003, Value=300.0)
    plc.wait("wp", lambda r: r.o["Done"], T)
    plc.wait("cyc", lambda r: r.o["Value"] == 300.0, T)
    plc.set("wp", Value=350.0)  # Enable stays TRUE: written again
    plc.wait("cyc", lambda r: r.o["Value"] == 350.0, T)
    # refusals with the TwinCAT codes
    plc.set("ro", "MC_WriteParameter", Enable=True, ParameterNumber=1000, Value=7.0)
    assert plc.wait("ro", lambda r: r.o["Error"], T).o["ErrorID"] == 0x704
    plc.set("unk", "MC_ReadParameter", Enable=True, ParameterNumber=4711)
    assert plc.wait("unk", lambda r: r.o["Error"], T).o["ErrorID"] == 0x703
    plc.set("typ", "MC_ReadBoolParameter", Enable=True, ParameterNumber=1003)
    assert plc.wait("typ", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4B05
    # while moving: a maximum velocity below the running one would break the profile
    plc.set("mv", "MC_MoveVelocity", Execute=True, Velocity=100.0, Direction=1)
    plc.wait("mv", lambda r: r.o["InVelocity"], T)
    plc.set("slow", "MC_WriteParameter", Execute=True, ParameterNumber=1003, Value=50.0)
    assert plc.wait("slow", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4221
    plc.set("halt", "MC_Halt", Execute=True)
    plc.wait("halt", lambda r: r.o["Done"], T)
    plc.edge("slow")
    plc.wait("slow", lambda r: r.o["Done"], T)
    plc.wait("cyc", lambda r: r.o["Value"] == 50.0, T)


def test_read_parameter_set_and_components(plc: PlcProcess) -> None:
    plc.set("rps", "MC_ReadParameterSet", axis=3, Execute=True)
    plc.wait("rps", lambda r: r.o["Done"], T)
    ps = plc.get("rps", "Parameter")
    assert ps["AxisId"] == 3 and ps["sAxisName"] == "Z" and ps["fVeloMaximum"] == 250.0
    assert ps["bEncEnableSoftEndMaxControl"] == 1 and ps["fEncSoftEndMax"] == 5.0 and ps["fAxisCycleTime"] == 0.001
    raw = encode_parameter_set(ps)
    assert len(raw) == 1024 and decode_parameter_set(raw) == ps
    plc.set("rac", "MC_ReadAxisComponents", axis=3, Execute=True)
    plc.wait("rac", lambda r: r.o["Done"], T)
    c = plc.get("rac", "AxisComponents")
    assert c == {"EncoderIDs": [3] + [0] * 8, "ControllerIDs": [3] + [0] * 8, "DriveIDs": [3] + [0] * 8}


def _stepper_config() -> str:
    text = server_config.default_config_text()
    head, sep, rest = text.partition('Name = "X"\n')
    assert sep, "default.toml changed: axis 1 is no longer X"
    extra = ("SimStepper = true\nAxisEnPositionLagMonitoring = false\nSimTimeConstant = 0.01\n"
             "AxisMaxPosLagFilterTime = 0.05\nAxisMaxPosLagValue = 1.0\n")
    rest = rest.replace("AxisMaxPosLagValue = 5.0\n", "", 1)
    return head + sep + extra + rest


def test_power_stepper_destalls_with_the_override_and_reports_errors(
        start_nc: Callable[..., NcServerProcess], nc_client: Callable[..., NcTestClient]) -> None:
    nc = start_nc(config_text=_stepper_config(), extra_args=NC_ARGS)
    cl = nc_client(nc.port)
    with PlcProcess(nc.endpoint, "plc-a") as plc:
        plc.wait_started()
        params = {"DestallDetectMode": 2, "DestallMode": 3, "DestallEnable": True, "StatusMonEnable": True}
        plc.set("ps", "MC_PowerStepper", Enable=True, Enable_Positive=True, Enable_Negative=True,
                DestallParams=params)
        plc.wait("ps", lambda r: r.o["Status"], T)
        plc.set("err", "MC_ReadAxisError", Enable=True)
        plc.trace(axis=1)
        plc.set("mv", "MC_MoveAbsolute", Execute=True, Position=200.0, Velocity=50.0)
        plc.wait("mv", lambda r: r.o["Active"], T)
        plc.wait_trace(1, lambda r: r.a["ActPos"] > 20.0, T)
        assert cl.request("SimStall", axis=1, Stall=True)["error"] == 0
        # UseOverride: the profile halts (override 0), the motor latches in and catches up, the profile ends
        done = plc.wait("mv", lambda r: r.o["Done"] or r.o["Error"] or r.o["CommandAborted"], T)
        assert done.o["Done"] and math.isclose(done.a["ActPos"], 200.0, abs_tol=0.05), done
        assert not any(r.o["Error"] for r in plc.history("ps"))
        assert any(r.a["SetVelo"] == 0.0 and r.a["ActPos"] < 199.0 for r in plc.trace_of(1)), "it was halted"
        # SetError: a stall becomes the axis error 0x4636
        params["DestallMode"] = 1
        plc.set("ps", DestallParams=params)
        plc.set("mv2", "MC_MoveAbsolute", Execute=True, Position=0.0, Velocity=50.0)
        plc.wait("mv2", lambda r: r.o["Active"], T)
        plc.wait_trace(1, lambda r: r.a["ActPos"] < 180.0, T)
        assert cl.request("SimStall", axis=1, Stall=True)["error"] == 0
        assert plc.wait("ps", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4636
        assert plc.wait("err", lambda r: r.o["AxisErrorID"] != 0, T).o["AxisErrorID"] == 0x4636
        assert plc.wait("mv2", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4636
        plc.set("rst", "MC_Reset", Execute=True)
        plc.wait("rst", lambda r: r.o["Done"], T)
        plc.wait("ps", lambda r: not r.o["Error"] and r.o["Status"], T)
        # status monitoring: a terminal error (overtemperature) is reported to the NC
        assert cl.request("SimTerminalError", axis=1, StatusWord=1 << 3)["error"] == 0
        assert plc.wait("ps", lambda r: r.o["Error"], T).o["ErrorID"] == 0x4630
        plc.wait("err", lambda r: r.o["AxisErrorID"] == 0x4630, T)
        assert any("MC_PowerStepper(AxId:=1) reporting error 0x4636 (stall error)!" in line for line in plc.err_lines)
