"""nc-opcua on real processes: an nc-server, nc-opcua in front of it, asyncua clients (tests/opcua/conftest.py).

Browse, subscribe and see a move, methods, refusals per role (BadUserAccessDenied), an NC refusal with its
ErrorID, parameters read on demand and refreshed after a write, many sessions, a jog that ends at its timeout,
a client that vanishes (its jog stops with 0x8F01, its claim is released). Waits are deadlines on conditions.
"""
from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from nc_schema import ErrorCodes
from znc_testing import NcServerProcess, NcTestClient, kill_process_group, wait_until
from znc_testing.opcua_testing import NcOpcuaProcess, call, client, ns, until, value

GOOD = 0
DENIED = ua.StatusCodes.BadUserAccessDenied


def run(coro: Any) -> Any:
    return asyncio.run(asyncio.wait_for(coro, 240))


def claims(watch: NcTestClient) -> dict[int, str]:
    arb = watch.request("Info")["Value"]["arbitration"]
    return {int(a): str(c) for a, c in (arb.get("claims") or {}).items()}


class _Collect:
    def __init__(self) -> None:
        self.values: list[Any] = []

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.values.append(val)


def test_browse_subscribe_and_see_a_move(opcua: NcOpcuaProcess, watch: NcTestClient) -> None:
    async def body() -> None:
        async with client(opcua.url, "alice", "alice-pw") as c:
            idx = await ns(c)
            ncs = await c.nodes.objects.get_child([f"{idx}:NCs"])
            assert [(await n.read_browse_name()).Name for n in await ncs.get_children()] == ["nc1"]
            axes = c.get_node(ua.NodeId("nc1.Axes", idx))
            await until(lambda: axes.get_children(), 30, "the axes of nc1")
            names = sorted([(await n.read_browse_name()).Name for n in await axes.get_children()])
            assert names == sorted(["X", "Y", "Z", "C"])
            ax = c.get_node(ua.NodeId("nc1.1", idx))
            children = {(await n.read_browse_name()).Name for n in await ax.get_children()}
            assert {"ActPos", "CmdPos", "ActSpeed", "CmdSpeed", "RemDist", "ActStatus", "IsReferenced", "ErrorCode",
                    "ErrorText", "NcToPlc", "Parameters", "Power", "MoveAbsolute", "JogStart", "WriteParameter"} <= children
            seen = _Collect()
            sub = await c.create_subscription(50, seen)
            await sub.subscribe_data_change(c.get_node(ua.NodeId("nc1.1.ActPos", idx)))
            start = float(await value(c, "nc1.1.ActPos"))
            assert (await call(c, "nc1.1", "Reset"))[0] == GOOD
            status, out = await call(c, "nc1.1", "Power", True, 100.0)
            assert status == GOOD and out == [0, ""], (hex(status), out)
            await until(lambda: value(c, "nc1.1.Enabled"), 20, "axis 1 enabled")
            assert claims(watch).get(1) == "opcua.alice"  # the door's user id holds it (<door>.<user>)
            target = start + 40.0
            status, out = await call(c, "nc1.1", "MoveAbsolute", target, 100.0)
            assert status == GOOD, (hex(status), out)
            await until(lambda: _at(c, "nc1.1.ActPos", target), 30, "ActPos at the target")
            await until(lambda: _eq(value(c, "nc1.1.ActStatus"), "STANDSTILL"), 10, "standstill")
            await until(lambda: _true(lambda: any(abs(v - target) < 1e-6 for v in seen.values)), 10, "the end notified")
            between = [v for v in seen.values if start + 0.5 < v < target - 0.5]
            assert between, f"no intermediate position notified: {seen.values}"  # the move was seen moving
            assert abs(float(await value(c, "nc1.1.NcToPlc.ActPos")) - target) < 1e-6
            assert watch.request("Info")["Value"]["arbitration"]["last_command"][1]["client"] == "opcua.alice"
            await sub.delete()
            assert (await call(c, "nc1.1", "Power", False, 100.0))[0] == GOOD
            await until(lambda: _true(lambda: 1 not in claims(watch)), 20, "axis 1 released after Power(FALSE)")
    run(body())


async def _at(c: Any, node: str, target: float) -> bool:
    return abs(float(await value(c, node)) - target) < 1e-6


async def _eq(aw: Any, want: Any) -> bool:
    return bool(await aw == want)


async def _true(f: Any) -> bool:
    return bool(f())


def last_command(watch: NcTestClient, axis: int) -> Any:
    arb = watch.request("Info")["Value"]["arbitration"]
    return (arb.get("last_command") or {}).get(str(axis))


