"""The in-process port runs nc-server's own request handler, claim table and watchdog."""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from nc_schema import ControlDWord, ErrorCodes, make_request
from nc_server.core import AxisConfig, NcCore
from nc_server.server.claims import ClaimTable
from nc_server.server.handler import CycleInputs, RequestHandler
from nc_sim import InProcessNc, InProcessPort, run_cycles
from plc_client import MC_MoveVelocity, MC_Power
from plc_client.port import PendingCommand
from znc_testing.plc_rig import Rig, powered

LOST = int(ErrorCodes.ZNC_CLIENT_LOST)
TIMEOUT = int(ErrorCodes.ZNC_PLCTONC_TIMEOUT)


def core2() -> NcCore:
    return NcCore([AxisConfig(AxisId=1), AxisConfig(AxisId=2)], cycle_time=0.001)


def reply(port: InProcessPort, p: PendingCommand) -> dict[str, Any]:
    port.poll()
    assert p.done and p.reply is not None
    return p.reply


def claimed(core: NcCore, client: str, override: int) -> tuple[InProcessPort, np.ndarray]:
    """A port of ``client`` holding axis 1, having published a PLCTONC with ControlDWord 7 and
    ``override``; returns the port and that record."""
    port = InProcessPort(core, client)
    assert reply(port, port.send("nc1", 1, "Claim"))["error"] == 0
    rec = np.zeros(1, dtype=core.plctonc.dtype)
    rec["ControlDWord"] = 7
    rec["Override"] = override
    port.publish_plctonc(np.array([1]), rec)
    return port, rec


def test_ports_of_one_core_share_the_servers_handler() -> None:
    core = core2()
    a, b = InProcessPort(core, "a"), InProcessPort(core, "b")
    assert a.server is b.server is InProcessNc.of(core)
    assert isinstance(a.server.handler, RequestHandler) and isinstance(a.claims, ClaimTable)
    assert isinstance(a.server.inputs, CycleInputs)
    assert a.claims.clients() == ["a", "b"]  # both are live clients
    with pytest.raises(ValueError):
        InProcessPort(core, "c", nc="other")  # the core answers as nc1
    with pytest.raises(ValueError):
        InProcessNc(core)  # one server side per core


def test_second_claim_refused_naming_the_holder_and_override_refused() -> None:
    core = core2()
    a, b = InProcessPort(core, "plc-a"), InProcessPort(core, "plc-b")
    assert reply(a, a.send("nc1", 1, "Claim"))["error"] == 0
    r = reply(b, b.send("nc1", 1, "Claim"))
    assert r["error"] == ErrorCodes.ADSERR_DEVICE_ACCESSDENIED == 0x723 and "'plc-a'" in r["text"]
    assert reply(b, b.send("nc1", 1, "SetOverride", Override=10.0))["error"] == 0x723
    assert reply(b, b.send("nc1", 1, "Release"))["error"] == 0x723
    assert reply(a, a.send("nc1", 1, "SetOverride", Override=10.0))["error"] == 0
    assert reply(b, b.send("nc1", 2, "SetOverride", Override=10.0))["error"] == 0  # unclaimed axis
    # Info: the server's map, with claims and clients
    v = reply(a, a.send("nc1", None, "Info"))["Value"]
    assert v["name"] == "nc1" and v["claims"] == {1: "plc-a"} and v["clients"] == ["plc-a", "plc-b"]
    assert v["timing"] == "in-process" and v["watchdog_timeout"] == 0.5
    # an axis command on the NC-level key: the server's 0x4012
    assert reply(a, a.send("nc1", None, "Reset"))["error"] == ErrorCodes.NC_AXIS_ID_NOT_ALLOWED


