"""nc-opcua's own life, on real processes: SIGTERM releases what its users powered (enables off, Release, no
error) and exits 0; an NC that goes away shows as Alive False with its axes' last values UncertainLastUsableValue;
the door still stops promptly then."""
from __future__ import annotations

import asyncio
import signal
from pathlib import Path

from asyncua import ua

from znc_testing import NcTestClient, start_nc_server, wait_until
from znc_testing.opcua_testing import call, client, ns, start_nc_opcua, until, value


def _claims(watch: NcTestClient) -> dict[int, str]:
    arb = watch.request("Info")["Value"]["arbitration"]
    return {int(a): str(c) for a, c in (arb.get("claims") or {}).items()}


def test_sigterm_releases_and_a_lost_nc_is_marked(tmp_path: Path, users_file: Path) -> None:
    nc = start_nc_server(tmp_path / "nc")
    doors = []
    watch = None
    try:
        watch = NcTestClient(nc.port, client_id="watch2", token=False)
        door = start_nc_opcua(tmp_path / "d1", nc.endpoint, ["--users", str(users_file)])
        doors.append(door)

        async def power() -> None:
            async with client(door.url, "alice", "alice-pw") as c:
                await until(lambda: _ok(c, "nc1.1.Enabled"), 60, "axis 1 served")
                await call(c, "nc1.1", "Reset")
                assert (await call(c, "nc1.1", "Power", True, 100.0))[0] == 0
                await until(lambda: value(c, "nc1.1.Enabled"), 20, "axis 1 enabled")
        asyncio.run(asyncio.wait_for(power(), 240))
        # the session closed: 0x8F01 and release (the rule for a session that ends); reset, power again and keep it
        wait_until(lambda: 1 not in _claims(watch), 20, "released after the session ended")
        wait_until(lambda: (r := watch.nctoplc(1)) is not None and int(r["ErrorCode"]) == 0x8F01, 20, "0x8F01")

        async def power_and_stop_the_door() -> None:
            async with client(door.url, "alice", "alice-pw", timeout=5) as c:  # (its close fails: the server is gone)
                await call(c, "nc1.1", "Reset")
                assert (await call(c, "nc1.1", "Power", True, 100.0))[0] == 0
                await until(lambda: value(c, "nc1.1.Enabled"), 20, "axis 1 enabled again")
                assert _claims(watch).get(1) == "opcua.alice"
                door.proc.send_signal(signal.SIGTERM)  # the door stops while the session is open
                assert await asyncio.to_thread(door.proc.wait, 60) == 0, door.stderr()
        try:
            asyncio.run(asyncio.wait_for(power_and_stop_the_door(), 240))
        except (ConnectionError, asyncio.TimeoutError, ua.UaError, OSError):
            pass  # (the client's own close after the server went: nothing to assert about it)
        assert door.proc.returncode == 0, door.stderr()
        wait_until(lambda: 1 not in _claims(watch), 20, "axis 1 released by the stopping door")
        wait_until(lambda: (r := watch.nctoplc(1)) is not None and int(r["ErrorCode"]) == 0
                   and not int(r["StateDWord"]) & (1 << 20), 20, "axis 1 disabled without an error")

        door2 = start_nc_opcua(tmp_path / "d2", nc.endpoint, ["--users", str(users_file)])
        doors.append(door2)

        async def nc_lost() -> None:
            async with client(door2.url, "bob", "bob-pw") as c:
                await until(lambda: _ok(c, "nc1.1.ActPos"), 60, "axis 1 served")
                assert await value(c, "nc1.Alive") is True
                nc.kill()
                await until(lambda: _not(value(c, "nc1.Alive")), 30, "nc1 not alive")
                idx = await ns(c)
                dv = await c.get_node(ua.NodeId("nc1.1.ActPos", idx)).read_data_value(raise_on_bad_status=False)
                assert dv.StatusCode.value == ua.StatusCodes.UncertainLastUsableValue, dv.StatusCode
                assert isinstance(dv.Value.Value, float)
        asyncio.run(asyncio.wait_for(nc_lost(), 240))
        assert door2.stop(60) == 0, door2.stderr()
    finally:
        if watch is not None:
            watch.close()
        for d in doors:
            d.kill()
        nc.kill()


async def _ok(c: object, node: str) -> bool:
    try:
        await value(c, node)  # type: ignore[arg-type]
        return True
    except Exception:
        return False


async def _not(aw: object) -> bool:
    return not await aw  # type: ignore[misc]