def test_roles_are_enforced(opcua: NcOpcuaProcess, watch: NcTestClient) -> None:
    velo_max = watch.request("ReadParameter", axis=2, ParameterNumber=1003)["Value"]
    assert velo_max != pytest.approx(100.0)  # (the refused writes below would change it)
    before = last_command(watch, 2)

    async def body() -> None:
        async with client(opcua.url, "bob", "bob-pw") as c:  # observer
            for m, args in (("Power", (True, 100.0)), ("MoveAbsolute", (1.0, 10.0)), ("Reset", ()),
                            ("JogStart", (1, 10.0, 1.0)), ("WriteParameter", ("AxisVeloMax", 100.0))):
                status, out = await call(c, "nc1.2", m, *args)
                assert status == DENIED, (m, hex(status))
                assert out[0] == ErrorCodes.ADSERR_DEVICE_ACCESSDENIED and "observer" in out[1]
            assert isinstance(await value(c, "nc1.2.ActPos"), float)  # reads are fine
            status, _ = await call(c, "nc1.2", "RefreshParameters")
            assert status == GOOD
        async with client(opcua.url) as c:  # anonymous (allowed: read-only)
            assert (await call(c, "nc1.2", "MoveVelocity", 10.0, 1))[0] == DENIED
            assert isinstance(await value(c, "nc1.2.CmdPos"), float)
        async with client(opcua.url, "alice", "alice-pw") as c:  # operator: no parameters
            status, out = await call(c, "nc1.2", "WriteParameter", "AxisVeloMax", 100.0)
            assert status == DENIED and "engineer" in out[1]
        # nothing was sent for the refused calls: no claim, no command recorded, the parameter as it was
        assert 2 not in claims(watch)
        assert last_command(watch, 2) == before
        assert watch.request("ReadParameter", axis=2, ParameterNumber=1003)["Value"] == velo_max
        with pytest.raises(Exception):
            async with client(opcua.url, "alice", "wrong") as c:
                await value(c, "nc1.2.ActPos")
    run(body())


def test_nc_refusal_returns_its_error_id(opcua: NcOpcuaProcess, watch: NcTestClient) -> None:
    async def body() -> None:
        async with client(opcua.url, "alice", "alice-pw") as c:
            await call(c, "nc1.2", "Reset")
            assert (await call(c, "nc1.2", "Power", True, 100.0))[0] == GOOD
            await until(lambda: value(c, "nc1.2.Enabled"), 20, "axis 2 enabled")
            status, out = await call(c, "nc1.2", "MoveAbsolute", 10.0, 1e9)  # above AxisVeloMax
            assert status == ua.StatusCodes.BadInvalidState, hex(status)
            assert out[0] == ErrorCodes.NC_VELOCITY_NOT_ALLOWED and "0x4221" in out[1], out
            status, out = await call(c, "nc1.2", "JogStart", 1, 10.0, 1e6)  # the door's own argument check
            assert status == ua.StatusCodes.BadInvalidArgument and out[0] == ErrorCodes.MC_PARAMETER_NOT_CORRECT
            assert (await call(c, "nc1.2", "Power", False, 100.0))[0] == GOOD
    run(body())


def test_parameters_on_demand_and_after_a_write(opcua: NcOpcuaProcess, watch: NcTestClient) -> None:
    async def body() -> None:
        async with client(opcua.url, "eve", "eve-pw") as c:
            nc_value = watch.request("ReadParameter", axis=3, ParameterNumber=1003)["Value"]  # AxisVeloMax
            assert float(await value(c, "nc1.3.P.AxisVeloMax")) == pytest.approx(nc_value)
            idx = await ns(c)
            eu = await c.get_node(ua.NodeId("nc1.3.P.AxisVeloMax.EU", idx)).read_value()
            assert eu.DisplayName.Text == "u/s"
            status, out = await call(c, "nc1.3", "WriteParameter", "AxisVeloMax", nc_value / 2)
            assert status == GOOD, (hex(status), out)
            assert watch.request("ReadParameter", axis=3, ParameterNumber=1003)["Value"] == pytest.approx(nc_value / 2)
            assert float(await value(c, "nc1.3.P.AxisVeloMax")) == pytest.approx(nc_value / 2)  # refreshed
            status, out = await call(c, "nc1.3", "WriteParameter", "NoSuchParameter", 1.0)
            assert status == ua.StatusCodes.BadInvalidArgument
            assert (await call(c, "nc1.3", "WriteParameter", "AxisVeloMax", nc_value))[0] == GOOD
    run(body())