def test_release_resets_plctonc_to_default() -> None:
    core = core2()
    a, rec = claimed(core, "a", 500_000)
    assert int(core.plctonc["ControlDWord"][0]) == 7
    assert reply(a, a.send("nc1", 1, "Release"))["error"] == 0
    assert int(core.plctonc["ControlDWord"][0]) == 0 and int(core.plctonc["Override"][0]) == 1_000_000
    a.publish_plctonc(np.array([1]), rec)  # no longer the holder: ignored
    assert int(core.plctonc["ControlDWord"][0]) == 0


def test_repeated_client_and_id_runs_once() -> None:
    core = core2()
    port, _ = claimed(core, "plc", 1_000_000)
    core.step()
    r1 = reply(port, port.send("nc1", 1, "MoveRelative", Distance=5.0, Velocity=100.0))
    port._next_id -= 1  # the same (client, id) again, as from a restarted PLC reusing ids
    core.step()
    r2 = reply(port, port.send("nc1", 1, "MoveRelative", Distance=5.0, Velocity=100.0))
    assert r1 == r2 and r1["error"] == 0 and r1["CmdNo"] == 1  # the cached reply
    assert port.server.handler.cache.hits == 1
    for _ in range(2000):
        core.step()
    assert abs(float(core.nctoplc[0]["SetPos"]) - 5.0) < 1e-9, "moved once, not twice"


def test_motion_request_reaches_the_core_with_its_client(monkeypatch: pytest.MonkeyPatch) -> None:
    core = core2()
    seen: list[str] = []
    real = core.execute

    def spy(req: dict[str, Any], axis_id: int) -> dict[str, Any]:
        seen.append(req["client"])
        return real(req, axis_id)

    monkeypatch.setattr(core, "execute", spy)
    port = InProcessPort(core, "plc7")
    reply(port, port.send("nc1", 1, "MoveVelocity", Velocity=1.0))
    assert seen == ["plc7"]


def test_closing_the_holder_faults_its_moving_axis_and_releases_the_claim(rig: Rig) -> None:
    ax, pw, calls = powered(rig, "plc1")
    mv = MC_MoveVelocity()
    calls["body"] = lambda p: mv(Axis=ax, Execute=True, Velocity=50.0)
    rig.run_until(lambda: mv.Active and ax.Status.ContinuousMotion, 10)
    plc1 = rig.plcs.pop("plc1")
    port = plc1.port
    plc1.close()
    plc1.close()  # idempotent
    assert port.claims.holder(1) is None and port.claims.clients() == []
    rig.run(1)
    assert int(rig.rec()["ErrorCode"]) == LOST == 0x8F01
    assert int(rig.core.plctonc["ControlDWord"][0]) == 0  # default PLCTONC
    rig.run_until(lambda: abs(float(rig.rec()["ActVelo"])) < 1e-9, 200)  # stopped with its ramp
    # another client may take the axis now
    plc2 = rig.plc("plc2")
    ax2 = plc2.axis("nc1", 1)
    pw2 = MC_Power()
    plc2.program = lambda p: pw2(Axis=ax2, Enable=True)
    rig.run(3)
    # the claim is granted (Active, no refusal 0x723); MC_Power's Error shows the axis's fault until a reset
    assert plc2.port.holds_claim(1) and pw2.Active and pw2.Error and pw2.ErrorID == LOST


def test_a_client_disappears_with_its_last_port() -> None:
    core = core2()
    a1, a2 = InProcessPort(core, "a"), InProcessPort(core, "a")
    assert reply(a1, a1.send("nc1", 2, "Claim"))["error"] == 0
    a1.close()
    assert a2.holds_claim(2) and a2.claims.clients() == ["a"]
    p = a1.send("nc1", 2, "Reset")  # a closed port is never answered
    a1.poll()
    assert not p.done
    a2.close()
    assert a2.claims.holder(2) is None
    core.step()
    assert int(core.nctoplc["ErrorCode"][1]) == LOST