def test_jog_stops_at_its_timeout_unless_renewed(opcua: NcOpcuaProcess, watch: NcTestClient) -> None:
    def set_velo() -> float:
        rec = watch.nctoplc(3)
        return 0.0 if rec is None else abs(float(rec["SetVelo"]))

    wait_until(lambda: watch.nctoplc(3) is not None, 20, "NCTOPLC of axis 3")

    async def body() -> None:
        async with client(opcua.url, "alice", "alice-pw") as c:
            await call(c, "nc1.3", "Reset")
            assert (await call(c, "nc1.3", "Power", True, 100.0))[0] == GOOD
            await until(lambda: value(c, "nc1.3.Enabled"), 20, "axis 3 enabled")
            # renewed every 0.3 s (a 1.5 s timeout): it keeps going for 3 s
            t_end = time.monotonic() + 3.0
            while time.monotonic() < t_end:
                status, out = await call(c, "nc1.3", "JogStart", 3, 20.0, 1.5)  # negative: Z has room there
                assert status == GOOD, (hex(status), out)
                await asyncio.sleep(0.3)
            await until(lambda: _true(lambda: set_velo() > 0), 5, "the renewed jog still running")
            # not renewed: it stops by itself (no JogStop)
            await until(lambda: _true(lambda: set_velo() == 0.0), 20, "the jog stopped at its timeout")
            assert int(await value(c, "nc1.3.ErrorCode")) == 0
            assert (await call(c, "nc1.3", "Power", False, 100.0))[0] == GOOD
    run(body())


def test_many_sessions_see_the_same_move(opcua: NcOpcuaProcess, watch: NcTestClient) -> None:
    n = 8

    async def body() -> None:
        clients = [client(opcua.url, "bob", "bob-pw") for _ in range(n)]
        for c in clients:
            await c.connect()
        try:
            idx = await ns(clients[0])
            seen = [_Collect() for _ in clients]
            for c, s in zip(clients, seen):
                sub = await c.create_subscription(50, s)
                await sub.subscribe_data_change(c.get_node(ua.NodeId("nc1.1.ActPos", idx)))
            async with client(opcua.url, "alice", "alice-pw") as op:
                await call(op, "nc1.1", "Reset")
                assert (await call(op, "nc1.1", "Power", True, 100.0))[0] == GOOD
                await until(lambda: value(op, "nc1.1.Enabled"), 20, "axis 1 enabled")
                start = float(await value(op, "nc1.1.ActPos"))
                assert (await call(op, "nc1.1", "MoveRelative", 15.0, 100.0))[0] == GOOD
                await until(lambda: _at(op, "nc1.1.ActPos", start + 15.0), 30, "the relative move")
                for i, s in enumerate(seen):
                    await until(lambda s=s: _true(lambda: any(abs(v - start - 15.0) < 1e-6 for v in s.values)),
                                20, f"session {i} notified of the end position")
                assert (await call(op, "nc1.1", "Power", False, 100.0))[0] == GOOD
        finally:
            for c in clients:
                await c.disconnect()
    run(body())


def test_a_vanished_client_s_jog_stops_and_its_claim_goes(opcua: NcOpcuaProcess, watch: NcTestClient,
                                                           tmp_path: Path) -> None:
    script = Path(__file__).with_name("opcua_jogger.py")
    err = open(tmp_path / "jogger.stderr", "w")
    proc = subprocess.Popen([sys.executable, str(script), opcua.url, "alice", "alice-pw", "nc1.4"],
                            stdout=subprocess.PIPE, stderr=err, text=True, start_new_session=True,
                            env=dict(os.environ, PYTHONPATH=os.pathsep.join(
                                [str(Path(__file__).parent.parent), os.environ.get("PYTHONPATH", "")])))
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # blocks until the jog runs (or the script dies: "")
        assert line.strip() == "jogging", (tmp_path / "jogger.stderr").read_text()
        wait_until(lambda: (r := watch.nctoplc(4)) is not None and float(r["SetVelo"]) > 0, 20, "axis 4 jogging")
        assert claims(watch).get(4) == "opcua.alice"
        os.killpg(proc.pid, signal.SIGKILL)  # vanishes: no CloseSession; its session ends at the timeout (3 s)
        proc.wait(10)
        rec = wait_until(lambda: (r := watch.nctoplc(4)) is not None and int(r["ErrorCode"]) == 0x8F01 and r, 30,
                         "axis 4 stopped with 0x8F01")
        wait_until(lambda: (r := watch.nctoplc(4)) is not None and float(r["SetVelo"]) == 0.0, 30, "axis 4 at rest")
        wait_until(lambda: 4 not in claims(watch), 20, "axis 4 released")
        # its user's last session: the id opcua.alice leaves the NC (its liveliness token is gone)
        wait_until(lambda: not watch.request("Info")["Value"]["arbitration"]["clients"].get("opcua.alice", {})
                   .get("alive"), 20, "opcua.alice no longer alive at the NC")
        assert rec is not None
    finally:
        kill_process_group(proc)
        err.close()