def test_silent_holder_times_out_with_8f02() -> None:
    rig = Rig()
    srv = InProcessNc(rig.core, watchdog_timeout=0.1)
    plc = rig.plc("plc1")
    assert plc.port.server is srv
    ax = plc.axis("nc1", 1)
    pw = MC_Power()
    plc.program = lambda p: pw(Axis=ax, Enable=True)
    run_cycles(rig.core, plc, 10, nc_steps=10)
    assert pw.Status and plc.port.holds_claim(1)
    for _ in range(85):  # its last frame is 10 + 85 ms of NC time old: still trusted
        srv.cycle()
        rig.core.step()
    assert plc.port.holds_claim(1)
    run_cycles(rig.core, [], 1, nc_steps=10)  # the NC runs on, the PLC stays silent
    assert not plc.port.holds_claim(1)
    assert int(rig.rec()["ErrorCode"]) == TIMEOUT == 0x8F02


def test_a_task_started_later_is_not_blamed_for_its_younger_clock(rig: Rig) -> None:
    """The watchdog runs on NC time: a second task whose own clock starts at 0 long after the
    first is not faulted when the first task's cycle runs the watchdog."""
    ax1, pw1, _ = powered(rig, "plc1")
    rig.run(100)  # 1 s
    ax2, pw2, _ = powered(rig, "plc2", axis_id=2)
    rig.run(100)
    assert pw1.Status and pw2.Status and not pw1.Error and not pw2.Error
    assert int(rig.rec(2)["ErrorCode"]) == 0
    assert int(rig.core.plctonc["ControlDWord"][1]) & int(ControlDWord.Enable)


def test_requests_as_bytes_get_the_servers_error_replies() -> None:
    core = core2()
    srv = InProcessNc.of(core)
    assert srv.request(1, b"\xc1")["error"] == 0x706
    assert srv.request(9, make_request("Reset", 1))["error"] == ErrorCodes.NC_AXIS_ID_NOT_ALLOWED
    # the same key checks as over zenoh: class, identity
    r = srv.request(1, make_request("WriteParameter", 2, ParameterNumber=1003, Value=100.0), cls="op")
    assert r["error"] == ErrorCodes.ADSERR_DEVICE_ACCESSDENIED and "class 'eng'" in r["text"]
    r = srv.request(1, make_request("Reset", 3, client="other"), client="plc")
    assert r["error"] == ErrorCodes.ADSERR_DEVICE_ACCESSDENIED and "'other'" in r["text"]
    assert srv.query("nc/nc1/axis/01/cmd/op/plc", make_request("Reset", 4))["error"] == ErrorCodes.NC_AXIS_ID_NOT_ALLOWED
    assert srv.request(1, make_request("Reset", 5))["error"] == 0


def test_in_process_ports_send_on_their_own_command_keys() -> None:
    """A port's requests go to Keys.command_key(cmd, axis, client): the NC sees the port's client."""
    core = core2()
    srv = InProcessNc.of(core)
    seen: list[str] = []
    handle = srv.handler.handle
    srv.handler.handle = lambda key, payload, now: (seen.append(key), handle(key, payload, now))[1]  # type: ignore[method-assign]
    port = InProcessPort(core, "plc7")
    for cmd, axis, args in (("Info", None, {}), ("ReadParameter", 1, {"ParameterNumber": 1003}),
                            ("Claim", 2, {}), ("WriteParameter", 1, {"ParameterNumber": 1003, "Value": 100.0})):
        p = port.send("nc1", axis, cmd, **args)
        port.poll()
        assert p.done and p.error == 0, p.reply
    assert seen == ["nc/nc1/cmd/read/plc7", "nc/nc1/axis/1/cmd/read/plc7", "nc/nc1/axis/2/cmd/op/plc7",
                    "nc/nc1/axis/1/cmd/eng/plc7"]
    assert srv.claims.holder(2) == "plc7"
    assert srv.handler.last_command[2][:2] == ("plc7", "Claim")
    port.close()
